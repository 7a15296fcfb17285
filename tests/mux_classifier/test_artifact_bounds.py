"""Untrusted artifact files are bounded: an .npz whose members would inflate (or whose .npy
headers would allocate) beyond the loader's budget is refused with ArtifactError naming the
file and the limit, before anything is inflated. A 1 MB file whose member inflated to 1 GiB
took the classifier node from 311 MB to 2.6 GB before it was refused."""
import io
import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from mux_classifier import artifact_format

pytestmark = pytest.mark.process

GIB = 2**30


def npy_header(shape, descr='<f8') -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {'descr': descr, 'fortran_order': False, 'shape': shape})
    return out.getvalue()


@pytest.fixture(scope='module')
def zip_bomb(tmp_path_factory):
    """A ~1 MB artifact-looking .npz with one member of 1 GiB of zeros (deflated), written
    in 1 MiB chunks so the test itself never holds it."""
    path = tmp_path_factory.mktemp('bomb') / 'bomb.npz'
    with zipfile.ZipFile(path, 'w', zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        archive.writestr('header.npy',
                         _npy(np.frombuffer(json.dumps({'format_version': 1}).encode(), np.uint8)))
        with archive.open('led_patterns.npy', 'w', force_zip64=True) as member:
            member.write(npy_header((GIB // 8,)))
            chunk = bytes(2**20)
            for _ in range(GIB // 2**20):
                member.write(chunk)
    return path


def _npy(array) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


LOAD = '''
import json, resource, sys
from mux_classifier.artifact import ArtifactError, TrainedArtifact
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
try:
    TrainedArtifact.load(sys.argv[1])
    outcome = 'loaded'
except ArtifactError as exc:
    outcome = 'ArtifactError: ' + str(exc)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({'outcome': outcome, 'grew_mb': (after - before) / 1024}))
'''


def load_in_a_process(path) -> dict:
    p = subprocess.run([sys.executable, '-c', LOAD, str(path)], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout)


def test_a_zip_bomb_artifact_is_refused_before_inflating(zip_bomb):
    assert zip_bomb.stat().st_size < 8 * 2**20
    got = load_in_a_process(zip_bomb)
    print(f'{zip_bomb.stat().st_size / 2**20:.1f} MB file, 1 GiB member: refused, peak memory '
          f'grew {got["grew_mb"]:.1f} MB')
    assert got['outcome'].startswith('ArtifactError: '), got
    assert str(zip_bomb) in got['outcome'] and 'would inflate to 1024 MiB, beyond the 256 MiB limit' \
        in got['outcome'], got
    assert got['grew_mb'] < 100, got


def test_an_npy_header_declaring_a_huge_array_is_refused_before_allocating(tmp_path):
    """A member of a few bytes whose .npy header declares 8 GiB: numpy allocates from the
    header's shape, so the header is checked, not only the zip's declared sizes."""
    path = tmp_path / 'liar.npz'
    with zipfile.ZipFile(path, 'w') as archive:
        archive.writestr('led_patterns.npy', npy_header((GIB,)) + bytes(8))
    got = load_in_a_process(path)
    assert got['outcome'].startswith('ArtifactError: '), got
    assert "member 'led_patterns.npy': shape (1073741824,) of float64" in got['outcome'], got
    assert 'beyond the 256 MiB limit' in got['outcome'] and str(path) in got['outcome'], got
    assert got['grew_mb'] < 100, got


def test_a_file_beyond_the_size_limit_is_refused_unread(tmp_path, monkeypatch):
    from mux_classifier.artifact import ArtifactError, TrainedArtifact
    monkeypatch.setattr(artifact_format, 'MAX_ARTIFACT_FILE_BYTES', 1000)
    path = tmp_path / 'big.npz'
    path.write_bytes(bytes(1001))
    with pytest.raises(ArtifactError, match=r'big\.npz.*beyond the 0 MiB limit of an artifact file'):
        TrainedArtifact.load(path)


def test_too_many_members_are_refused(tmp_path, monkeypatch):
    from mux_classifier.artifact import ArtifactError, TrainedArtifact
    monkeypatch.setattr(artifact_format, 'MAX_ARTIFACT_MEMBERS', 3)
    path = tmp_path / 'many.npz'
    with zipfile.ZipFile(path, 'w') as archive:
        for i in range(4):
            archive.writestr(f'a{i}.npy', _npy(np.zeros(1)))
    with pytest.raises(ArtifactError, match='it has 4 members, more than the 3'):
        TrainedArtifact.load(path)
