"""The light stage's physics without hardware: what an image of a sample under a pattern is.
Pure Python, no rclpy and no camera SDK (docs/PHYSICS.md).

The stage and its data:
    rig                 illumination sites, LED channels and the camera of a capture (rig.yaml)
    capture_format      the capture folder: relightable models on disk (docs/CAPTURE_FORMAT.md)
    scene_models        `ModelSet`: one image per single LED for every sample and pose
    errors              the capture, destination, noise-file and sample errors
    output_files        files about to be written: never replaced unless asked, rescue folders
    workers             the worker count of the parallel verbs (`--jobs`, `n_jobs`)
Images under any light:
    render              relighting (``I = L @ w``) and the noisy renders, NumPy
    render_jax          its differentiable twin with the camera noise, JAX (float32)
    noise               the affine camera noise model, its presets and noise files
    noise_fit           fitting that model to frames of a target under several lights
    calibration_target  the simulated calibration chart and its frames
Synthetic captures and plots:
    synth               the synthetic dataset: planned samples and poses, rendered and written
    materials           the real and fake materials of every object type, and their blending
    fruit_render        one pose of an object lit by each LED: shapes, shading, shadows
    synth_cli           `lightstage synth`: the dataset, a procedural family or a calibration target
    families            procedural object families: two class materials apart by a strength,
                        several physical samples per class (`lightstage synth --family`)
    flat_objects        flat and low-relief objects: coins, banknote-like prints, seals
    camera_plots        the noise characteristic and a sample relit by a few patterns

Importing the package imports none of them (`render_jax` is the one that loads JAX).
"""

__all__ = ['rig', 'capture_format', 'scene_models', 'errors', 'output_files', 'workers',
           'render', 'render_jax', 'noise', 'noise_fit', 'calibration_target', 'synth',
           'materials', 'fruit_render', 'families', 'synth_cli', 'flat_objects', 'camera_plots']
