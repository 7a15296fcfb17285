"""`make demo` leaves the bag of its stage session and prints the commands that replay it into
a classifier that only observes; running those commands gives the recorded labels again.

A short stage session of the demo's own code (`demo._on_stage`: driver, camera, classifier and
the recorder as processes; two samples, each classified with 8 and then 4 images), recorded
with a small max_bag_size_bytes so that the bag is split, then the two printed commands.
"""
import re
import shlex
import signal
import subprocess

import pytest

from lightstage_bringup import demo
from lightstage_recording import BagReader
from lightstage_graph.ros_env import ros_environment
from recording_helpers import bag_results
from suite_helpers import GraphClient, fresh_domain_id, lightstage_command

pytestmark = pytest.mark.ros

SAMPLES = ['banana-fake/s0/p01', 'orange-real/s1/p02']


def _run_printed(command: str, domain_id: int, **kwargs):
    argv = shlex.split(command)
    assert argv[0] == 'lightstage'
    return lightstage_command(*argv[1:]), dict(env=ros_environment(domain_id), text=True, **kwargs)


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
    assert [(r.label, r.images_used) for r in recorded] == \
        [(row['label'], row['images_used']) for row in calls]

    # the printed commands, as a user runs them in two terminals
    client = GraphClient(domain_id)
    replayed = []
    client.node.create_subscription(ClassificationResult, '/lightstage/result', replayed.append, 10)
    up_argv, up_kwargs = _run_printed(commands[0], domain_id)
    classifier = subprocess.Popen(up_argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  **up_kwargs)
    try:
        client.spin_until(lambda: client.node.count_publishers('/lightstage/result') > 0, 60.0,
                          'the observing classifier')
        play_argv, play_kwargs = _run_printed(commands[1], domain_id)
        p = subprocess.run(play_argv, capture_output=True, timeout=180, **play_kwargs)
        assert p.returncode == 0, p.stdout + p.stderr
        client.spin_until(lambda: len(replayed) >= len(recorded), 30.0,
                          lambda: f'{len(recorded)} replayed results (got {len(replayed)})')
    finally:
        classifier.send_signal(signal.SIGINT)
        log, _ = classifier.communicate(timeout=60)
        client.close()
    by_sequences = {tuple(r.sequences): r for r in replayed}
    for r in recorded:  # every call (8 and 4 images: both use the artifact's first patterns)
        again = by_sequences[tuple(r.sequences)]
        assert (again.label, again.images_used) == (r.label, r.images_used), log
