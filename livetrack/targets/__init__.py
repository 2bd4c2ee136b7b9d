"""Target geometry, code book, printable artwork."""

from livetrack.targets.spec import CodeSpec, TargetSpec, load_targets

__all__ = ["CodeSpec", "TargetSpec", "load_targets"]
