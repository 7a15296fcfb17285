"""The classifier node in this process: its last-resort guards (the service answers, the
parameter call answers) for failures that validation does not foresee."""
import pytest

from helpers.suite import fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.process]


@pytest.fixture
def node(stage_artifact_path):
    import rclpy
    from mux_classifier.classifier_node import ClassifierNode
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = ClassifierNode(context=context, parameter_overrides=[
        Parameter('artifact_path', value=str(stage_artifact_path))])
    yield node
    node.destroy_node()
    rclpy.shutdown(context=context)


def answer(node, request):
    """Run the node's service handler (a coroutine awaiting the stage queue's worker) to its
    response, as the executor would."""
    import time
    from lightstage_interfaces.srv import Classify
    handler = node._on_classify(request, Classify.Response())
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        try:
            handler.send(None)
        except StopIteration as done:
            return done.value
        time.sleep(0.005)
    raise AssertionError('the handler did not answer within 30 s')


def test_an_unforeseen_failure_in_a_call_is_answered_with_its_text(node, monkeypatch):
    from lightstage_interfaces.srv import Classify
    from mux_classifier import classifier_node

    def broken(*_args, **_kwargs):
        raise RuntimeError('boom')

    monkeypatch.setattr(node.stage, 'wait_ready', lambda _timeout_s: None)
    monkeypatch.setattr(node.stage, 'camera_parameters', lambda _names, _t: {'backend': 'sim',
                                                                             'dimmer': 0.45})
    monkeypatch.setattr(classifier_node, 'classify_on_stage', broken)
    r = answer(node, Classify.Request(max_images=4, timeout_s=1.0))
    assert not r.success
    assert r.message.startswith('the classifier failed unexpectedly (RuntimeError: boom)')
    assert node._busy.acquire(blocking=False)  # the stage lock was let go
    node._busy.release()
    assert node.queue.served == 1 and len(node.queue) == 0  # the queue's worker goes on


def test_a_camera_that_does_not_answer_refuses_the_call(node, monkeypatch):
    """A stopped camera made the classifier skip its dimmer check after 2 s and
    light the stage anyway; the safety check fails closed."""
    from lightstage_interfaces.srv import Classify
    from mux_classifier import classifier_node
    lit = []
    monkeypatch.setattr(node.stage, 'wait_ready', lambda _timeout_s: None)
    monkeypatch.setattr(node.stage, 'camera_parameters', lambda _names, _t: None)  # no answer
    monkeypatch.setattr(classifier_node, 'classify_on_stage', lambda *a, **k: lit.append(a))
    r = answer(node, Classify.Request(max_images=4, timeout_s=1.0))
    assert not r.success and not lit
    assert r.message == (
        "not classifying: the camera node 'camera' did not answer a parameter query within 1.0 s, "
        "so its dimmer cannot be checked against the classifier's (0.45; a sim camera at "
        "another dimmer classifies wrong silently). Is the camera running and not stopped or "
        "hung (`ros2 node list`, its log)? If the camera node has another name, set the "
        "classifier's camera_node parameter to it")


def test_an_unforeseen_failure_loading_an_artifact_is_a_rejection(node, monkeypatch, tmp_path):
    from mux_classifier import classifier_node
    from rclpy.parameter import Parameter
    loaded = node.artifact

    def broken(_path):
        raise KeyError('surprise')

    monkeypatch.setattr(classifier_node.TrainedArtifact, 'load', broken)
    (result,) = node.set_parameters([Parameter('artifact_path', value=str(tmp_path / 'a.npz'))])
    assert not result.successful
    assert result.reason == (f"{str(tmp_path / 'a.npz')!r} cannot be used as a classifier "
                             "(KeyError: 'surprise'); retrain to get a new file")
    assert node.artifact is loaded


def test_diagnostics_say_which_classifier_is_loaded_and_its_inner_estimate(node):
    """/diagnostics (and so the operator's page) carry the classifier and the estimate it
    was trained with, and how its inner splits held out."""
    from lightstage_graph.diagnostics import OK
    artifact = node.artifact
    inner = artifact.provenance['inner_estimate']
    report = node._classifier_status()
    assert node.diagnostics.name == 'classifier: model'
    assert report.level == OK and report.message == artifact.describe()
    assert f"inner estimate {100 * inner['accuracy']:.1f} %" in report.message
    assert report.values['classes'] == ', '.join(artifact.class_names)
    assert report.values['image_counts'] == '4, 8'
    assert report.values['inner_estimate_percent'] == f"{100 * inner['accuracy']:.1f}"
    assert report.values['inner_estimate_held_out'] == inner['held_out']
    assert report.values['selection_optimism_points'] == '0.0'   # a fixed matrix chose nothing


def test_diagnostics_of_a_provenance_without_some_figures_leave_them_out(node):
    """A provenance written by hand or by an older trainer: the status says what it has,
    and the timer that publishes it never raises."""
    from dataclasses import replace
    loaded = node.artifact
    try:
        node.artifact = replace(loaded, provenance={**loaded.provenance, 'inner_estimate': {
            'accuracy': 0.5, 'selection_optimism': 0.1}})
        values = node._classifier_status().values
        assert values['inner_estimate_percent'] == '50.0'
        assert 'selection_optimism_points' not in values
        node.artifact = replace(loaded, provenance={**loaded.provenance, 'inner_estimate': 'high'})
        assert 'inner_estimate_percent' not in node._classifier_status().values
    finally:
        node.artifact = loaded


def test_diagnostics_say_why_no_classifier_is_loaded(tmp_path):
    import rclpy
    from lightstage_graph.diagnostics import ERROR
    from mux_classifier.classifier_node import ClassifierNode
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = ClassifierNode(context=context, parameter_overrides=[
        Parameter('artifact_path', value=str(tmp_path / 'missing.npz'))])
    try:
        report = node._classifier_status()
        assert report.level == ERROR
        assert report.message.startswith('no classifier loaded:')
        assert report.values == {'artifact_path': str(tmp_path / 'missing.npz')}
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
