"""Bags split by size or duration as rosbag2 splits them (NAME_0.mcap, NAME_1.mcap, ...,
metadata.yaml listing every file), a bounded number of files kept, and every reader path
(info, messages, recover, rosbags) taking split bags. In-process, no ROS."""
import shutil

import pytest
import yaml
from rclpy.serialization import serialize_message

import lightstage_recording as lr
from lightstage_recording import bag_cli
from helpers.recording import image, result
from helpers.write_faults import FailingDisk

pytestmark = pytest.mark.process

T0 = 1_700_000_000_000_000_000
IMG = 'sensor_msgs/msg/Image'
RESULT = 'lightstage_interfaces/msg/ClassificationResult'
IMAGE_BYTES = len(serialize_message(image(seed=0)))  # 28.8 kB at 120 px


def _write(path, n, step_ns=100_000_000, flush_every=0, **limits):
    """n images (and a result after every 4th) 0.1 s apart; returns the writer (closed) and
    what was written, in order."""
    sent = []
    w = lr.BagWriter(path, chunk_size_bytes=64 * 1024, **limits)
    w.add_topic('/image_raw', IMG)
    w.add_topic('/lightstage/result', RESULT)
    try:
        for i in range(n):
            t = T0 + i * step_ns
            data = serialize_message(image(seed=i))
            w.write('/image_raw', data, t)
            sent.append(('/image_raw', data, t))
            if i % 4 == 3:
                data = serialize_message(result(label=f'label-{i}'))
                w.write('/lightstage/result', data, t + 1)
                sent.append(('/lightstage/result', data, t + 1))
            if flush_every and i % flush_every == 0:
                w.flush()
    except lr.BagWriteError:
        w.close()  # as the recorder does: the bag is closed with what it holds
        raise
    return w, sent


def _metadata(path):
    return yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def _read(path):
    return [(m.topic, m.data, m.log_time_ns) for m in lr.BagReader(path).messages()]


def test_split_by_size_names_files_as_rosbag2_and_lists_each(tmp_path):
    bag = tmp_path / 'sized'
    limit = 200 * 1024
    w, sent = _write(bag, 40, max_bag_size_bytes=limit)
    w.close()
    files = sorted(bag.glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1]))
    assert [f.name for f in files] == [f'sized_{i}.mcap' for i in range(len(files))]
    assert len(files) >= 5  # 40 x 28.8 kB in 200 kB files
    summary_slack = 16 * 1024  # the summary and footer come after the last chunk
    assert all(f.stat().st_size <= limit + summary_slack for f in files[:-1]), \
        [f.stat().st_size for f in files]
    meta = _metadata(bag)
    assert meta['relative_file_paths'] == [f.name for f in files]
    assert [e['path'] for e in meta['files']] == [f.name for f in files]
    assert sum(e['message_count'] for e in meta['files']) == meta['message_count'] == len(sent)
    assert meta['files'][0]['starting_time']['nanoseconds_since_epoch'] == T0
    for e in meta['files']:  # each file is a complete MCAP file with its own counts
        info = lr.BagReader(bag / e['path']).info()
        assert info.complete and info.message_count == e['message_count']
        assert set(info.topics) == {'/image_raw', '/lightstage/result'}  # every channel in each
    assert _read(bag) == sent
    info = lr.BagReader(bag).info(verify=True)
    assert info.complete and info.message_count == len(sent) and info.verified
    assert {t.name: t.count for t in info.topics.values()} == {'/image_raw': 40, '/lightstage/result': 10}
    # an independent reader takes the split bag as rosbag2 lays it out
    from rosbags.rosbag2 import Reader
    with Reader(bag) as reader:
        assert reader.message_count == len(sent)
        assert [bytes(raw) for _, _, raw in reader.messages()] == [s[1] for s in sent]


def test_split_by_duration(tmp_path):
    bag = tmp_path / 'timed'
    w, sent = _write(bag, 25, max_bag_duration_s=1.0)  # 2.5 s of messages 0.1 s apart
    w.close()
    meta = _metadata(bag)
    assert [e['path'] for e in meta['files']] == ['timed_0.mcap', 'timed_1.mcap', 'timed_2.mcap']
    # a file ends before the first message logged 1 s after its first one
    assert [e['message_count'] for e in meta['files']] == [10 + 2, 10 + 3, 5 + 1]
    assert all(e['duration']['nanoseconds'] < 1_000_000_000 for e in meta['files'])
    assert _read(bag) == sent
    assert [e.split(' ')[0] for e in w.events] == ['timed_0.mcap', 'timed_1.mcap']
    assert 'max_bag_duration_s 1 reached' in w.events[0]


def test_max_bag_files_keeps_the_newest_and_says_what_was_deleted(tmp_path, capsys):
    bag = tmp_path / 'bounded'
    told = []
    w, sent = _write(bag, 25, max_bag_duration_s=1.0, max_bag_files=2, on_event=told.append)
    w.close()
    assert sorted(p.name for p in bag.glob('*.mcap')) == ['bounded_1.mcap', 'bounded_2.mcap']
    meta = _metadata(bag)
    assert meta['relative_file_paths'] == ['bounded_1.mcap', 'bounded_2.mcap']
    kept = sent[12:]  # the first file held 10 images and 2 results
    assert meta['message_count'] == len(kept) and _read(bag) == kept
    assert meta['starting_time']['nanoseconds_since_epoch'] == kept[0][2]
    assert {t['topic_metadata']['name']: t['message_count']
            for t in meta['topics_with_message_count']} == {'/image_raw': 15, '/lightstage/result': 4}
    note = meta['custom_data']['deleted_files']
    assert note.startswith('1 oldest files (bounded_0.mcap .. bounded_0.mcap, 12 messages logged from')
    assert 'to keep max_bag_files 2' in note
    assert 'bounded_0.mcap deleted (12 messages) to keep max_bag_files 2' in told
    assert bag_cli.bag_main(['info', str(bag)]) == 0
    out = capsys.readouterr().out
    assert 'Files:             bounded_1.mcap, bounded_2.mcap' in out
    assert f'NOT KEPT: {note}' in out


def test_a_killed_writer_of_a_split_bag_loses_only_its_unflushed_chunk(tmp_path, capsys):
    """What a SIGKILLed recorder leaves: its closed files complete, the one in progress without
    summary, no metadata.yaml. Every flushed message reads, and `bag recover` gives all back."""
    bag = tmp_path / 'live'
    w, sent = _write(bag, 30, max_bag_duration_s=1.0, flush_every=1)
    flushed = len(sent)
    w.write('/image_raw', serialize_message(image(seed=99)), T0 + 31 * 100_000_000)  # not flushed
    killed = tmp_path / 'killed'
    killed.mkdir()
    for f in w.files:  # the files as they are on disk at the kill
        shutil.copy(f, killed / f.name.replace('live', 'killed'))
    w.close()
    assert len(list(killed.glob('*.mcap'))) == 4
    reader = lr.BagReader(killed)
    info = reader.info()
    assert not info.complete and not info.has_metadata_yaml
    assert _read(killed) == sent[:flushed]
    assert bag_cli.bag_main(['recover', str(killed)]) == 0
    out = capsys.readouterr().out
    assert f'recovered {flushed} messages on 2 topics' in out, out
    assert _read(tmp_path / 'killed_recovered') == sent[:flushed]


def test_disk_full_in_a_split_bag_keeps_the_closed_files_and_counts_what_is_held(tmp_path,
                                                                                monkeypatch):
    bag = tmp_path / 'full'
    # one failed write (a torn chunk), then the disk takes metadata.yaml again
    disk = FailingDisk(monkeypatch, after_chunks=9, stays_full=False)
    with pytest.raises(lr.BagWriteError, match='disk full writing'):
        _write(bag, 40, max_bag_size_bytes=150 * 1024)
    monkeypatch.undo()
    assert disk.failures
    meta = _metadata(bag)
    assert len(meta['files']) >= 3
    held = _read(bag)
    assert meta['message_count'] == sum(e['message_count'] for e in meta['files']) == len(held)
    assert 0 < len(held) < 50
    # the closed files are complete; the one in progress ends after its last complete chunk
    info = lr.BagReader(bag).info(verify=True)
    last = meta['files'][-1]['path']
    assert [p for p in info.problems if 'MCAP footer' in p] == [
        p for p in info.problems if p.startswith(f'{last} ends at byte ')], info.problems
    assert len(info.problems) == 1 and not info.complete
    assert bag_cli.bag_main(['recover', str(bag)]) == 0
    assert _read(tmp_path / 'full_recovered') == held


def test_split_limits_are_checked(tmp_path):
    with pytest.raises(lr.BagError, match='max_bag_size_bytes 100 is too small; use 0'):
        lr.BagWriter(tmp_path / 'a', max_bag_size_bytes=100)
    with pytest.raises(lr.BagError, match='must be >= 0'):
        lr.BagWriter(tmp_path / 'b', max_bag_files=-1)
    assert not (tmp_path / 'a').exists() and not (tmp_path / 'b').exists()
