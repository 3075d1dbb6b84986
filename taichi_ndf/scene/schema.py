"""Strict reading of TOML tables: every key is known, every value has the right type.

Errors name the full key (``material.poisson``) so a user can find the line in the scene file.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any


class SceneError(ValueError):
    """A scene file is invalid; the message names the offending key."""


_MISSING = object()


def read_toml(path: Path, what: str) -> dict:
    """The parsed TOML file `path`; SceneError if it is missing ("`what` not found") or not
    valid TOML."""
    if not path.is_file():
        raise SceneError(f"{what} not found: {path}")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text file (TOML in UTF-8)") from None
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"{path}: not valid TOML: {err}") from None


def checked(build, where: str):
    """build(), with a ValueError, TypeError or FileNotFoundError it raises re-raised as a
    SceneError prefixed by `where` (the section or key it comes from)."""
    try:
        return build()
    except SceneError:
        raise
    except (ValueError, TypeError, FileNotFoundError) as err:
        raise SceneError(f"{where}: {err}") from err


class Table:
    """A TOML table read key by key; ``close()`` rejects keys nobody asked for."""

    def __init__(self, data: Any, path: str):
        if not isinstance(data, dict):
            raise SceneError(f"{path or 'scene'}: expected a table, got {type(data).__name__}")
        self.data = data
        self.path = path
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def has(self, name: str) -> bool:
        return name in self.data

    def _get(self, name: str, default: Any) -> Any:
        self.used.add(name)
        if name in self.data:
            return self.data[name]
        if default is _MISSING:
            raise SceneError(f"{self.key(name)}: required key is missing")
        return default

    def number(self, name: str, default: Any = _MISSING, *, positive: bool = False,
               nonnegative: bool = False) -> float:
        v = self._get(name, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SceneError(f"{self.key(name)}: expected a number, got {v!r}")
        if not math.isfinite(v):
            raise SceneError(f"{self.key(name)}: must be finite, got {v!r}")
        if positive and v <= 0:
            raise SceneError(f"{self.key(name)}: must be > 0, got {v!r}")
        if nonnegative and v < 0:
            raise SceneError(f"{self.key(name)}: must be >= 0, got {v!r}")
        return float(v)

    def integer(self, name: str, default: Any = _MISSING, *, minimum: int | None = None) -> int:
        v = self._get(name, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise SceneError(f"{self.key(name)}: expected an integer, got {v!r}")
        if minimum is not None and v < minimum:
            raise SceneError(f"{self.key(name)}: must be >= {minimum}, got {v!r}")
        return v

    def boolean(self, name: str, default: Any = _MISSING) -> bool:
        v = self._get(name, default)
        if not isinstance(v, bool):
            raise SceneError(f"{self.key(name)}: expected true or false, got {v!r}")
        return v

    def string(self, name: str, default: Any = _MISSING, *, choices=None) -> str:
        v = self._get(name, default)
        if v is None:
            return None
        if not isinstance(v, str):
            raise SceneError(f"{self.key(name)}: expected a string, got {v!r}")
        if choices is not None and v not in choices:
            raise SceneError(f"{self.key(name)}: must be one of {sorted(choices)}, got {v!r}")
        return v

    def vector(self, name: str, length: int, default: Any = _MISSING) -> tuple[float, ...]:
        v = self._get(name, default)
        if v is None:
            return None
        if (not isinstance(v, (list, tuple)) or len(v) != length
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)):
            raise SceneError(f"{self.key(name)}: expected a list of {length} numbers, got {v!r}")
        if not all(math.isfinite(x) for x in v):
            raise SceneError(f"{self.key(name)}: values must be finite, got {v!r}")
        return tuple(float(x) for x in v)

    def numbers(self, name: str, default: Any = _MISSING) -> tuple[float, ...]:
        v = self._get(name, default)
        if (not isinstance(v, (list, tuple))
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)):
            raise SceneError(f"{self.key(name)}: expected a list of numbers, got {v!r}")
        return tuple(float(x) for x in v)

    def table(self, name: str, *, optional: bool = False) -> Table | None:
        v = self._get(name, {} if optional else _MISSING)
        return Table(v, self.key(name))

    def tables(self, name: str) -> list[Table]:
        v = self._get(name, [])
        if not isinstance(v, list):
            raise SceneError(f"{self.key(name)}: expected an array of tables ([[{name}]])")
        return [Table(item, f"{self.key(name)}[{i}]") for i, item in enumerate(v)]

    def close(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            where = self.path or "top level"
            raise SceneError(f"{where}: unknown key(s) {', '.join(repr(k) for k in unknown)}")
