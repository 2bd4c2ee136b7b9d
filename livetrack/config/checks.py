"""Validation helpers for YAML input at the boundary.

Every loader in livetrack reads plain dicts (from ``yaml.safe_load``) through these helpers, so that a wrong
file always names the key path and the problem, e.g. ``camera.fx: must be > 0, got -3``. Unknown keys are
rejected, never ignored.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A configuration or input file is wrong. ``str()`` names the key path and the problem."""

    def __init__(self, path: str, problem: str):
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}" if path else problem)


def join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else str(key)


def load_yaml(file: str | Path) -> Any:
    """Read a YAML file; errors name the file (and line, from the YAML parser)."""
    file = Path(file)
    try:
        with open(file, "rb") as stream:
            data = stream.read(MAX_YAML_BYTES + 1)  # bounded: a path to /dev/zero must not fill the memory
    except OSError as exc:
        raise ConfigError(str(file), f"cannot read: {exc.strerror or exc}") from exc
    if len(data) > MAX_YAML_BYTES:
        raise ConfigError(str(file), f"larger than {MAX_YAML_BYTES // 2**20} MiB: not a livetrack YAML file")
    return parse_yaml(data, file)


MAX_YAML_BYTES = 16 * 2**20
MAX_YAML_DEPTH = 100  # livetrack's files nest a few levels; deeper is not one of them (and recursion in PyYAML)
MAX_YAML_NODES = 1_000_000  # values, counting each alias as the copy it stands for


def parse_yaml(data: bytes, file: str | Path) -> Any:
    """Parse the UTF-8 YAML ``data`` of ``file`` with ``yaml.safe_load``. Raises ConfigError naming the file for
    anything that is not UTF-8 YAML: bad bytes (with their offset), syntax (with the line), nesting deeper than
    ``MAX_YAML_DEPTH``, recursive aliases or aliases expanding beyond ``MAX_YAML_NODES``, values PyYAML cannot
    build (e.g. a date 2024-13-45)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ConfigError(str(file), f"not UTF-8 text: byte 0x{data[exc.start]:02x} at offset {exc.start} "
                                     f"(line {line})") from None
    try:
        loader = _BoundedLoader(text)
        try:
            root = loader.get_single_node()
            if root is not None:
                problem = _graph_problem(root)
                if problem:
                    raise ConfigError(str(file), f"not valid YAML for livetrack: {problem}")
            return None if root is None else loader.construct_document(root)
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        raise ConfigError(str(file), f"not valid YAML: {exc}") from None
    except (ValueError, TypeError, OverflowError) as exc:  # PyYAML's constructors: dates, !!binary, ...
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(str(file), f"not valid YAML: {exc}") from None
    except RecursionError:
        raise ConfigError(str(file), "not valid YAML: nested too deeply") from None


class _BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses flow collections (``[``, ``{``) nested deeper than ``MAX_YAML_DEPTH``
    while scanning: PyYAML's scanner takes time quadratic in that depth (3000 ``[`` take seconds)."""

    def fetch_flow_collection_start(self, TokenClass: Any) -> None:  # noqa: N803 - PyYAML's name
        if self.flow_level >= MAX_YAML_DEPTH:
            raise yaml.scanner.ScannerError(None, None, f"nested more than {MAX_YAML_DEPTH} levels deep",
                                            self.get_mark())
        super().fetch_flow_collection_start(TokenClass)


def _graph_problem(root: yaml.Node) -> str | None:
    """Why a composed YAML node graph is not acceptable, or None: nested deeper than ``MAX_YAML_DEPTH``, an
    alias inside its own anchor (a cycle), or aliases that expand to more than ``MAX_YAML_NODES`` nodes (a
    "billion laughs": 432 bytes that every later check would walk, or print, 10**9 times). Iterative, linear in
    the number of distinct nodes."""

    def children(node: yaml.Node) -> list[yaml.Node]:
        if isinstance(node, yaml.SequenceNode):
            return list(node.value)
        if isinstance(node, yaml.MappingNode):
            return [item for pair in node.value for item in pair]
        return []

    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        if finished:
            on_path.discard(key)
            kids = children(node)
            size[key] = min(MAX_YAML_NODES + 1, 1 + sum(size[id(k)] for k in kids))
            depth[key] = 1 + max((depth[id(k)] for k in kids), default=0)
            if depth[key] > MAX_YAML_DEPTH:
                return f"nested more than {MAX_YAML_DEPTH} levels deep"
            continue
        if key in size:
            continue
        if key in on_path:
            return "an alias inside its own anchor (a recursive structure)"
        on_path.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in children(node))
    if size[id(root)] > MAX_YAML_NODES:
        return f"aliases expand to more than {MAX_YAML_NODES} nodes"
    return None


def mapping(data: Any, path: str, required: Iterable[str] = (), optional: Iterable[str] = ()) -> Mapping:
    """Check that ``data`` is a mapping with all ``required`` keys and no keys outside required+optional."""
    if not isinstance(data, Mapping):
        raise ConfigError(path, f"must be a mapping, got {type(data).__name__}")
    required = list(required)
    allowed = set(required) | set(optional)
    for key in required:
        if key not in data:
            raise ConfigError(join(path, key), "missing (required)")
    for key in data:
        if key not in allowed:
            raise ConfigError(join(path, str(key)), f"unknown key (allowed: {', '.join(sorted(allowed))})")
    return data


def number(
    data: Mapping,
    key: str,
    path: str,
    *,
    default: float | None = None,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
) -> float:
    """A finite real number, with optional bounds. ``default=None`` means required."""
    full = join(path, key)
    if key not in data or data[key] is None:
        if default is None:
            raise ConfigError(full, "missing (required)")
        return float(default)
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(full, f"must be a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:  # an integer beyond float range
        raise ConfigError(full, f"must be finite, got {_int_text(value)}") from None
    if not math.isfinite(value):
        raise ConfigError(full, f"must be finite, got {value}")
    if gt is not None and not value > gt:
        raise ConfigError(full, f"must be > {gt}, got {value}")
    if ge is not None and not value >= ge:
        raise ConfigError(full, f"must be >= {ge}, got {value}")
    if lt is not None and not value < lt:
        raise ConfigError(full, f"must be < {lt}, got {value}")
    if le is not None and not value <= le:
        raise ConfigError(full, f"must be <= {le}, got {value}")
    return value


def integer(
    data: Mapping, key: str, path: str, *, default: int | None = None, ge: int | None = None,
    le: int | None = None, choices: Iterable[int] | None = None,
) -> int:
    full = join(path, key)
    if key not in data or data[key] is None:
        if default is None:
            raise ConfigError(full, "missing (required)")
        return int(default)
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(full, f"must be an integer, got {value!r}")
    if ge is not None and value < ge:
        raise ConfigError(full, f"must be >= {ge}, got {_int_text(value)}")
    if le is not None and value > le:
        raise ConfigError(full, f"must be <= {le}, got {_int_text(value)}")
    if choices is not None and value not in set(choices):
        raise ConfigError(full, f"must be one of {sorted(set(choices))}, got {value}")
    return value


def _int_text(value: int) -> str:
    return str(value) if abs(value) < 10**30 else f"an integer of {value.bit_length()} bits"


def number_list(data: Mapping, key: str, path: str, *, length: int | None = None,
                default: list[float] | None = None) -> list[float]:
    full = join(path, key)
    if key not in data or data[key] is None:
        if default is None:
            raise ConfigError(full, "missing (required)")
        return list(default)
    value = data[key]
    if not isinstance(value, (list, tuple)):
        raise ConfigError(full, f"must be a list of numbers, got {value!r}")
    if length is not None and len(value) != length:
        raise ConfigError(full, f"must have {length} numbers, got {len(value)}")
    out = []
    for i, item in enumerate(value):
        try:
            ok = not isinstance(item, bool) and isinstance(item, (int, float)) and math.isfinite(item)
        except OverflowError:  # an integer beyond float range
            ok = False
        if not ok:
            raise ConfigError(f"{full}[{i}]", f"must be a finite number, got {_describe(item)}")
        out.append(float(item))
    return out


def _describe(value: Any) -> str:
    if isinstance(value, int) and not isinstance(value, bool):
        return _int_text(value)
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def string(data: Mapping, key: str, path: str, *, default: str | None = None,
           choices: Iterable[str] | None = None) -> str:
    full = join(path, key)
    if key not in data or data[key] is None:
        if default is None:
            raise ConfigError(full, "missing (required)")
        return default
    value = data[key]
    if not isinstance(value, str):
        raise ConfigError(full, f"must be a string, got {value!r}")
    if choices is not None and value not in set(choices):
        raise ConfigError(full, f"must be one of {sorted(set(choices))}, got {value!r}")
    return value


def boolean(data: Mapping, key: str, path: str, *, default: bool) -> bool:
    full = join(path, key)
    if key not in data or data[key] is None:
        return default
    value = data[key]
    if not isinstance(value, bool):
        raise ConfigError(full, f"must be true or false, got {value!r}")
    return value
