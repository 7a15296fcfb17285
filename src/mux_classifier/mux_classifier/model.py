"""Old home of the estimator (`estimator`) and the artifact file (`artifact`)."""
# SHIM(issue 13): remove at merge (classifier_node.py imports ArtifactError, TrainedArtifact)
from .artifact import ArtifactError, TrainedArtifact  # noqa: F401
