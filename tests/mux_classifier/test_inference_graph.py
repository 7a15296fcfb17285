"""End to end: driver (sim firmware), sim camera and classifier as processes, classify over samples.

Every node runs in its own process through the bring-up supervisor, in a domain id of this
test's own with LOCALHOST discovery; the test talks to them from an in-process client.
The classifier answers every request and survives every artifact file: fuzzed
Classify requests and artifact_path files.

LIGHTSTAGE_FUZZ_EXAMPLES=N runs N examples per fuzz test here (default: a few, they go
through the graph).
"""
import itertools
import json
import math
import os
import re
import subprocess
import sys
import threading
import zipfile
from pathlib import Path
from typing import NamedTuple

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from lightstage_bringup.supervisor import Supervisor
from mux_classifier.classify_request import MAX_IMAGES_MAX, TIMEOUT_MAX_S, TIMEOUT_MIN_S

from helpers.artifact_mutations import mutated_artifacts
from helpers.suite import (GraphClient, classify_on_the_stage_graph, fresh_domain_id, stage_graph_params,
                           start_nodes, write_params)

pytestmark = [pytest.mark.ros, pytest.mark.process]

# samples of both object types and both variants; the classifier was trained on these poses
# with fresh noise, so the labels are the ones it should give back
SAMPLES = ['banana-fake/s0/p01', 'orange-real/s1/p02', 'banana-real/s1/p00',
           'orange-fake/s0/p00', 'banana-real/s0/p02', 'orange-real/s0/p01']


def valid_timeout(timeout_s: float) -> bool:
    return timeout_s == 0 or TIMEOUT_MIN_S <= timeout_s <= TIMEOUT_MAX_S


def refusal(timeout_s: float) -> str:
    """The node's answer to a request time limit outside its contract."""
    return ("timeout_s must be 0 (the classifier node's default) or between 0.1 and 600 s; "
            f"got {timeout_s!r}")


def classify(client, max_images=0, timeout_s=10.0):
    from lightstage_interfaces.srv import Classify
    # 0 = the node's default (10 s here); a time limit outside the contract is refused at once
    limit_s = timeout_s if valid_timeout(timeout_s) and timeout_s > 0 else 10.0
    return client.call(Classify, '/lightstage/classify',
                       Classify.Request(max_images=max_images, timeout_s=timeout_s),
                       timeout_s=limit_s + 10)


class Graph(NamedTuple):
    client: GraphClient
    domain_id: int
    supervisor: Supervisor


@pytest.fixture(scope='module')
def graph(stage_capture, stage_artifact_path, tmp_path_factory):
    domain_id = fresh_domain_id()
    params = write_params(tmp_path_factory.mktemp('graph') / 'params.yaml',
                          stage_graph_params(stage_capture, SAMPLES[0], 3, stage_artifact_path))
    client = GraphClient(domain_id)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            yield Graph(client, domain_id, supervisor)
    finally:
        client.close()


def test_classify_over_samples_is_complete_consistent_and_accurate(graph):
    from lightstage_interfaces.msg import ClassificationResult
    client = graph.client
    results = []
    client.node.create_subscription(ClassificationResult, '/lightstage/result', results.append, 10)
    answers = []
    for i, sample in enumerate(SAMPLES):
        (ok,) = client.set_parameters('camera', sample=sample)
        assert ok.successful, ok.reason
        requested = 4 if i % 2 else 8
        r = classify(client, max_images=requested)
        assert r.success, r.message
        assert r.images_used == requested
        assert list(r.class_names) == ['banana-fake', 'banana-real', 'orange-fake', 'orange-real']
        assert r.label in r.class_names
        assert len(r.scores) == len(r.class_names)
        assert r.label == r.class_names[max(range(len(r.scores)), key=lambda k: r.scores[k])]
        assert r.acquisition_ms > 0 and r.compute_ms > 0
        # the driver exposes each pattern for the artifact's 22.5 ms (sigma3): a floor
        assert r.acquisition_ms > requested * 22.5 * 0.9
        answers.append((sample.split('/')[0], r.label))
    client.spin_for(0.5)
    assert [m.label for m in results] == [label for _, label in answers]
    assert all(len(m.sequences) == m.images_used for m in results)
    # consecutive triggers, and the next call's triggers follow the previous call's
    seqs = [s for m in results for s in m.sequences]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    same_type = sum(t.split('-')[0] == p.split('-')[0] for t, p in answers)
    exact = sum(t == p for t, p in answers)
    assert same_type == len(SAMPLES), answers  # banana vs orange: clearly separable
    assert exact >= len(SAMPLES) - 1, answers


def test_an_artifact_on_pose_robust_features_classifies_on_the_stage(
        graph, stage_intensity_artifact_path, stage_artifact_path):
    """An artifact whose classifiers use `intensity_stats` (recorded in its
    header), set at run time, classifies the stage's samples through the graph."""
    from mux_classifier.artifact import TrainedArtifact
    client = graph.client
    assert TrainedArtifact.load(stage_intensity_artifact_path).features == 'intensity_stats'
    (ok,) = client.set_parameters('classifier', artifact_path=str(stage_intensity_artifact_path))
    assert ok.successful, ok.reason
    try:
        answers = []
        for sample in SAMPLES:
            (ok,) = client.set_parameters('camera', sample=sample)
            assert ok.successful, ok.reason
            r = classify(client, max_images=8)
            assert r.success, r.message
            assert r.images_used == 8
            answers.append((sample.split('/')[0], r.label))
        assert sum(t.split('-')[0] == p.split('-')[0] for t, p in answers) == len(SAMPLES), answers
        assert sum(t == p for t, p in answers) >= len(SAMPLES) - 1, answers
    finally:
        (ok,) = client.set_parameters('classifier', artifact_path=str(stage_artifact_path))
        assert ok.successful, ok.reason


def test_a_classify_as_soon_as_the_nodes_spin_gets_every_frame(stage_capture, stage_artifact_path,
                                                              tmp_path):
    """Nothing waits for the stage's links here, as for a user who classifies as soon as
    `lightstage up` is up: the driver and the camera wait for the readers the graph shows
    and their publishers have not matched yet (lightstage_graph.links), so no trigger or
    frame of the first sequence is published into a link that is not there yet."""
    sample = SAMPLES[1]
    params = write_params(tmp_path / 'params.yaml',
                          stage_graph_params(stage_capture, sample, 3, stage_artifact_path))
    answer, seen = classify_on_the_stage_graph(params, fresh_domain_id(), '--max-images', '8',
                                               n_illumination=8, wait_links=False)
    assert answer['success'] and answer['images_used'] == 8, answer
    assert answer['label'].split('-')[0] == sample.split('-')[0], answer
    assert len(seen) == 8


def test_unknown_sample_is_rejected_and_the_stage_keeps_its_sample(graph):
    client = graph.client
    (ok,) = client.set_parameters('camera', sample='orange-real/s0/p01')
    assert ok.successful
    (bad,) = client.set_parameters('camera', sample='kiwi-real/s9/p99')
    assert not bad.successful and 'unknown sample' in bad.reason
    r = classify(client)
    assert r.success and r.label.startswith('orange'), (r.label, r.message)

def test_a_sim_camera_at_another_dimmer_is_refused(graph):
    """The artifact records its training dimmer (0.45); a sim camera rendering at 0.3 would
    give images 0.67 x as bright and classify wrong silently: the classifier refuses."""
    client = graph.client
    (ok,) = client.set_parameters('camera', dimmer=0.3)
    assert ok.successful, ok.reason
    try:
        r = classify(client)
        assert not r.success
        assert "trained with dimmer 0.45 but the camera's dimmer is 0.3" in r.message, r.message
    finally:
        (ok,) = client.set_parameters('camera', dimmer=0.45)
        assert ok.successful, ok.reason
    r = classify(client)
    assert r.success, r.message



def _burst(client, n, **request):
    """`n` Classify calls sent at once from one client; their answers, in sending order."""
    from lightstage_interfaces.srv import Classify
    service = client.service(Classify, '/lightstage/classify')
    client.spin_until(service.service_is_ready, 10.0, 'the classify service')
    futures = [service.call_async(Classify.Request(**request)) for _ in range(n)]
    client.spin_until(lambda: all(f.done() for f in futures), 300.0,
                      lambda: f'{sum(not f.done() for f in futures)} of {n} answers')
    return [f.result() for f in futures]


def _served_order(answers, results):
    """Which answer each result (published in the order calls are served) belongs to, tied by
    the timings both carry."""
    return [next(i for i, r in enumerate(answers)
                 if (r.acquisition_ms, r.compute_ms) == (m.acquisition_ms, m.compute_ms))
            for m in results]


def test_twenty_concurrent_calls_are_all_served_in_order(graph):
    """Four or more concurrent calls all failed: every executor thread waited for the stage,
    none was left for the driver's reply. Twenty at once, each with time enough to wait its
    turn: every one classifies, one at a time, in the order sent, and the node stays up."""
    from lightstage_interfaces.msg import ClassificationResult
    client = graph.client
    (ok,) = client.set_parameters('camera', sample='orange-real/s0/p01')
    assert ok.successful, ok.reason
    results = []
    client.node.create_subscription(ClassificationResult, '/lightstage/result', results.append, 100)
    client.spin_for(0.5)
    answers = _burst(client, 20, max_images=4, timeout_s=300.0)
    assert all(r.success for r in answers), [r.message for r in answers if not r.success]
    client.spin_until(lambda: len(results) >= 20, 10.0, 'the 20 results')
    assert _served_order(answers, results[-20:]) == list(range(20))
    # one sequence after the other on the stage, never interleaved
    seqs = [s for m in results[-20:] for s in m.sequences]
    assert seqs == list(range(seqs[0], seqs[0] + 80))
    assert all(r.label.startswith('orange') for r in answers)
    assert not graph.supervisor.exited()


def test_calls_beyond_what_fits_their_time_limit_are_refused_at_once(graph):
    """Twenty at once with 1.5 s each: those the stage can serve in time classify, in order;
    the others are refused with the reason (the calls ahead of them, the time limit) instead
    of failing after it; none is left unanswered and the stage classifies afterwards."""
    from lightstage_interfaces.msg import ClassificationResult
    client = graph.client
    results = []
    client.node.create_subscription(ClassificationResult, '/lightstage/result', results.append, 100)
    classify(client, max_images=4)  # the queue has learnt how long a call takes
    client.spin_until(lambda: results, 10.0, 'the first result')
    answers = _burst(client, 20, max_images=4, timeout_s=1.5)
    served = [i for i, r in enumerate(answers) if r.success]
    refused = [r.message for r in answers if not r.success]
    assert served and refused
    client.spin_until(lambda: len(results) >= 1 + len(served), 10.0, 'the results')
    assert _served_order(answers, results[1:]) == served  # in the order sent
    for message in refused:
        assert ('ahead of this one would keep the stage busy' in message
                or 'less than a call takes' in message), message
        assert 'timeout_s' in message, message
    r = classify(client, max_images=4)
    assert r.success, r.message
    assert not graph.supervisor.exited()


def test_a_stopped_camera_is_refused_not_skipped(graph):
    """A camera stopped with SIGSTOP made the classifier skip its dimmer check after 2 s and
    light the stage anyway ("its dimmer is not checked"); the check fails closed: the call is
    refused naming the camera, and classifies again once the camera runs."""
    import signal
    client = graph.client
    r = classify(client, max_images=4)  # the camera is matched and answering
    assert r.success, r.message
    camera = graph.supervisor['camera']
    os.kill(camera.pid, signal.SIGSTOP)
    try:
        r = classify(client, max_images=4, timeout_s=5.0)
    finally:
        os.kill(camera.pid, signal.SIGCONT)
    assert not r.success
    assert re.match(r"not classifying: the camera node 'camera' did not answer a parameter "
                    r'query within [\d.]+ s, so its dimmer cannot be checked', r.message), r.message
    r = classify(client, max_images=4)
    assert r.success, r.message
    assert not graph.supervisor.exited()


def test_classify_cli_prints_the_answer(graph):
    domain_id = graph.domain_id
    # the installed command, as a user runs it (its exit tears the client down differently
    # from `python -m`)
    lightstage = str(Path(sys.executable).with_name('lightstage'))
    p = subprocess.run([lightstage, 'classify', '--domain-id', str(domain_id), '--json',
                        '--max-images', '4'], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    # every successful call ended in `Exception ignored in: <function
    # Executor.__del__> ... InvalidHandle`; the client now closes in order
    assert 'Exception ignored' not in p.stderr and 'Traceback' not in p.stderr, p.stderr
    answer = json.loads(p.stdout)
    assert answer['success'] and answer['images_used'] == 4
    assert answer['label'] in answer['class_names']


FUZZ_EXAMPLES = int(os.environ.get('LIGHTSTAGE_FUZZ_EXAMPLES', 0))
SPECIAL_TIMEOUTS = [0.0, -0.0, 1e-6, 0.1, 600.0, 600.0000001, 1e10, threading.TIMEOUT_MAX,
                    math.inf, -math.inf, math.nan, -1.0, 5e-324]


def test_request_time_limits_outside_the_contract_are_refused(graph):
    """Timeout_s above threading.TIMEOUT_MAX killed the node (OverflowError
    in the stage lock's acquire); negative and NaN were silently replaced by the default;
    1e-6 answered 'timeout_s must be > 0, got -9.43e-06'. Each is refused, naming the value."""
    for bad in [1e10, threading.TIMEOUT_MAX * 2, -1.0, math.nan, math.inf, -math.inf, 1e-6]:
        r = classify(graph.client, timeout_s=bad)
        assert not r.success and r.message == refusal(bad)
    assert not graph.supervisor.exited()
    r = classify(graph.client, max_images=4, timeout_s=0.0)  # 0: the node's timeout_s
    assert r.success, r.message


def test_malformed_artifact_set_at_run_time_is_rejected_and_the_old_one_kept(
        graph, tmp_path, monkeypatch):
    """Set at run time, this file made the parameter call go unanswered and
    took the graph down."""
    monkeypatch.chdir(tmp_path)
    zipfile.ZipFile('x.npz', 'w').writestr('header.npy', b'garbage')
    (bad,) = graph.client.set_parameters('classifier', artifact_path=str(tmp_path / 'x.npz'))
    assert not bad.successful
    assert bad.reason == (f"{str(tmp_path / 'x.npz')!r} is not a readable lightstage classifier "
                          "file: its members ['header'] are not .npy arrays; retrain to get a new file")
    r = classify(graph.client, max_images=4)
    assert r.success, r.message
    assert not graph.supervisor.exited()


def test_fuzz_classify_answers_every_request_and_the_node_stays_up(graph):
    """Any value of every request field (the .srv has max_images and timeout_s): an answer,
    a refusal naming the value when the time limit is outside the contract."""
    @settings(max_examples=FUZZ_EXAMPLES or 25, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(max_images=st.integers(0, MAX_IMAGES_MAX) | st.sampled_from([0, 1, 4, 5, 8, 9]),
           timeout_s=st.floats() | st.floats(TIMEOUT_MIN_S, TIMEOUT_MAX_S)
           | st.sampled_from(SPECIAL_TIMEOUTS))
    def one_request(max_images, timeout_s):
        r = classify(graph.client, max_images=max_images, timeout_s=timeout_s)
        if not valid_timeout(timeout_s):
            assert not r.success and r.message == refusal(timeout_s)
        elif r.success:
            assert r.images_used in (4, 8) and r.images_used <= (max_images or 8)
            assert r.label in r.class_names and len(r.scores) == len(r.class_names)
        else:
            assert r.message, (max_images, timeout_s)
        assert not graph.supervisor.exited()

    one_request()
    r = classify(graph.client, max_images=8)  # and the stage still classifies
    assert r.success, r.message


def test_malformed_artifacts_leave_the_node_up_at_start_and_at_run_time(
        stage_artifact_path, tmp_path, monkeypatch):
    """An unreadable artifact at start-up (the node died), then fuzzed artifact files set through
    artifact_path: every parameter call is answered and the node stays up."""
    monkeypatch.chdir(tmp_path)
    zipfile.ZipFile('x.npz', 'w').writestr('header.npy', b'garbage')
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml',
                          {'classifier': {'artifact_path': str(tmp_path / 'x.npz')}})
    client = GraphClient(domain_id)
    names = (tmp_path / f'fuzzed-{i}.npz' for i in itertools.count())
    with Supervisor(sigint_timeout_s=5.0) as supervisor:
        try:
            start_nodes(supervisor, client, ['classifier'], domain_id, params)
            r = classify(client, timeout_s=2.0)
            assert not r.success
            assert r.message == (f"no classifier loaded: {str(tmp_path / 'x.npz')!r} is not a "
                                 "readable lightstage classifier file: its members ['header'] "
                                 "are not .npy arrays; retrain to get a new file")

            @settings(max_examples=FUZZ_EXAMPLES or 6, deadline=None, database=None,
                      suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
            @given(data=mutated_artifacts(stage_artifact_path.read_bytes()))
            def set_artifact(data):
                path = next(names)
                path.write_bytes(data)
                (result,) = client.set_parameters('classifier', artifact_path=str(path))
                assert result.successful or str(path) in result.reason, result.reason
                assert not supervisor.exited()

            set_artifact()
            (ok,) = client.set_parameters('classifier', artifact_path=str(stage_artifact_path))
            assert ok.successful, ok.reason
            (bad,) = client.set_parameters('classifier', artifact_path=str(tmp_path / 'x.npz'))
            assert not bad.successful
            # the artifact stayed: the call gets as far as looking for the driver
            r = classify(client, max_images=4, timeout_s=0.5)
            assert not r.success and '/lightstage/apply_patterns' in r.message, r.message
            assert not supervisor.exited()
        finally:
            client.close()


def test_error_paths_missing_artifact_no_driver_no_camera(stage_artifact_path, tmp_path):
    domain_id = fresh_domain_id()
    missing = tmp_path / 'nowhere' / 'classifier.npz'
    params = write_params(tmp_path / 'params.yaml',
                          {'classifier': {'artifact_path': str(missing)}})
    client = GraphClient(domain_id)
    with Supervisor(sigint_timeout_s=5.0) as supervisor:
        start_nodes(supervisor, client, ['classifier'], domain_id, params)
        try:
            # 1. no artifact: the node is up and says which file it could not load
            r = classify(client, timeout_s=2.0)
            assert not r.success and str(missing) in r.message
            (bad,) = client.set_parameters('classifier', artifact_path=str(tmp_path / 'other.npz'))
            assert not bad.successful and 'other.npz' in bad.reason
            (ok,) = client.set_parameters('classifier', artifact_path=str(stage_artifact_path))
            assert ok.successful, ok.reason
            # 2. no driver: a clear answer after waiting the request's timeout for it
            r = classify(client, timeout_s=1.5)
            assert not r.success and '/lightstage/apply_patterns' in r.message
            waited = re.search(r'is not available \(waited ([\d.]+) s\)', r.message)
            assert waited and 0 < float(waited.group(1)) <= 1.5, r.message  # what remained of the 1.5 s
            # 3. driver but no camera: refused before any LED is lit (images that do not
            #    arrive from a running camera are named: test_inference.py)
            start_nodes(supervisor, client, ['driver'], domain_id, params)
            # the classifier's own participant can take ~3.5 s to discover a node started
            # after it (Fast DDS announces every 3 s): give the call time to see the driver
            r = classify(client, max_images=4, timeout_s=6.0)
            assert not r.success
            assert 'no camera is publishing camera/image_raw' in r.message
        finally:
            client.close()
    # 4. the CLI with no graph at all
    p = subprocess.run([sys.executable, '-m', 'lightstage_bringup.classify_cli', '--domain-id',
                        str(domain_id), '--wait-s', '0.5'], capture_output=True, text=True, timeout=60)
    assert p.returncode == 3 and 'not available' in p.stderr
