"""A viewer that draws nothing, for headless runs and tests: the same API as MeshcatView."""

from __future__ import annotations

from teleop.util.errors import ConfigError
from teleop.viz.frames import VizFrame, VizScene


class NullView:
    """Accepts frames and drops them. ``url`` is None; ``save_html`` writes nothing."""

    url = None

    def __init__(self, scene: VizScene | None = None, record: bool = False, open_browser: bool = False):
        if scene is not None and not isinstance(scene, VizScene):
            raise ConfigError(f"NullView.scene: expected a VizScene, got {type(scene).__name__}")
        self.scene, self.record = scene, bool(record)
        self.closed = False

    def publish(self, frame: VizFrame) -> bool:
        """Check the argument's type and do nothing; returns False (nothing was drawn)."""
        if not isinstance(frame, VizFrame):
            raise ConfigError(f"publish: expected a VizFrame, got {type(frame).__name__}")
        return False

    def flush(self, timeout_s: float = 0.0) -> None:
        """Nothing to wait for."""

    def save_html(self, path, autoplay: bool = True) -> None:
        """Write nothing (there is no scene to record); a ConfigError without ``record=True``."""
        if not self.record:
            raise ConfigError("save_html: this view does not record; make it with record=True")
        return None

    def hold(self, say=None) -> None:
        """Nothing is served: returns at once."""

    def close(self) -> None:
        self.closed = True

    def __enter__(self) -> NullView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
