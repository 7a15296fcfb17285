"""The trained multiplexed-illumination classifier: features, the estimator, its file, and
classifying on the stage (docs/CLASSIFIER.md). No module here imports JAX; only the node
imports rclpy.

The classifier and its file:
    estimator          `MuxClassifier` (scikit-learn style) and `LearnedModelClassifier`
    artifact           `TrainedArtifact`: what training produces and the classify node loads
    artifact_format    the versioned ``.npz`` file: `write_artifact`, `read_artifact`
    learned_model      a learned-illumination model's inference, in numpy
    gated_head         a linear head gated by object type: which type, then which class
    confidence         calibrated probabilities, the anytime stop rule, an answer's decision
    novelty            is this object unlike every trained class? (the "unknown" answer)
Features of a sample's images:
    features           extractors by name and a sample's feature vector, in image order
    hog                batched HOG equal to skimage's for the paper's configuration
    hog_kernel         the compiled (numba) HOG kernel behind `hog.hog_batch`
    hog_constants      the constants `hog` and `hog_kernel` share
    pooled_hog         dense local HOG pooled over the object: a placement-robust feature
    pose_normalise     the object centred and turned before the HOG grid
    object_mask        where the object lies: a foreground mask and its pose
    intensity_stats    per-image reflectance statistics over the object
    ratio_stats        cross-image relief statistics over pairs of images
    bow                a bag of visual words over dense HOG (the naive + BoW baseline)
Classifying on the stage:
    inference          patterns out, stamped images back, a label (the service's core)
    observe            classifying trigger sequences the classifier only watches (live, replayed)
    stage_queue        classifications take turns on the stage, first come first served
    classify_request   what a Classify request may ask for (node and `lightstage classify`)
ROS (rclpy):
    classifier_node    ``/lightstage/classify`` lights the learned patterns and classifies

Importing the package imports none of them: `from mux_classifier.artifact import TrainedArtifact`.
"""

__all__ = ['estimator', 'artifact', 'artifact_format', 'learned_model', 'gated_head', 'confidence',
           'novelty', 'features',
           'hog', 'hog_kernel', 'hog_constants', 'pooled_hog', 'pose_normalise', 'object_mask',
           'intensity_stats', 'ratio_stats', 'bow', 'inference', 'observe', 'stage_queue',
           'classify_request', 'classifier_node']
