"""Bags from anywhere are bounded: an MCAP chunk is inflated only within the size it declares
and the reader's memory limit (`scan.MAX_CHUNK_BYTES`), and metadata.yaml may name only the
regular files of the bag directory, each once. Each refusal is a `BagError` naming the file
and the limit; `bag info`, `bag recover` and `play` print it and exit 2 (play: the player's
refusal) with the process's memory growing by less than 100 MB.

The chunk bomb is a 4 MB MCAP file whose one lz4 chunk inflates to 1 GiB (a probe's file: `bag
info` took 2.1 GB and `bag recover` copied it as "no damage found")."""
import json
import os
import struct
import subprocess
import sys
import textwrap

import lz4.frame
import pytest
import yaml
from rclpy.serialization import serialize_message

from lightstage_recording import BagError, BagReader, BagWriter
from helpers.recording import illumination
from helpers.suite import fresh_domain_id, lightstage_command

pytestmark = pytest.mark.process

GIB = 1 << 30
LIMIT_TEXT = '268435456 bytes (256 MiB)'


def _record(opcode: int, body: bytes) -> bytes:
    return struct.pack('<BQ', opcode, len(body)) + body


def _string(s: str) -> bytes:
    return struct.pack('<I', len(s)) + s.encode()


def write_chunk_bomb(path, inflated: int = GIB, declared: int | None = None):
    """An MCAP file (no summary) with a schema, a channel and one lz4 chunk holding one
    message of ``inflated`` zero bytes; the chunk declares ``declared`` bytes uncompressed (by
    default the truth). Compressed in 1 MiB steps: the test never holds the inflated data."""
    schema = _record(0x03, struct.pack('<H', 1) + _string('lightstage_interfaces/msg/IlluminationState')
                     + _string('ros2msg') + struct.pack('<I', 0))
    channel = _record(0x04, struct.pack('<HH', 1, 1) + _string('/illumination') + _string('cdr')
                      + struct.pack('<I', 0))
    message_head = struct.pack('<BQ', 0x05, 2 + 4 + 8 + 8 + inflated) + struct.pack('<HIQQ', 1, 1, 1, 1)
    compressor = lz4.frame.LZ4FrameCompressor()
    parts = [compressor.begin(), compressor.compress(message_head)]
    zeros = bytes(1 << 20)
    for _ in range(inflated >> 20):
        parts.append(compressor.compress(zeros))
    parts.append(compressor.flush())
    data = b''.join(parts)
    size = len(message_head) + inflated if declared is None else declared
    chunk = _record(0x06, struct.pack('<QQQI', 1, 1, size, 0) + _string('lz4')
                    + struct.pack('<Q', len(data)) + data)
    with open(path, 'wb') as f:
        f.write(b'\x89MCAP0\r\n' + _record(0x01, _string('ros2') + _string('bomb')) + schema
                + channel + chunk + _record(0x0F, struct.pack('<I', 0))
                + _record(0x02, struct.pack('<QQI', 0, 0, 0)) + b'\x89MCAP0\r\n')
    return path


@pytest.fixture(scope='module')
def bomb(tmp_path_factory):
    path = write_chunk_bomb(tmp_path_factory.mktemp('bomb') / 'bomb.mcap')
    assert path.stat().st_size < 8 << 20
    return path


# the child reads its peak resident size (VmHWM) after every import, runs the command, and
# reports what the peak grew by
_MEASURE = textwrap.dedent('''
    import json, sys
    def peak_kb():
        for line in open('/proc/self/status'):
            if line.startswith('VmHWM:'):
                return int(line.split()[1])
    import lz4.frame, zstandard, mcap.stream_reader, mcap.reader
    from lightstage_recording import BagReader, bag_cli
    verb, args = sys.argv[1], sys.argv[2:]
    if verb == 'play':
        import rclpy
        from lightstage_recording import player_node
    before = peak_kb()
    if verb == 'bag':
        rc = bag_cli.bag_main(args)
    elif verb == 'play':
        rc = bag_cli.play_main(args)
    else:
        rc = 0
        try:
            for _ in BagReader(args[0]).messages():
                pass
        except Exception as exc:
            print(type(exc).__name__, exc, file=sys.stderr)
            rc = 2
    print(json.dumps({'rc': rc, 'growth_kb': peak_kb() - before}))
''')


def _measure(*argv, timeout=120):
    p = subprocess.run([sys.executable, '-c', _MEASURE, *argv], capture_output=True, text=True,
                       timeout=timeout, env={**os.environ, 'ROS_DOMAIN_ID': str(fresh_domain_id())})
    result = json.loads(p.stdout.strip().splitlines()[-1])
    return result, p.stdout + p.stderr


@pytest.mark.parametrize('verb', ['info', 'recover', 'play', 'messages'])
def test_a_chunk_inflating_to_1_gib_is_refused_with_the_file_and_the_limit(verb, bomb, tmp_path):
    argv = {'info': ('bag', 'info', str(bomb)),
            'recover': ('bag', 'recover', str(bomb), '-o', str(tmp_path / 'copy')),
            'play': ('play', str(bomb), '--domain-id', str(fresh_domain_id())),
            'messages': ('messages', str(bomb))}[verb]
    result, out = _measure(*argv)
    assert result['rc'] == 2, out
    assert str(bomb) in out and LIMIT_TEXT in out, out
    assert result['growth_kb'] < 100_000, out
    assert not (tmp_path / 'copy').exists()


def test_a_chunk_that_inflates_beyond_what_it_declares_is_damage_within_the_memory_limit(tmp_path):
    """A chunk declaring 1 KiB whose data inflates to 1 GiB: inflated only up to what it
    declares, reported as a damaged chunk; the process grows by less than 100 MB."""
    liar = write_chunk_bomb(tmp_path / 'liar.mcap', declared=1024)
    result, out = _measure('bag', 'info', str(liar))
    assert result['rc'] == 1, out
    assert 'inflates to more than the 1024 bytes it declares' in out, out
    assert result['growth_kb'] < 100_000, out


def test_the_memory_limit_is_the_reader_s_to_raise(bomb):
    """`BagReader(..., max_chunk_bytes=...)`: a bag with larger chunks can be read on purpose."""
    small = bomb.with_name('small.mcap')
    write_chunk_bomb(small, inflated=2 << 20)
    with pytest.raises(BagError, match=r'2097183 bytes .* more than the 1048576 bytes \(1 MiB\)'):
        list(BagReader(small, max_chunk_bytes=1 << 20).messages())
    assert [len(m.data) for m in BagReader(small).messages()] == [2 << 20]


@pytest.fixture
def bag(tmp_path):
    path = tmp_path / 'bag'
    with BagWriter(path) as w:
        w.add_topic('/illumination', 'lightstage_interfaces/msg/IlluminationState')
        w.write('/illumination', serialize_message(illumination()), 1_700_000_000_000_000_000)
    return path


def _list_in_metadata(bag, names):
    meta_path = bag / 'metadata.yaml'
    meta = yaml.safe_load(meta_path.read_text())
    meta['rosbag2_bagfile_information']['relative_file_paths'] = names
    meta_path.write_text(yaml.safe_dump(meta))


def _cli(*args, timeout=60):
    return subprocess.run(lightstage_command(*args), capture_output=True, text=True, timeout=timeout)


def test_a_file_listed_20000_times_is_refused_before_any_is_read(bag):
    _list_in_metadata(bag, ['bag_0.mcap'] * 20_000)
    with pytest.raises(BagError, match=r'lists bag_0.mcap more than once \(20000 times\)'):
        BagReader(bag)
    p = _cli('bag', 'recover', str(bag), '-o', str(bag.parent / 'copy'))
    assert p.returncode == 2 and 'more than once' in p.stderr, p.stdout + p.stderr
    assert not (bag.parent / 'copy').exists()


@pytest.mark.parametrize('verb', ['info', 'recover', 'play'])
def test_a_fifo_named_as_a_bag_file_is_refused_not_opened(verb, bag, tmp_path):
    """Opening a FIFO blocks until a writer comes: info, recover and play hung on one."""
    os.mkfifo(bag / 'bag_1.mcap')
    _list_in_metadata(bag, ['bag_0.mcap', 'bag_1.mcap'])
    args = {'info': ('bag', 'info', str(bag)),
            'recover': ('bag', 'recover', str(bag), '-o', str(tmp_path / 'copy')),
            'play': ('play', str(bag), '--domain-id', str(fresh_domain_id()))}[verb]
    p = _cli(*args)
    assert p.returncode == 2, p.stdout + p.stderr
    assert f'{bag / "bag_1.mcap"} is a FIFO, not a regular file' in p.stderr, p.stderr


def test_a_fifo_in_a_bag_without_metadata_is_refused(bag):
    (bag / 'metadata.yaml').unlink()
    os.mkfifo(bag / 'bag_1.mcap')
    with pytest.raises(BagError, match='is a FIFO, not a regular file'):
        BagReader(bag)


@pytest.mark.parametrize('name', ['/etc/passwd', '../../../../../../../../etc/passwd', 'link'])
def test_a_file_outside_the_bag_directory_is_refused_and_not_read(name, bag):
    (bag / 'link').symlink_to('/etc/passwd')
    _list_in_metadata(bag, ['bag_0.mcap', name])
    p = _cli('bag', 'info', str(bag))
    assert p.returncode == 2, p.stdout + p.stderr
    assert 'refused, nothing read' in p.stderr, p.stderr
    head = open('/etc/passwd', 'rb').read(8)
    assert repr(head) not in p.stderr and head.decode() not in p.stderr, p.stderr


def test_a_metadata_yaml_with_aliases_is_refused_before_they_are_expanded(bag):
    """Nine levels of ten aliases each ('billion laughs') would be 10**9 strings once expanded
    by a consumer that walks the tree; rosbag2 writes no anchors, so any is refused."""
    meta_path = bag / 'metadata.yaml'
    laughs = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i, name in enumerate('bcdefghi'):
        prev = 'abcdefgh'[i]
        laughs.append(f'{name}: &{name} [{", ".join(["*" + prev] * 10)}]')
    meta_path.write_text(meta_path.read_text() + '\n'.join(laughs) + '\n')
    with pytest.raises(BagError, match=r'metadata\.yaml uses YAML anchors or aliases'):
        BagReader(bag)
    p = _cli('bag', 'info', str(bag))
    assert p.returncode == 2 and 'anchors or aliases' in p.stderr, p.stdout + p.stderr


def test_a_metadata_yaml_beyond_1_mib_is_refused_with_the_file_and_the_limit(bag):
    meta_path = bag / 'metadata.yaml'
    meta_path.write_text(meta_path.read_text() + '#' * (2 << 20) + '\n')
    with pytest.raises(BagError, match=r'metadata\.yaml is \d+ bytes, more than the 1048576 bytes'):
        BagReader(bag)
