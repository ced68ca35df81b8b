"""Render a recording of both sides in headless chromium and check the pixels: the master side
(left) and the slave side (right) both drew, in the colours the viewer gives the tool, the arm and
the tissue; a cobot run replayed from its folder shows the labels, the device, both tools, the
tissue and the contact arrow, and leaves the run's own recording alone. Needs the Debian package
``chromium``; without it this test fails (it does not skip)."""

import hashlib
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from teleop.viz.shapes import COLORS

TOOLS = Path(__file__).resolve().parents[2] / "tools" / "screenshot.py"


def _screenshot_module():
    spec = importlib.util.spec_from_file_location("teleop_tools_screenshot", TOOLS)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _near(img: np.ndarray, color: int, tol: float) -> np.ndarray:
    """Pixels whose hue matches ``color``: the same normalised RGB direction within ``tol`` (shading
    and translucency change brightness, not so much the direction), and not washed out to grey."""
    rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255], dtype=float)
    px = img.astype(float)
    chroma = px.max(axis=2) - px.min(axis=2)
    a = px / (np.linalg.norm(px, axis=2, keepdims=True) + 1e-9)
    return (np.linalg.norm(a - rgb / np.linalg.norm(rgb), axis=2) < tol) & (chroma > 60)


def test_both_sides_render_in_chromium(tmp_path):
    shot = _screenshot_module()
    shot.find_chromium()  # a missing chromium fails here, naming the package
    html = shot.demo_recording(tmp_path / "run.html", duration_s=0.5, fixture="scalpel")
    png = tmp_path / "run.png"
    took = shot.render(html, png, 1280, 720)
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape == (720, 1280, 3)
    img = img[30:]  # below meshcat's "Open Controls" bar
    drawn = np.abs(img.astype(int) - 255).max(axis=2) > 30  # the page is white where nothing is
    left, right = img[:, :640], img[:, 640:]
    assert drawn[:, :640].sum() > 5000, "the master side (left) drew nothing"
    assert drawn[:, 640:].sum() > 5000, "the slave side (right) drew nothing"
    arm = _near(img, COLORS["arm"], 0.12)
    tool = _near(left, COLORS["tool"], 0.15)
    assert arm.sum() > 5000 and tool.sum() > 500, (arm.sum(), tool.sum())  # orange arm, blue tool
    arm_x, tool_x = np.nonzero(arm)[1], np.nonzero(tool)[1]
    assert np.percentile(arm_x, 1) > np.percentile(tool_x, 99)  # side by side: master left of slave
    assert np.median(arm_x) > 640
    assert _near(right, COLORS["tissue"], 0.12).sum() > 1000  # the pink tissue block, slave side
    assert _near(right, COLORS["contact"], 0.12).sum() > 5  # the red contact force arrow
    assert took < 30.0


@pytest.mark.long  # about 45 s here: a cobot run, a replay and a render (CI's long stage runs it)
def test_a_cobot_run_replayed_from_its_folder_shows_everything(tmp_path):
    """`teleop run straight_incision --master cobot --out DIR`, then `teleop replay DIR`."""
    from teleop.app.cli import main

    shot = _screenshot_module()
    shot.find_chromium()
    run = tmp_path / "run"
    assert main(["run", "straight_incision", "--master", "cobot", "--duration", "1.5", "--out", str(run)]) in (0, 1)
    own = run / "recording.html"
    before = hashlib.sha256(own.read_bytes()).hexdigest()
    assert main(["replay", str(run)]) == 0
    assert hashlib.sha256(own.read_bytes()).hexdigest() == before  # the run's recording unchanged
    png = tmp_path / "replay.png"
    shot.render(run / "replay.html", png, 1280, 720)
    img = np.asarray(Image.open(png).convert("RGB"))[30:]  # below meshcat's "Open Controls" bar
    left, right = img[:, :640], img[:, 640:]
    counts = {
        "master label": _near(left, COLORS["label"], 0.1).sum(),
        "slave label": _near(right, COLORS["label"], 0.1).sum(),
        "device": _near(left, COLORS["device"], 0.1).sum(),
        "master tool": _near(left, COLORS["tool"], 0.1).sum(),
        "slave tool": _near(right, COLORS["tool"], 0.1).sum(),
        "tissue": _near(right, COLORS["tissue"], 0.12).sum(),
        "contact arrow": _near(right, COLORS["contact"], 0.1).sum(),
    }
    least = {"master label": 300, "slave label": 300, "device": 1000, "master tool": 500, "slave tool": 300,
             "tissue": 5000, "contact arrow": 100}
    missing = {k: int(v) for k, v in counts.items() if v < least[k]}
    assert not missing, (missing, {k: int(v) for k, v in counts.items()})
    # the labels sit above their sides: the master label in the upper part of the left half
    rows = np.nonzero(_near(left, COLORS["label"], 0.1))[0]
    assert np.median(rows) < img.shape[0] / 3
