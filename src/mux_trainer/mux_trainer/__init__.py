"""Training: illumination patterns and their classifier, learned from relightable models in
simulation, and the evaluation that compares the methods (docs/SEARCH.md, docs/LEARNED.md).

The methods (greedy and the baselines share `pattern_model.PatternModelMixin`: patterns, a
classifier per image count, prediction, a trained artifact):
    greedy              greedy joint selection of patterns and classifier (the paper's method)
    learned             learned illumination (a subpackage): LED levels trained through the
                        image formation with a linear head (JAX)
    learned_method      learned illumination built, written and evaluated as the others are
    learned_schedule    how long learned illumination trains (no JAX)
    baselines           the paper's fixed-pattern baselines: SNR-optimal and naive
    bow_baseline        naive with a bag of visual words
    snr_optimal         SNR-optimal multiplexing matrices and Hadamard S-matrix codes
    pattern_model       what every trained method shares
    search_params       the settings a search or baseline is built from, grouped
    selection_bias      the optimism of choosing the best candidate on the inner splits
Inside the search:
    candidate_patterns  the candidate illumination patterns (site patterns, joint LED patterns)
    data                from a capture to the arrays the search works on
    rendering           rendering and noise for the search, laid out for speed
    evaluation          candidate evaluation: how good is `[columns so far | candidate]`
    split_scoring       mean test accuracy of a classifier over many train/test splits
    splits              the repeated random pose splits (75 / 25)
    column_count        how many pattern columns a trained model keeps
    cluster             candidate evaluation on an existing Dask cluster
    reference           the straightforward (slow) candidate evaluation, for checks
Training runs and evaluation:
    training            one training run: capture folder in, artifact out (CLI and node)
    calibration         calibrated probabilities and the anytime target, from held-out answers
    novelty_fit         the unknown-object models, fitted at training time, and their evaluation
    holdout             held-out evaluation: train on some poses or samples, test on the others
    report              the paper's Table 1 and accuracy-vs-image-count figure
    evaluation_plots    the figures of an evaluation
    cli                 `lightstage train` and `lightstage eval`
ROS (rclpy):
    trainer_node        the Train action (``/lightstage/train``) around `training`

Importing the package imports none of them (`learned` is the one that loads JAX).
"""

__all__ = ['greedy', 'learned', 'learned_method', 'learned_schedule', 'baselines', 'bow_baseline',
           'snr_optimal', 'pattern_model', 'search_params', 'selection_bias', 'candidate_patterns', 'data',
           'rendering', 'evaluation', 'split_scoring', 'splits', 'column_count', 'cluster',
           'reference', 'training', 'calibration', 'novelty_fit', 'holdout', 'report', 'evaluation_plots', 'cli',
           'trainer_node']
