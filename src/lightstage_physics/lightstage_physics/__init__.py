"""The light stage's physics without hardware: rig conventions, capture format, scene models, rendering (NumPy and JAX), the noise model and its fit, synthetic captures, output files."""
