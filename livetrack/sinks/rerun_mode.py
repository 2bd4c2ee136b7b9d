"""The ``--rerun`` / ``outputs.rerun.mode`` syntax, parsed without importing rerun (it takes ~0.8 s to import)."""

from __future__ import annotations

DEFAULT_CONNECT_URL = "rerun+http://127.0.0.1:9876/proxy"
MODES = ("spawn", "connect", "serve", "save")


def parse_mode(text: str) -> tuple[str, str | None]:
    """``off | spawn | serve | connect[:URL] | save:PATH`` -> (mode, argument). ValueError if malformed."""
    mode, sep, arg = text.partition(":")
    if mode in ("off", "spawn", "serve") and not sep:
        return mode, None
    if mode == "connect":
        return mode, arg if sep and arg else DEFAULT_CONNECT_URL
    if mode == "save" and sep and arg:
        return mode, arg
    raise ValueError(f"must be off, spawn, serve, connect[:URL] or save:PATH, got {text!r}")
