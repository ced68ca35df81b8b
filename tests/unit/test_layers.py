"""The package's layers (pyproject.toml's [tool.importlinter] contracts), checked by
import-linter: no package imports from a layer above it, and the tick, the physics and the
devices import no transport, viewer, scene format or runner."""

from pathlib import Path

from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[2]


def test_the_layer_contracts_are_kept(monkeypatch):
    monkeypatch.chdir(ROOT)
    # 0: every contract kept
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True) == 0
