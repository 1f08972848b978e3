"""C2D2 geometry of coverage: simulator, ground truth, lumen, cross-check, pipeline and CLI."""

__version__ = "0.1.0"
