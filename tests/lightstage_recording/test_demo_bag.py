"""`make demo` leaves the bag of its stage session and prints the commands that replay it into
a classifier that only observes; running those commands gives the recorded labels again.

A stage session of the demo's own code (`demo._on_stage`: driver, camera, classifier and the
recorder as processes; 15 samples, each classified with 8 and then 4 images: 30 calls),
recorded with a small max_bag_size_bytes so that the bag is split, then the two printed
commands. The first starts the observing classifier *and a recorder* (`lightstage up`
records unless --no-record), which subscribes to the same topics as the classifier while
the bag plays: every one of the 30 labels must come back all the same (with the
recorder on, 2 to 4 of the demo's 30 did), and the recorder must have recorded every image.
"""
import re
import shlex
import signal
import subprocess

import pytest

from lightstage_bringup import demo
from lightstage_recording import BagReader
from lightstage_graph.ros_env import ros_environment
from helpers.recording import bag_results
from lightstage_graph.graph_client import GraphTimeout
from helpers.suite import GraphClient, fresh_domain_id, lightstage_command

pytestmark = [pytest.mark.ros, pytest.mark.process]

# 15 of the stage capture's 24 models, both types and variants
SAMPLES = [f'{kind}/s{s}/p{p:02d}' for kind in ('banana-fake', 'banana-real', 'orange-fake',
                                                 'orange-real')
           for s in (0, 1) for p in (0, 1)][:15]


def _run_printed(command: str, domain_id: int, **kwargs):
    argv = shlex.split(command)
    assert argv[0] == 'lightstage'
    return lightstage_command(*argv[1:]), dict(env=ros_environment(domain_id), text=True, **kwargs)


@pytest.mark.slow
def test_the_demo_leaves_its_bag_and_its_replay_command_reproduces_the_labels(
        stage_capture, stage_artifact_path, tmp_path, capsys):
    from lightstage_interfaces.msg import ClassificationResult
    domain_id = fresh_domain_id()
    # the demo's two methods, here one artifact used with 8 and with 4 images
    summary = {'greedy': {'artifact': str(stage_artifact_path), 'best_n_images': 8},
               'naive': {'artifact': str(stage_artifact_path), 'best_n_images': 4}}
    results = demo._on_stage(tmp_path, stage_capture, summary, SAMPLES, domain_id,
                             recorder={'max_bag_size_bytes': 256 * 1024})
    out = capsys.readouterr().out
    bag = tmp_path / demo.BAG
    assert f'[demo] stage session recorded: {bag} (' in out, out
    commands = re.findall(r'^\[demo\]   (lightstage .*)$', out, re.MULTILINE)
    assert [c.split()[:2] for c in commands] == [['lightstage', 'up'], ['lightstage', 'play']], out

    info = BagReader(bag).info(verify=True)
    assert info.complete and len(info.files) > 1  # split by max_bag_size_bytes
    recorded = bag_results(bag)
    calls = [row for method in ('greedy', 'naive') for row in results[method]]
    assert len(calls) == 30
    assert [(r.label, r.images_used) for r in recorded] == \
        [(row['label'], row['images_used']) for row in calls]
    played_images = sum(1 for _ in BagReader(bag).messages(['/camera/image_raw']))
    assert played_images == sum(row['images_used'] for row in calls)

    # the printed commands, as a user runs them in two terminals
    client = GraphClient(domain_id)
    replayed = []
    # deep enough for every result: this client does not spin while the bag plays
    client.node.create_subscription(ClassificationResult, '/lightstage/result', replayed.append, 100)
    up_argv, up_kwargs = _run_printed(commands[0], domain_id)
    assert '--no-record' not in up_argv  # the recorder runs beside the observing classifier
    classifier = subprocess.Popen(up_argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  cwd=tmp_path, **up_kwargs)
    try:
        client.spin_until(lambda: client.node.count_publishers('/lightstage/result') > 0, 60.0,
                          'the observing classifier')
        play_argv, play_kwargs = _run_printed(commands[1], domain_id)
        p = subprocess.run(play_argv, capture_output=True, timeout=180, **play_kwargs)
        assert p.returncode == 0, p.stdout + p.stderr
        try:
            client.spin_until(lambda: len(replayed) >= len(recorded), 30.0,
                              lambda: f'{len(recorded)} replayed results (got {len(replayed)})')
            missed = None
        except GraphTimeout as exc:
            missed = exc
    finally:
        classifier.send_signal(signal.SIGINT)
        log, _ = classifier.communicate(timeout=60)
        client.close()
    assert missed is None, f'{missed}; the classifier said:\n{log}'
    by_sequences = {tuple(r.sequences): r for r in replayed}
    for r in recorded:  # every call (8 and 4 images: both use the artifact's first patterns)
        again = by_sequences.get(tuple(r.sequences))
        assert again is not None, log
        assert (again.label, again.images_used) == (r.label, r.images_used), log
    assert 'not classified' not in log, log
    # the recorder `lightstage up` started was on the same topic meanwhile (it subscribes
    # within its discovery period of the player's publishers appearing, which the player does
    # not wait for: it may miss the first images, not the bulk)
    (replay_bag,) = (tmp_path / 'out' / 'bags').iterdir()
    recorded_again = sum(1 for _ in BagReader(replay_bag).messages(['/camera/image_raw']))
    assert played_images // 2 <= recorded_again <= played_images
