"""Frame sources that need no camera: replay of recordings and plain videos, and a synthetic
stereo scene renderer with ground truth. Registered as the ``replay`` and ``synthetic`` drivers."""
