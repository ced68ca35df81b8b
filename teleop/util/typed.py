"""Typed settings: one validator for every frozen dataclass of settings, driven by its fields.

A settings class is a frozen dataclass whose fields carry a type hint and, through
:func:`setting`, their rules in ``dataclasses.field`` metadata (bounds, length, choices, a check,
the reason to give). :func:`validate` builds such a class from a plain table (a TOML table, a dict)
and every error is one :class:`~teleop.util.errors.SceneError` naming the file, the dotted key and the
reason; an unknown key gets "did you mean". It works on any frozen dataclass handed to it at run
time, with or without metadata (then the type hints alone are checked), so a user's parameter
class is validated by the same rules. Classes that mix in :class:`Checked` also validate their
fields when built directly from Python.

Supported hints: ``float`` (finite unless ``finite=False``), ``int``, ``bool``, ``str`` (plain: no
control characters), ``Literal[...]``, ``tuple[X, ...]`` / ``tuple[X, Y]``, ``np.ndarray`` (of
floats), a nested dataclass (a sub-table), ``X | None`` (None only as a default: TOML has no null)
and unions of these (chosen by the value's kind). :func:`json_schema` turns a class into a JSON
Schema (draft 2020-12).

This module imports nothing from the rest of teleop but its errors, so every layer may use it.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import operator
import types
import typing
import unicodedata

import numpy as np

from teleop.util.errors import ConfigError, FieldError, SceneError, plain

MISSING = dataclasses.MISSING


def setting(default=MISSING, *, factory=MISSING, ge=None, gt=None, le=None, lt=None, n=None, lens=None,
            broadcast=False, choices=None, check=None, why=None, finite=True, internal=False, doc=""):
    """A dataclass field with its rules: bounds ``ge gt le lt`` (each number, elementwise for
    lists), ``n`` the length of a list (``lens`` the allowed lengths), ``broadcast`` a number
    accepted for a list of ``n``, ``choices`` the allowed values (for lists: of each item),
    ``check(value) -> reason or None`` any further rule (its reason is given as is), ``why`` the
    reason given when a bound or choice fails, ``finite`` False to allow inf, ``internal`` a field
    set by the program (never read from a table), ``doc`` a description for the JSON Schema."""
    meta = {k: v for k, v in dict(ge=ge, gt=gt, le=le, lt=lt, n=n, lens=lens, choices=choices, check=check,
                                   why=why, doc=doc).items() if v not in (None, "")}
    meta.update(broadcast=broadcast, finite=finite, internal=internal)
    if factory is not MISSING:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


class Checked:
    """Mixin: a frozen dataclass that validates (and normalizes: lists to tuples, ints to floats)
    its own fields on creation. A subclass with cross-field rules calls ``super().__post_init__()``
    and raises :class:`FieldError` naming the key."""

    def __post_init__(self):
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            if f.init and not f.metadata.get("internal"):
                object.__setattr__(self, f.name, convert(getattr(self, f.name), hints[f.name], f.metadata, f.name))


def validate(cls, table, path: str = "", where: str = "", given: dict | None = None):
    """Build settings class ``cls`` from ``table``; ``path`` the file, ``where`` the table's dotted
    key, ``given`` values the program sets (internal fields). Any problem: SceneError(path, key,
    reason) on one line (without a path its message is "key: reason")."""
    try:
        return build(cls, table, where, given)
    except FieldError as e:
        raise SceneError(path, e.key, e.reason) from None


def build(cls, table, where: str = "", given: dict | None = None):
    """As :func:`validate`, raising FieldError with the full dotted key (no file)."""
    if isinstance(table, cls):
        return table
    if dataclasses.is_dataclass(table) and not isinstance(table, type):  # e.g. a base class's instance
        table = {f.name: getattr(table, f.name) for f in dataclasses.fields(table) if f.init}
    if not isinstance(table, dict):
        raise FieldError(where or "<root>", f"expected a table, got {_kind(table)}")
    flds = [f for f in dataclasses.fields(cls) if f.init and not f.metadata.get("internal")]
    names = [f.name for f in flds]
    for k in table:
        if k not in names:
            raise FieldError(join(where, plain(k)), unknown_key(plain(k), names))
    hints = typing.get_type_hints(cls)
    kw = dict(given or {})
    for f in flds:
        if f.name in table:
            kw[f.name] = convert(table[f.name], hints[f.name], f.metadata, join(where, f.name))
        elif f.name not in kw and f.default is MISSING and f.default_factory is MISSING:
            what = "table" if _is_table(hints[f.name]) else "key"
            raise FieldError(join(where, f.name), f"required {what} is missing")
    try:
        return cls(**kw)
    except FieldError as e:
        raise FieldError(join(where, e.key), e.reason) from None
    except (ConfigError, ValueError, TypeError) as e:
        raise FieldError(where or "<root>", str(e)) from None


def join(where: str, key: str) -> str:
    return f"{where}.{key}" if where and not key.startswith("[") else f"{where}{key}"


def unknown_key(key: str, known) -> str:
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    if close:
        return f"unknown key; did you mean {close[0]!r}?"
    return f"unknown key; known keys here: {', '.join(sorted(known))}"


def _kind(v) -> str:
    return {dict: "a table", list: "a list", str: "a string", bool: "a boolean"}.get(type(v), type(v).__name__)


def _is_table(hint) -> bool:
    return dataclasses.is_dataclass(hint) or any(dataclasses.is_dataclass(a) for a in typing.get_args(hint))


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _options(hint) -> list:
    """The alternatives of a union hint (None removed)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return [a for a in typing.get_args(hint) if a is not type(None)]
    return [hint]


def _pick(value, options):
    """The union member a value's kind selects."""
    for o in options:
        origin = typing.get_origin(o)
        if ((isinstance(value, dict) and dataclasses.is_dataclass(o))
                or (dataclasses.is_dataclass(o) and isinstance(value, o))):
            return o
        if isinstance(value, str) and (o is str or origin is typing.Literal):
            return o
        if isinstance(value, (list, tuple, np.ndarray)) and (origin is tuple or o is np.ndarray or o is tuple):
            return o
        if _is_number(value) and o in (float, int):
            return o
        if isinstance(value, bool) and o is bool:
            return o
    return options[0]


def convert(value, hint, meta, key: str):
    """One value checked against its hint and rules; returns it normalized. Raises FieldError."""
    options = _options(hint)
    if value is None:
        if len(options) < len(typing.get_args(hint)) or hint is type(None):
            return None
        raise FieldError(key, "a value is required")
    made = [o for o in options if dataclasses.is_dataclass(o) and isinstance(value, o)]
    hint = made[0] if made else options[0] if len(options) == 1 else _pick(value, options)
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return build(hint, value, key)
    if origin is typing.Literal:
        allowed = typing.get_args(hint)
        if value not in allowed or isinstance(value, bool):
            raise FieldError(key, f"{meta.get('why', 'choose one of')} {allowed} (got {value!r})")
        out = value
    elif hint is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise FieldError(key, f"expected true or false, got {value!r}")
        out = bool(value)
    elif hint is int:
        if not isinstance(value, (int, np.integer)) or isinstance(value, (bool, np.bool_)):
            raise FieldError(key, f"expected an integer, got {value!r}")
        out = int(value)
    elif hint is float:
        out = _float(value, meta, key)
    elif hint is str:
        out = _plain(value, key)
    elif origin is tuple or hint is tuple or hint is np.ndarray:
        out = _sequence(value, hint, meta, key)
    else:
        raise FieldError(key, f"cannot check a value of type {hint!r}")  # a settings class's own bug
    _rules(out, meta, key, value)
    return out


def _float(value, meta, key):
    if not _is_number(value) or (meta.get("finite", True) and not math.isfinite(value)) or math.isnan(value):
        raise FieldError(key, f"expected a finite number, got {value!r}")
    return float(value)


def _plain(value, key):
    if not isinstance(value, str):
        raise FieldError(key, f"expected a string, got {_kind(value)}")
    if any(unicodedata.category(c) in ("Cc", "Cf", "Cs") for c in value):
        raise FieldError(key, f"expected plain text, got control characters in {value!r}")
    return value


def _sequence(value, hint, meta, key):
    args = typing.get_args(hint)
    item = float if hint is np.ndarray or not args else args[0]
    n = meta.get("n")
    if meta.get("broadcast") and _is_number(value):
        value = [value] * n
    if isinstance(value, np.ndarray):
        value = value.reshape(-1).tolist()
    if not isinstance(value, (list, tuple)):
        raise FieldError(key, f"expected a list, got {_kind(value)}")
    if item is float and (len(args) != 2 or args[1] is Ellipsis):
        if not all(_is_number(x) and (math.isfinite(x) or not meta.get("finite", True)) and not math.isnan(x)
                   for x in value):
            raise FieldError(key, f"expected a list of finite numbers, got {value!r}")
    if len(args) > 1 and args[1] is not Ellipsis and len(value) != len(args):
        raise FieldError(key, f"expected {len(args)} items, got {len(value)}")
    lens = meta.get("lens") or ((n,) if n is not None else None)
    if lens is not None and len(value) not in lens:
        n_text = " or ".join(map(str, lens))
        what = f"a number or {n_text} finite numbers" if meta.get("broadcast") else f"{n_text} numbers"
        raise FieldError(key, f"expected {what}, got {len(value)}")
    items = args if len(args) > 1 and args[1] is not Ellipsis else (item,) * len(value)
    inner = {"finite": meta.get("finite", True)}
    out = tuple(convert(x, h, inner, f"{key}[{i}]") for i, (x, h) in enumerate(zip(value, items)))
    return np.array(out, dtype=float) if hint is np.ndarray else out


def _rules(out, meta, key, raw):
    numbers = [out] if isinstance(out, float) or (isinstance(out, int) and not isinstance(out, bool)) else (
        [x for x in out if _is_number(x)] if isinstance(out, (tuple, np.ndarray)) else [])
    for b in (b for b in ("ge", "gt", "le", "lt") if b in meta):
        lim = meta[b]
        ok = {"ge": operator.ge, "gt": operator.gt, "le": operator.le, "lt": operator.lt}[b]
        if not all(ok(x, lim) for x in numbers):
            raise FieldError(key, f"{meta.get('why') or _range_text(meta)} (got {raw!r})")
    check = meta.get("check")
    if check is not None:
        reason = check(out)
        if reason:
            raise FieldError(key, reason)
    choices = meta.get("choices")
    if choices is not None:
        for v in (out if isinstance(out, tuple) else (out,)):
            if v not in choices:
                raise FieldError(key, f"{meta.get('why', 'choose one of')} {tuple(choices)} (got {v!r})")


def _range_text(meta) -> str:
    lo = ("[", meta["ge"]) if "ge" in meta else ("(", meta["gt"]) if "gt" in meta else None
    hi = (meta["le"], "]") if "le" in meta else (meta["lt"], ")") if "lt" in meta else None
    if lo and hi:
        return f"expected a value in {lo[0]}{lo[1]:g}, {hi[0]:g}{hi[1]}"
    if lo:
        return f"expected a value {'>=' if lo[0] == '[' else '>'} {lo[1]:g}"
    return f"expected a value {'<=' if hi[1] == ']' else '<'} {hi[0]:g}"


def json_schema(cls, title: str = "") -> dict:
    """A JSON Schema (draft 2020-12) of settings class ``cls``: objects closed to unknown keys,
    types, bounds, lengths and choices as the validator checks them (``check`` rules are not
    expressible and left to the validator)."""
    out = _object_schema(cls)
    out["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    if title:
        out["title"] = title
    return out


def _object_schema(cls) -> dict:
    if callable(getattr(cls, "__json_schema__", None)):  # a table shaped otherwise than its fields
        return cls.__json_schema__()
    hints = typing.get_type_hints(cls)
    props, required = {}, []
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("internal"):
            continue
        props[f.name] = _value_schema(hints[f.name], f.metadata)
        if f.default is MISSING and f.default_factory is MISSING:
            required.append(f.name)
    out = {"type": "object", "properties": props, "additionalProperties": False}
    if cls.__doc__:
        out["description"] = " ".join(cls.__doc__.split())
    if required:
        out["required"] = required
    return out


def _value_schema(hint, meta) -> dict:
    options = _options(hint)
    if len(options) > 1:
        return {"anyOf": [_value_schema(o, meta) for o in options]}
    hint = options[0]
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return _object_schema(hint)
    if origin is typing.Literal:
        out = {"enum": list(typing.get_args(hint))}
    elif hint is bool:
        out = {"type": "boolean"}
    elif hint is int:
        out = {"type": "integer"}
    elif hint is float:
        out = {"type": "number"}
    elif hint is str:
        out = {"type": "string"}
    else:  # a list
        args = typing.get_args(hint)
        fixed = len(args) > 1 and args[1] is not Ellipsis
        item = float if hint is np.ndarray or not args else args[0]
        out = {"type": "array"}
        if fixed:
            out["prefixItems"] = [_value_schema(a, {}) for a in args]
            out["minItems"] = out["maxItems"] = len(args)
        else:
            out["items"] = _value_schema(item, {k: v for k, v in meta.items()
                                                if k in ("choices", "ge", "gt", "le", "lt")})
        lens = meta.get("lens") or ((meta["n"],) if meta.get("n") is not None else None)
        if lens:
            out["minItems"], out["maxItems"] = min(lens), max(lens)
        if meta.get("broadcast"):
            out = {"anyOf": [{"type": "number"}, out]}
        return _described(out, meta)
    for b, word in (("ge", "minimum"), ("gt", "exclusiveMinimum"), ("le", "maximum"), ("lt", "exclusiveMaximum")):
        if b in meta and out.get("type") in ("number", "integer"):
            out[word] = meta[b]
    if meta.get("choices") is not None:
        out["enum"] = list(meta["choices"])
    return _described(out, meta)


def _described(out: dict, meta) -> dict:
    if meta.get("doc"):
        out["description"] = meta["doc"]
    return out


def as_table(obj):
    """A settings object back as a plain table (the inverse of :func:`validate`): fields equal to
    their default and None are left out, tuples and arrays become lists. An object that defines
    ``__table__()`` (a table whose shape is not its fields') gives its own."""
    if callable(getattr(type(obj), "__table__", None)):
        return obj.__table__()
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out = {}
        for f in dataclasses.fields(obj):
            if not f.init or f.metadata.get("internal"):
                continue
            v = getattr(obj, f.name)
            if v is None or _is_default(f, v):
                continue
            out[f.name] = as_table(v)
        return out
    if isinstance(obj, (tuple, list)):
        return [as_table(x) for x in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return obj


def _is_default(f, v) -> bool:
    if f.default is not MISSING:
        d = f.default
    elif f.default_factory is not MISSING:
        d = f.default_factory()
    else:
        return False
    try:
        return bool(np.array_equal(np.asarray(d, dtype=object), np.asarray(v, dtype=object))) if not (
            dataclasses.is_dataclass(d)) else as_table(d) == as_table(v)
    except (ValueError, TypeError):
        return False
