"""Features (HOG) and the trained multiplexed-illumination classifier; the classify node."""
