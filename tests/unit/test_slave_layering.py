"""The slave's layering: it reads its fixtures as rows (teleop.dynamics) and imports nothing from
the scene format or the runtime, at module level or inside functions."""

import ast
from pathlib import Path

import teleop.slave

FORBIDDEN = ("teleop.scenario", "teleop.app.runtime", "teleop.app.cli")


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module


def test_the_slave_imports_neither_the_scene_nor_the_runtime():
    folder = Path(teleop.slave.__file__).parent
    bad = {f"{f.name}: {m}" for f in folder.rglob("*.py")
           for m in _imports(f) if m.startswith(FORBIDDEN)}
    assert not bad, sorted(bad)
