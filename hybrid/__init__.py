"""C2D2 geometry of coverage: simulator, ground truth, lumen, cross-check, pipeline and CLI."""

__version__ = "0.1.0"

LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"
"""How the command line's log lines read (batch workers set it up again)."""
