"""Developer tools run as modules, e.g. ``python -m livetrack.tools.fuzz TARGET --seconds N`` (fuzz campaigns)."""
