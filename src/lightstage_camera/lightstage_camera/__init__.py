"""Camera hardware and acquisition: the camera node and its backends (simulated, pypylon, Aravis), trigger pairing, model capture and noise calibration (the acquisition node)."""
