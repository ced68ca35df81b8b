"""Strict reading of scene tables: every error names the file, the key and the reason.

A :class:`Table` wraps one TOML table. ``take`` reads a key with a type and a check; ``done``
rejects any key that was not read, so a typo in a scene file is an error, never silently ignored.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from teleop.errors import SceneError

_MISSING = object()


class Table:
    """One table of a scene file. ``where`` is the dotted path of the table (e.g. ``tool``)."""

    def __init__(self, path: str, where: str, data: Any):
        if not isinstance(data, dict):
            raise SceneError(path, where or "<root>", f"expected a table, got {type(data).__name__}")
        self.path, self.where, self.data = str(path), where, data
        self._read: set[str] = set()

    def key(self, k: str) -> str:
        return f"{self.where}.{k}" if self.where else k

    def error(self, k: str, reason: str) -> SceneError:
        return SceneError(self.path, self.key(k), reason)

    def has(self, k: str) -> bool:
        return k in self.data

    def take(self, k: str, kind: str, default: Any = _MISSING, check: Callable | None = None, why: str = ""):
        """Read key ``k`` as ``kind``: 'float', 'int', 'bool', 'str', 'vec3', 'vec6', 'floats', 'table',
        'list'. ``check(value) -> bool`` with ``why`` explains a range failure."""
        self._read.add(k)
        if k not in self.data:
            return self._absent(k, default, "key")
        value = _convert(self, k, self.data[k], kind)
        if check is not None and not check(value):
            raise self.error(k, f"{why or 'value out of range'} (got {self.data[k]!r})")
        return value

    def _absent(self, k: str, default: Any, what: str):
        """An absent key: a misspelt neighbour is the error; else the default, or "missing"."""
        typo = self._typo_of(k)
        if typo is not None:
            raise self.error(typo, f"unknown key; did you mean {k!r}?")
        if default is _MISSING:
            raise self.error(k, f"required {what} is missing")
        return default

    def _typo_of(self, k: str) -> str | None:
        """An unread key of this table that looks like a misspelling of ``k``."""
        import difflib

        spare = [x for x in self.data if x not in self._read and isinstance(x, str)]
        match = difflib.get_close_matches(k, spare, n=1, cutoff=0.8)
        return match[0] if match else None

    def sub(self, k: str, default: Any = _MISSING) -> "Table | None":
        """A nested table, or ``default`` when absent (pass ``None`` for optional tables)."""
        self._read.add(k)
        if k not in self.data:
            return self._absent(k, default, "table")
        return Table(self.path, self.key(k), self.data[k])

    def done(self) -> None:
        unknown = sorted(set(self.data) - self._read)
        if unknown:
            raise self.error(unknown[0], f"unknown key; known keys here: {', '.join(sorted(self._read))}")


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _convert(t: Table, k: str, v: Any, kind: str):
    if kind == "float":
        if not _finite(v):
            raise t.error(k, f"expected a finite number, got {v!r}")
        return float(v)
    if kind == "int":
        if not isinstance(v, int) or isinstance(v, bool):
            raise t.error(k, f"expected an integer, got {v!r}")
        return v
    if kind == "bool":
        if not isinstance(v, bool):
            raise t.error(k, f"expected true or false, got {v!r}")
        return v
    if kind == "str":
        if not isinstance(v, str):
            raise t.error(k, f"expected a string, got {v!r}")
        return v
    if kind in ("vec3", "vec6", "floats"):
        n = {"vec3": 3, "vec6": 6}.get(kind)
        if not isinstance(v, list) or not all(_finite(x) for x in v):
            raise t.error(k, f"expected a list of finite numbers, got {v!r}")
        if n is not None and len(v) != n:
            raise t.error(k, f"expected {n} numbers, got {len(v)}")
        return tuple(float(x) for x in v)
    if kind == "list":
        if not isinstance(v, list):
            raise t.error(k, f"expected a list, got {type(v).__name__}")
        return v
    if kind == "table":
        if not isinstance(v, dict):
            raise t.error(k, f"expected a table, got {type(v).__name__}")
        return v
    raise AssertionError(f"unknown kind {kind}")  # programming error, not user input
