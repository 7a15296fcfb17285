"""A recorder whose disk fails (full, I/O error) stops cleanly: the error says what happened,
what the bag holds and what to do; the file ends after its last complete chunk, the bag's
metadata.yaml lists exactly the messages it holds, and `bag recover` completes it.
Also what the writer makes durable (fsync) and which output directories it takes -- the
claims of docs/RECORDING.md. The recording core is pure: no ROS, except the last test."""
import errno
import os

import pytest
import yaml
from rclpy.serialization import serialize_message

import lightstage_recording as lr
from lightstage_recording import fileio
from lightstage_recording.recording import Recording
from helpers.recording import REPO, illumination, image, recover
from helpers.write_faults import FailingDisk

pytestmark = pytest.mark.process

T0 = 1_700_000_000_000_000_000
ILLUM = 'lightstage_interfaces/msg/IlluminationState'
IMG = 'sensor_msgs/msg/Image'
RELIABLE = lr.QosProfile(history='unknown', depth=0)


def _info(i):
    """rclpy's message info of a raw subscription, for message i."""
    t = T0 + i * 30_000_000
    return {'received_timestamp': t, 'source_timestamp': t - 40_000,
            'publication_sequence_number': i + 1}


def _message(i):
    """(topic, serialized data) of message i: illumination states and images in turn."""
    if i % 2:
        return '/image_raw', serialize_message(image(seed=i))
    return '/illumination', serialize_message(illumination(index=i % 4, seq=i))


def _recording(path):
    rec = Recording(lr.BagWriter(path, chunk_size_bytes=1024))
    assert rec.add_topic('/illumination', ILLUM, [RELIABLE])
    assert rec.add_topic('/image_raw', IMG, [RELIABLE])
    return rec


def _record(rec, indexes, flush=True):
    sent = []
    for i in indexes:
        topic, data = _message(i)
        assert rec.receive(topic, data, _info(i))
        if flush:
            assert rec.flush()  # the recorder's flush timer
        sent.append((topic, data, _info(i)['received_timestamp']))
    return sent


def _assert_bag_holds(path, sent):
    """Every reader finds exactly ``sent`` in the complete bag, from its summary and by reading
    it."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader
    reader = lr.BagReader(path)
    info = reader.info()  # from the summary
    assert info.complete and not info.problems, info.problems
    assert info.message_count == len(sent)
    assert {t.name: t.count for t in info.topics.values()} == _counts(sent)
    assert [(m.topic, m.data, m.log_time_ns) for m in reader.messages()] == sent
    assert lr.BagReader(path).info(verify=True).message_count == len(sent)
    _assert_metadata_yaml_lists(path, sent)
    (mcap,) = path.glob('*.mcap')
    with open(mcap, 'rb') as f:  # the mcap library, from the summary's chunk indexes
        mr = make_reader(f)
        assert mr.get_summary().statistics.message_count == len(sent)
        assert [m.data for _, _, m in mr.iter_messages(log_time_order=True)] == [s[1] for s in sent]
        (rosbag2,) = [m for m in mr.iter_metadata() if m.name == 'rosbag2']
        assert yaml.safe_load(rosbag2.metadata['serialized_metadata'])['message_count'] == len(sent)
    with Reader(path) as rb:  # rosbags: metadata.yaml and the MCAP file
        assert rb.message_count == len(sent)
        assert sum(1 for _ in rb.messages()) == len(sent)


def _counts(sent):
    return {t: sum(s[0] == t for s in sent) for t in ('/illumination', '/image_raw')}


def _assert_metadata_yaml_lists(path, sent):
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] == len(sent)
    assert {t['topic_metadata']['name']: t['message_count']
            for t in meta['topics_with_message_count']} == _counts(sent)
    assert meta['starting_time']['nanoseconds_since_epoch'] == sent[0][2]
    assert meta['duration']['nanoseconds'] == sent[-1][2] - sent[0][2]


def _assert_stopped_bag_holds(path, sent, tmp_path):
    """The bag a write error stopped: its file ends after its last complete chunk, without
    summary and footer, as a killed recorder's does; the reader takes exactly ``sent`` from
    it, and `lightstage bag recover` (the recovery path) makes it a complete bag."""
    reader = lr.BagReader(path)
    info = reader.info()
    assert not info.complete and info.message_count == len(sent)
    assert {t.name: t.count for t in info.topics.values()} == _counts(sent)
    (problem,) = [p for p in info.problems if 'MCAP footer' in p]
    assert problem.startswith('run_0.mcap ends at byte ') and 'without the MCAP footer' in problem
    assert not any('cut off' in p or 'damaged' in p for p in info.problems), info.problems
    assert [(m.topic, m.data, m.log_time_ns) for m in reader.messages()] == sent
    assert 'INCOMPLETE BAG' in lr.format_info(info)
    fixed = recover(path, tmp_path / 'fixed')
    assert fixed.complete and fixed.message_count == len(sent)
    _assert_bag_holds(tmp_path / 'fixed', sent)


@pytest.mark.parametrize('code, head, todo', [
    (errno.ENOSPC, 'disk full writing', 'free space and record again'),
    (errno.EIO, 'cannot write', 'check the disk and record again')])
def test_a_write_error_stops_the_recording_and_closes_the_bag_with_what_it_holds(
        tmp_path, monkeypatch, code, head, todo):
    """The 7th chunk fails (half of it reaches the disk); space is back when the bag closes."""
    disk = FailingDisk(monkeypatch, after_chunks=6, code=code, stays_full=False)
    bag = tmp_path / 'run'
    rec = _recording(bag)
    sent = _record(rec, range(6))
    topic, data = _message(6)
    assert rec.receive(topic, data, _info(6))  # into the chunk in progress
    assert not rec.flush()  # the chunk does not reach the disk: the recording stops
    assert disk.failures == 1 and rec.stopped
    for i in (7, 8):
        assert not rec.receive(*_message(i), _info(i))  # not written, counted
    assert not rec.flush() and not rec.add_topic('/late', ILLUM)
    assert rec.dropped == 2
    error = rec.close()
    assert error == rec.error and error.startswith(f'{head} {bag}: {os.strerror(code)}; ')
    assert (f'; the bag holds everything up to {lr.format_time(sent[-1][2])}: 6 messages; '
            'run_0.mcap ends after its last complete chunk, without a summary: '
            f'`lightstage bag recover {bag}` writes a complete copy; {todo}' in error), error
    report = rec.report(1.0)
    assert report.startswith(f'RECORDING STOPPED: {error}\nrecorded 6 messages on 2 topics'), report
    assert 'the chunk in progress at the error and the 2 messages that arrived from then on' in report
    assert not rec.writer.summary_written and rec.writer.metadata_written
    _assert_metadata_yaml_lists(bag, sent)
    _assert_stopped_bag_holds(bag, sent, tmp_path)


def test_a_disk_full_when_the_bag_is_closed_keeps_every_flushed_chunk(tmp_path, monkeypatch):
    """Closing writes the chunk in progress first: that fails, and the file ends after the
    last chunk that was flushed."""
    disk = FailingDisk(monkeypatch, after_chunks=5, stays_full=False)
    bag = tmp_path / 'run'
    rec = _recording(bag)
    sent = _record(rec, range(5))
    _record(rec, [6], flush=False)  # small: stays in the chunk in progress
    assert not rec.stopped
    error = rec.close()
    assert disk.failures == 1
    assert error.startswith(f'disk full writing {bag}: ') and ': 5 messages; ' in error
    _assert_metadata_yaml_lists(bag, sent)
    _assert_stopped_bag_holds(bag, sent, tmp_path)


def test_a_disk_that_stays_full_leaves_a_bag_that_ends_after_its_last_complete_chunk(
        tmp_path, monkeypatch):
    """No metadata.yaml can be written either; the torn chunk is taken back, so the file reads
    like that of a recorder killed between two flushes, and recover completes it."""
    disk = FailingDisk(monkeypatch, after_chunks=4, stays_full=True)
    bag = tmp_path / 'run'
    rec = _recording(bag)
    sent = _record(rec, range(4))
    assert not rec.receive(*_message(5), _info(5))  # an image: a chunk of its own, which fails
    error = rec.close()
    assert disk.failures == 2  # the chunk, metadata.yaml
    assert error.startswith(f'disk full writing {bag}: ') and ': 4 messages; ' in error
    assert 'metadata.yaml could not be written' in error
    assert not rec.writer.summary_written and not rec.writer.metadata_written
    assert sorted(p.name for p in bag.iterdir()) == ['run_0.mcap']  # no leftover metadata.yaml.tmp
    disk.full = disk.stays_full = False  # space again
    _assert_stopped_bag_holds(bag, sent, tmp_path)


def test_the_bag_writer_context_manager_raises_when_close_could_not_write(tmp_path, monkeypatch):
    disk = FailingDisk(monkeypatch)
    with pytest.raises(lr.BagWriteError, match='disk full writing .*holds everything up to'):
        with lr.BagWriter(tmp_path / 'b', chunk_size_bytes=1024) as w:
            w.add_topic('/illumination', ILLUM)
            w.write('/illumination', _message(0)[1], T0)
            w.flush()
            disk.full = True
            w.write('/illumination', _message(2)[1], T0 + 1)
    assert w.message_count == 1


# ----------------------------------------------------------------------------- durability


def test_flush_hands_the_chunk_to_the_os_and_close_fsyncs_file_metadata_and_directory(
        tmp_path, monkeypatch):
    """docs/RECORDING.md: the periodic flush does not fsync (a killed recorder loses nothing
    flushed; a power loss may lose what the OS has not yet written back); close fsyncs the
    MCAP file, metadata.yaml and the bag directory."""
    synced = []
    real_fsync = os.fsync

    def fsync(fd):
        synced.append(os.readlink(f'/proc/self/fd/{fd}'))
        return real_fsync(fd)

    monkeypatch.setattr(fileio.os, 'fsync', fsync)
    bag = tmp_path / 'run'
    w = lr.BagWriter(bag, chunk_size_bytes=1 << 20)
    w.add_topic('/illumination', ILLUM)
    w.write('/illumination', _message(0)[1], T0)
    w.flush()
    assert synced == []
    # what was flushed is in the file for any other process (a killed writer loses none of it)
    assert [m.log_time_ns for m in lr.BagReader(bag).messages()] == [T0]
    w.close()
    real = bag.resolve()
    assert synced[0] == str(real / 'run_0.mcap')
    assert str(real / 'metadata.yaml.tmp') in synced  # fsynced before the rename
    assert str(real) in synced and str(real.parent) in synced  # the new names in both directories


def test_output_dir_may_be_new_or_an_empty_directory_nothing_else(tmp_path):
    """ros2 bag record refuses any existing output folder; here an existing empty one is
    used (the recorder's output_dir, `lightstage record -o`, `bag recover -o`), and the
    docs and the parameter description say so."""
    empty = tmp_path / 'empty'
    empty.mkdir()
    with lr.BagWriter(empty) as w:
        w.add_topic('/illumination', ILLUM)
        w.write('/illumination', _message(0)[1], T0)
    assert sorted(p.name for p in empty.iterdir()) == ['empty_0.mcap', 'metadata.yaml']
    assert lr.BagReader(empty).info().message_count == 1
    with pytest.raises(lr.BagError, match='already exists and is not empty; choose another output '
                                          'directory or delete it'):
        lr.BagWriter(empty)
    (tmp_path / 'file').write_text('x')
    with pytest.raises(lr.BagError, match='already exists and is not a directory'):
        lr.BagWriter(tmp_path / 'file')
    assert (tmp_path / 'file').read_text() == 'x'
    with lr.BagWriter(tmp_path / 'new' / 'deeper'):
        pass
    assert (tmp_path / 'new' / 'deeper' / 'metadata.yaml').is_file()
    # the docs and the parameter description
    doc = (REPO / 'docs' / 'RECORDING.md').read_text()
    (row,) = [line for line in doc.splitlines() if line.startswith('| `output_dir` |')]
    assert 'must not exist, or be an empty directory' in row, row
    from lightstage_recording.recorder_node import PARAMETERS
    assert 'must not exist, or be an empty directory' in PARAMETERS['output_dir'][1].description


# ----------------------------------------------------------------------------- the node


@pytest.mark.ros
def test_the_recorder_node_ends_the_recording_on_a_write_error(tmp_path, monkeypatch):
    """The node's part: its callbacks go through `Recording`; the first error ends the run
    (``done`` is set, `run` then closes the bag and exits 1) and the report leads with it."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from lightstage_recording.recorder_node import RecorderNode
    from helpers.suite import fresh_domain_id
    disk = FailingDisk(monkeypatch, after_chunks=1)
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id(),
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        bag = tmp_path / 'run'
        node = RecorderNode(context=context, parameter_overrides=[
            Parameter('output_dir', value=str(bag)), Parameter('chunk_size_bytes', value=1024),
            Parameter('topics', value=['/image_raw'])])
        try:
            assert node.recording.add_topic('/image_raw', IMG, [RELIABLE])
            on_message = node._writer_callback('/image_raw')
            on_message(_message(1)[1], _info(1))  # an image: a chunk of its own
            assert not node.done.done() and disk.chunks == 1
            on_message(_message(3)[1], _info(3))
            assert node.done.done() and node.done.result() is False
            report = node.finish()
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    assert report.startswith(f'RECORDING STOPPED: disk full writing {bag}: '), report
    assert '\n  /image_raw: 1 (sensor_msgs/msg/Image)\n' in report
    assert lr.BagReader(bag).info().message_count == 1
