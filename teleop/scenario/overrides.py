"""Command-line overrides of a scene: ``--set dotted.key=VALUE`` sets any key of the scene table.

VALUE is read as a TOML value (``0.3``, ``true``, ``[1, 2, 3]``, ``"daqp"``, ``{ urdf = "a.urdf" }``);
a bare word that is not TOML (``daqp``) is taken as a string. Keys are dotted table paths, a list
item as ``phases[0]``. The table is then validated again as a whole by the same validator, so a
misspelt key gets the same one-line error with "did you mean".
"""

from __future__ import annotations

import re
import tomllib

from teleop.util.errors import SceneError

_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")


def parse_setting(text: str, path: str = "--set") -> tuple[str, object]:
    """"key=value" -> (key, value parsed as TOML, else the bare string)."""
    key, eq, raw = text.partition("=")
    key = key.strip()
    if not eq or not key:
        raise SceneError(path, f"--set {text}", "expected KEY=VALUE, e.g. slave.solver=daqp")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return key, value


def apply_settings(data: dict, path: str, sets=(), pairs=(), optional=frozenset()) -> dict:
    """Set each override into the scene table ``data`` (changed in place, returned); ``optional``
    as :func:`set_key`'s."""
    for key, value in [parse_setting(s, path) for s in sets or ()] + list(pairs):
        set_key(data, key, value, path, optional)
    return data


def set_key(data: dict, key: str, value, path: str, optional=frozenset()) -> None:
    """data[a][b][i]... = value for key "a.b[i]"; missing tables are created (the validator then
    names a key that does not exist), except the ``optional`` ones (dotted keys of tables whose
    absence turns a part off, such as "slave"): a key inside one the scene does not have is
    refused, since creating the table would add the part with every other key at its default
    (the table itself may be set: ``slave={}``)."""
    steps: list = []
    for part in key.split("."):
        m = _PART.fullmatch(part)
        if m is None:
            raise SceneError(path, key, "expected a dotted key such as tool.mass_kg or operator.phases[0].end_s")
        steps.append(m.group(1))
        steps += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    node = data
    for i, step in enumerate(steps[:-1]):
        where = _where(steps[: i + 1])
        if isinstance(step, int):
            if not isinstance(node, list) or step >= len(node):
                raise SceneError(path, where, "no such list item")
            node = node[step]
        else:
            if not isinstance(node, dict):
                raise SceneError(path, _where(steps[:i]), "is not a table")
            if step not in node and where in optional:
                raise SceneError(path, key, f"the scene has no [{where}] table, and setting one of its keys would "
                                            f"add one with every other key at its default; add the table to the "
                                            f"scene file (or --set '{where}={{}}' first to mean it)")
            node = node.setdefault(step, {} if not isinstance(steps[i + 1], int) else [])
    last = steps[-1]
    if isinstance(last, int):
        if not isinstance(node, list) or last >= len(node):
            raise SceneError(path, _where(steps), "no such list item")
    elif not isinstance(node, dict):
        raise SceneError(path, _where(steps[:-1]), "is not a table")
    node[last] = value


def _where(steps) -> str:
    return "".join(f"[{s}]" if isinstance(s, int) else (f".{s}" if j else s) for j, s in enumerate(steps))
