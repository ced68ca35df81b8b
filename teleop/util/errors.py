"""One error hierarchy. Every message names what was wrong and where."""

import difflib
import re

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u200b-\u200f\u2028-\u202e\u2066-\u2069]")


def plain(text) -> str:
    """``text`` on one line with control and format characters escaped (safe for a terminal)."""
    return _CONTROL.sub(lambda m: m.group(0).encode("unicode_escape").decode("ascii"), str(text))


class TeleopError(Exception):
    """Base of every error raised by teleop."""


class ConfigError(TeleopError, ValueError):
    """A parameter, scene setting or file is invalid. The message names the key and the reason."""


class SceneError(ConfigError):
    """A scene file is malformed: names the file, the key and the reason."""

    def __init__(self, path: str, key: str, reason: str):
        self.path, self.key, self.reason = str(path), key, reason
        super().__init__(f"{path}: {key}: {reason}" if path else f"{key}: {reason}")


class FieldError(ConfigError):
    """A setting is invalid: ``key`` (dotted, relative to the table being built) and ``reason``.
    The validator (teleop.util.typed) prefixes the table's key and turns it into a SceneError."""

    def __init__(self, key: str, reason: str):
        self.key, self.reason = key, reason
        super().__init__(f"{key}: {reason}")


class DynamicsError(TeleopError):
    """The constrained dynamics cannot be evaluated (e.g. a singular inertia)."""


class SolverError(TeleopError):
    """A solver name or setting is unknown; the message lists what is installed."""


class CanError(TeleopError):
    """A CAN frame, database or bus problem."""


def check_table(d, where: str, known, what: str = "key", hint: str = "") -> None:
    """Raise ConfigError unless ``d`` is a dict whose keys are all in ``known``.

    The message names ``where`` (the table's dotted path) and the bad key, suggests the closest
    known key, and lists them all; ``what`` names a key ("fault", "setting"), ``hint`` what the
    table holds ("a table of fault settings")."""
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: expected {hint or 'a table'}, got {type(d).__name__}")
    for key in d:
        if key not in known:
            close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1, cutoff=0.8)
            guess = f"did you mean {close[0]!r}? " if close else ""
            raise ConfigError(f"{where}.{key}: unknown {what}; {guess}known: {sorted(known)}")
