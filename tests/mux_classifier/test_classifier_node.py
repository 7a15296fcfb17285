"""The classifier node in this process: its last-resort guards (the service answers, the
parameter call answers) for failures that validation does not foresee."""
import pytest

from suite_helpers import fresh_domain_id

pytestmark = pytest.mark.ros


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


def test_an_unforeseen_failure_in_a_call_is_answered_with_its_text(node, monkeypatch):
    from lightstage_interfaces.srv import Classify
    from mux_classifier import classifier_node

    def broken(*_args, **_kwargs):
        raise RuntimeError('boom')

    monkeypatch.setattr(classifier_node, 'classify_on_stage', broken)
    r = node._on_classify(Classify.Request(max_images=4, timeout_s=1.0), Classify.Response())
    assert not r.success
    assert r.message.startswith('the classifier failed unexpectedly (RuntimeError: boom)')
    assert node._busy.acquire(blocking=False)  # the stage lock was let go


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
