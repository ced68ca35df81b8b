"""One error hierarchy. Every message names what was wrong and where."""


class TeleopError(Exception):
    """Base of every error raised by teleop."""


class ConfigError(TeleopError, ValueError):
    """A parameter, scene setting or file is invalid. The message names the key and the reason."""


class SceneError(ConfigError):
    """A scene file is malformed: names the file, the key and the reason."""

    def __init__(self, path: str, key: str, reason: str):
        self.path, self.key, self.reason = str(path), key, reason
        super().__init__(f"{path}: {key}: {reason}")


class DynamicsError(TeleopError):
    """The constrained dynamics cannot be evaluated (e.g. a singular inertia)."""


class SolverError(TeleopError):
    """A solver name or setting is unknown; the message lists what is installed."""


class CanError(TeleopError):
    """A CAN frame, database or bus problem."""
