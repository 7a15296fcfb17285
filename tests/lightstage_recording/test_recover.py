"""`lightstage bag recover`: it says what was damaged or lost in the source, and a copy that
cannot be completed (disk full) or has nothing to copy never leaves a bag that claims more
than it holds. In-process (`bag_cli.bag_main`), no ROS."""
import os
import shutil

import pytest
import yaml
from rclpy.serialization import serialize_message

import lightstage_recording as lr
from lightstage_recording import bag_cli
from helpers.recording import image, recover
from helpers.write_faults import FailingDisk

pytestmark = pytest.mark.process

T0 = 1_700_000_000_000_000_000
IMG = 'sensor_msgs/msg/Image'


def _source(path, n=12, size=320, chunk_size_bytes=1 << 20):
    """n images of size x size (205 kB each at 320 px: the default 1 MiB chunks take 6)."""
    sent = []
    with lr.BagWriter(path, chunk_size_bytes=chunk_size_bytes) as w:
        w.add_topic('/image_raw', IMG)
        for i in range(n):
            data = serialize_message(image(seed=i, size=size))
            w.write('/image_raw', data, T0 + i * 1_000_000)
            sent.append((data, T0 + i * 1_000_000))
    return sent


def _damage(path, data):
    """Flip bytes of a message's payload inside the MCAP file: its chunk fails its CRC."""
    (mcap,) = path.glob('*.mcap')
    raw = bytearray(mcap.read_bytes())
    at = raw.find(data[1000:1032])
    assert at > 0
    raw[at:at + 8] = bytes(255 - b for b in raw[at:at + 8])
    mcap.write_bytes(bytes(raw))


def _recover(capsys, *args):
    rc = bag_cli.bag_main(['recover', *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


def _metadata(path):
    return yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def test_recover_prints_what_was_damaged_and_lost_in_the_source(tmp_path, capsys):
    """A closed bag with a damaged chunk: its summary lists 12 messages, 6 are readable."""
    src = tmp_path / 'damaged'
    sent = _source(src)
    _damage(src, sent[2][0])
    rc, out, err = _recover(capsys, src)
    assert rc == 0, out + err
    assert f'{src} is damaged or incomplete:\n  - damaged_0.mcap: the chunk at byte ' in out, out
    assert 'is damaged (' in out and 'its messages are skipped' in out
    assert f'lost in {src}: 6 of the 12 messages its summary / metadata.yaml lists' in out, out
    dst = tmp_path / 'damaged_recovered'
    assert f'recovered 6 messages on 1 topics into {dst}' in out
    info = lr.BagReader(dst).info(verify=True)
    assert info.complete and info.message_count == 6
    assert [m.data for m in lr.BagReader(dst).messages()] == [s[0] for s in sent[6:]]
    meta = _metadata(dst)
    assert meta['message_count'] == 6
    assert meta['custom_data']['recovered_from'] == str(src)
    assert 'its messages are skipped' in meta['custom_data']['source_problems']


def test_recover_of_a_cut_off_bag_names_the_cut(tmp_path, capsys):
    """A killed recorder's bag (no metadata.yaml, file cut inside a chunk)."""
    full = tmp_path / 'full'
    sent = _source(full, chunk_size_bytes=1024)  # one chunk per image
    cut = tmp_path / 'cut'
    cut.mkdir()
    shutil.copy(full / 'full_0.mcap', cut / 'cut_0.mcap')
    os.truncate(cut / 'cut_0.mcap', (full / 'full_0.mcap').stat().st_size // 2)
    rc, out, err = _recover(capsys, cut, '-o', tmp_path / 'fixed')
    assert rc == 0, out + err
    assert 'no metadata.yaml (the recorder did not close the bag)' in out, out
    assert 'cut_0.mcap is cut off at byte ' in out
    assert f'lost in {cut}: whatever was written after the damage above' in out
    n = lr.BagReader(tmp_path / 'fixed').info().message_count
    assert 0 < n < len(sent) and f'recovered {n} messages on 1 topics' in out


def test_recover_stopped_by_a_full_disk_lists_only_what_it_copied(tmp_path, capsys, monkeypatch):
    """The second chunk of the copy hits a full disk (space is back when it closes): the new
    bag's file ends after the first chunk, whose 6 messages metadata.yaml lists; exit 1."""
    src = tmp_path / 'src'
    sent = _source(src)
    dst = tmp_path / 'copy'
    disk = FailingDisk(monkeypatch, after_chunks=1, stays_full=False)
    rc, out, err = _recover(capsys, src, '-o', dst)
    assert disk.failures == 1
    assert rc == 1, out + err
    assert f'{src}: no damage found' in out
    assert f'RECOVERY STOPPED: disk full writing {dst}: ' in out, out
    assert f'free space and run `lightstage bag recover {src} -o {dst}` again once {dst} is deleted' in out
    assert f'partly recovered: 6 messages on 1 topics into {dst}' in out
    assert f'Not copied: the rest of {src} (12 messages in all by its info)' in out
    assert 'the copy stopped midway' in err
    info = lr.BagReader(dst).info()
    assert not info.complete and info.message_count == 6  # no summary: what is in the file
    assert any('ends at byte' in p and 'without the MCAP footer' in p for p in info.problems)
    assert [m.data for m in lr.BagReader(dst).messages()] == [s[0] for s in sent[:6]]
    meta = _metadata(dst)
    assert meta['message_count'] == 6
    assert meta['topics_with_message_count'][0]['message_count'] == 6
    assert meta['duration']['nanoseconds'] == sent[5][1] - sent[0][1]
    assert 'disk full' in meta['custom_data']['recovery_stopped']
    shown = lr.format_info(info)  # `lightstage bag info` says it is a partial copy
    assert f'PARTIAL COPY of {src}: the recovery stopped (disk full writing' in shown, shown
    # as a function: the same, and the wrapper raises
    shutil.rmtree(dst)
    disk.failures, disk.chunks = 0, 0
    with pytest.raises(lr.BagWriteError, match='disk full writing'):
        recover(src, dst)
    assert _metadata(dst)['message_count'] == 6


def test_recover_with_nothing_intact_writes_nothing_and_exits_1(tmp_path, capsys):
    src = tmp_path / 'lost'
    sent = _source(src, n=3)  # one chunk
    _damage(src, sent[1][0])
    rc, out, err = _recover(capsys, src)
    assert rc == 1, out + err
    assert 'lost_0.mcap: the chunk at byte ' in out and 'lost in ' in out
    assert (f'nothing could be recovered: {src} holds no intact message; no bag was written to '
            f'{tmp_path / "lost_recovered"}') in out
    assert 'nothing could be recovered' in err
    assert not (tmp_path / 'lost_recovered').exists()
    with pytest.raises(lr.BagError, match='nothing could be recovered'):
        recover(src, tmp_path / 'other')
    assert not (tmp_path / 'other').exists()


def test_recover_on_a_full_disk_leaves_no_bag(tmp_path, capsys, monkeypatch):
    src = tmp_path / 'src'
    _source(src, n=3)
    FailingDisk(monkeypatch, stays_full=True).full = True  # not even the file header
    rc, out, err = _recover(capsys, src, '-o', tmp_path / 'copy')
    assert rc == 1, out + err
    assert f'RECOVERY STOPPED: disk full writing {tmp_path / "copy"}: ' in out
    assert 'nothing was written; free space and ' in out
    assert 'nothing could be recovered: the copy stopped before any message reached' in out
    assert not (tmp_path / 'copy').exists()
