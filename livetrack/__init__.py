"""livetrack: live pose of fractal black/white ring targets, compensated for over- and underexposure."""

__version__ = "0.1.0"
