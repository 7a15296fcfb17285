"""Camera and stage physics: capture format, model store, rendering, noise model, calibration, synthetic data and the camera node."""
