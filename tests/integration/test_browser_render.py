"""Render the viewer's pages in headless chromium and check the pixels.

* Every shipped scene (``teleop run SCENE --out DIR``): its ``recording.html``, shot right after
  it loads, holds the "master" (and "slave") label and the legend, each an intact card (the
  legend's force arrows on it, no plane over it); and each side's environment and fixture are
  drawn: taking them out of the page (tissue, fixture, and the trocar or the curved surface where
  the scene has one) changes that side's pixels. One scene runs in the default suite, the sweep
  is marked long.
* The live page of a view, shot right after it loads, holds the labels, the legend and the arm.
* A synthetic recording draws both sides side by side; a cobot run replayed from its folder
  shows the labels, the device, both tools, the tissue and the contact arrow.

Needs the Debian package ``chromium``; without it these tests fail (they do not skip).
"""

import base64
import hashlib
import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest
import umsgpack
from PIL import Image
from scipy import ndimage

from teleop.scenario.schema import list_scenes, load_scene
from teleop.viz.shapes import COLORS

TOOLS = Path(__file__).resolve().parents[2] / "tools" / "screenshot.py"
W, H = 1280, 720
#: the scene of the sweep that runs in the default suite: a trocar, planes under the legend
DEFAULT_SCENE = "laparoscopic_incision"


def _screenshot_module():
    spec = importlib.util.spec_from_file_location("teleop_tools_screenshot", TOOLS)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _rgb(color: int) -> np.ndarray:
    return np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255], dtype=float)


def _near(img: np.ndarray, color: int, tol: float, chroma: float = 60.0) -> np.ndarray:
    """Pixels whose hue matches ``color``: the same normalised RGB direction within ``tol`` (shading
    and translucency change brightness, not so much the direction), and not washed out to grey
    (max - min channel above ``chroma``)."""
    rgb = _rgb(color)
    px = img.astype(float)
    c = px.max(axis=2) - px.min(axis=2)
    a = px / (np.linalg.norm(px, axis=2, keepdims=True) + 1e-9)
    return (np.linalg.norm(a - rgb / np.linalg.norm(rgb), axis=2) < tol) & (c > chroma)


def _exact(img: np.ndarray, color: int, tol: int) -> np.ndarray:
    """Pixels within ``tol`` per channel of ``color`` (the cards are unlit textures: exact)."""
    return np.abs(img.astype(int) - _rgb(color).astype(int)).max(axis=2) <= tol


def _shot(shot, html, png) -> np.ndarray:
    shot.render(html, png, W, H)
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape == (H, W, 3)
    return img


def _cards(img: np.ndarray) -> list:
    """The opaque cards (labels, legend) in a shot: connected regions of the card's own colour,
    largest first, as (area px, bounding box slices, centroid (row, col))."""
    mask = _exact(img, COLORS["panel"], 1)
    mask[:30] = False  # meshcat's "Open Controls" bar
    labels, _ = ndimage.label(mask)
    out = []
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        area = int((labels[box] == k).sum())
        if area >= 1000:
            out.append((area, box, ndimage.center_of_mass(labels == k)))
    return sorted(out, key=lambda c: -c[0])


def check_labels_and_legend(img: np.ndarray, has_slave: bool, has_device: bool = False) -> None:
    """The legend (the largest card) with its force arrows and text, intact (no plane drawn over
    it); one label card per side above it, with its word in the label's colour."""
    cards = _cards(img)
    assert cards, "no label or legend card on the page"
    area, box, (cy, _) = cards[0]
    legend = img[box]
    inner = legend[4:-4, 4:-4]
    card = _exact(inner, COLORS["panel"], 1).mean()
    assert card > 0.6, f"the legend's card is not intact ({card:.0%} of it the card's colour): something covers it"
    for key in ("operator", "constraint") + (("contact",) if has_slave else ()):
        hits = _exact(legend, COLORS[key], 40).sum()
        assert hits >= 30, f"the legend's {key} arrow: {hits} px"
    assert _exact(legend, COLORS["text"], 40).sum() >= 500, "the legend's text"
    if has_device:
        assert _exact(legend, COLORS["device"], 12).sum() >= 20, "the legend's cobot swatch"
    signs = [c for c in cards[1:] if c[0] < area]
    assert len(signs) >= (2 if has_slave else 1), f"{len(signs)} label card(s)"
    signs = sorted(signs[: 2 if has_slave else 1], key=lambda c: c[2][1])  # left to right: master, slave
    for _, sbox, (sy, _) in signs:
        word = _exact(img[sbox], COLORS["label"], 40).sum()
        assert word >= 200, f"a label card without its word ({word} px)"
        assert sy < H / 3, "a label card below the top third"
    if has_slave:
        assert signs[0][2][1] < W / 2 < signs[1][2][1] and cy > signs[0][2][0]  # master left, slave right, legend below


def _commands(html: str) -> list:
    return [umsgpack.unpackb(base64.b64decode(b))
            for b in re.findall(r'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"', html)]


def _held(html: str) -> str:
    """The page without its animation: it holds the last frame the view drew (what a replay
    shows), the same in every shot."""
    def drop(m):
        return "" if umsgpack.unpackb(base64.b64decode(m.group(1)))["type"] == "set_animation" else m.group(0)

    return re.sub(r'teleop_command\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\);\n?', drop, html)


def _with(html: str, extra: list) -> str:
    """The page with ``extra`` commands applied after its own (as the page's script applies them)."""
    calls = "".join(f'teleop_command("data:application/octet-binary;base64,'
                    f'{base64.b64encode(umsgpack.packb(c)).decode()}");\n' for c in extra)
    i = html.rindex("</script>")
    return html[:i] + calls + html[i:]


def check_environment_drawn(shot, html: str, tmp_path: Path, has_slave: bool) -> None:
    """Each side's tissue and fixture are in the picture: the page held on its last frame, then
    without them, differ on that side (and without the trocar or the curved surface, where the
    scene has them, on each side)."""
    objects = [c["path"] for c in _commands(html) if c["type"] == "set_object"]
    html = _held(html)
    base = _shot(shot, _write(tmp_path / "held.html", html), tmp_path / "held.png")
    sides = ("master", "slave") if has_slave else ("master",)
    groups = {"tissue": [f"/{s}/tissue/" for s in sides], "fixture": [f"/{s}/fixture/" for s in sides],
              "trocar": [f"/{s}/fixture/trocar_" for s in sides], "surface": [f"/{s}/fixture/surface" for s in sides]}
    for group, marks in groups.items():
        paths = sorted({p for p in objects if any(m in p for m in marks)})
        if not paths:
            continue
        gone = _with(html, [{"type": "delete", "path": p} for p in paths])
        img = _shot(shot, _write(tmp_path / f"no_{group}.html", gone), tmp_path / f"no_{group}.png")
        changed = np.abs(img.astype(int) - base.astype(int)).max(axis=2) > 12
        for side in sides:
            if not any(f"/{side}/" in p for p in paths):
                continue
            half = changed[:, : W // 2] if side == "master" and has_slave else (
                changed[:, W // 2:] if has_slave else changed)
            least = {"tissue": 3000, "fixture": 1000}.get(group, 150)
            assert half.sum() >= least, f"{side} side: taking its {group} away changed {half.sum()} px"


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _run_scene(name: str, folder: Path) -> Path:
    from teleop.app.cli import main

    assert main(["run", name, "--duration", "0.3", "--out", str(folder), "--quiet"]) in (0, 1)
    return folder / "recording.html"


def _check_scene(name: str, tmp_path: Path) -> None:
    shot = _screenshot_module()
    shot.find_chromium()  # a missing chromium fails here, naming the package
    scene = load_scene(name)
    html = _run_scene(name, tmp_path / "run")
    img = _shot(shot, html, tmp_path / "at_load.png")  # right after load, as the file is
    check_labels_and_legend(img, scene.slave is not None)
    check_environment_drawn(shot, html.read_text(encoding="utf-8"), tmp_path, scene.slave is not None)


def test_a_scenes_recording_is_complete_when_it_loads(tmp_path):
    _check_scene(DEFAULT_SCENE, tmp_path)


@pytest.mark.long  # about 10 s a scene (a run, four renders); CI's long stage runs it
@pytest.mark.parametrize("name", [n for n in list_scenes() if n != DEFAULT_SCENE])
def test_every_shipped_scenes_recording_is_complete_when_it_loads(name, tmp_path):
    _check_scene(name, tmp_path)


def test_the_live_page_is_complete_when_it_loads(tmp_path):
    """A live view (as `teleop replay DIR --viewer` serves it) shot right after its page loads:
    labels, legend and the arm's meshes are there, not seconds later."""
    from teleop.app.view_bridge import replay_run, viz_scene_for
    from teleop.viz import make_view

    shot = _screenshot_module()
    shot.find_chromium()
    run = tmp_path / "run"
    _run_scene("straight_incision", run)
    with make_view("meshcat", viz_scene_for(load_scene("straight_incision"))) as view:
        replay_run(run, view)
        view.flush()
        img = _shot(shot, view.url, tmp_path / "live.png")
    check_labels_and_legend(img, has_slave=True)
    assert _near(img[:, W // 2:], COLORS["arm"], 0.12).sum() > 5000, "the arm's meshes"


def test_both_sides_render_in_chromium(tmp_path):
    shot = _screenshot_module()
    shot.find_chromium()  # a missing chromium fails here, naming the package
    html = shot.demo_recording(tmp_path / "run.html", duration_s=0.5, fixture="scalpel")
    png = tmp_path / "run.png"
    took = shot.render(html, png, W, H)
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape == (H, W, 3)
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
    assert _near(right, COLORS["tissue"], 0.06, chroma=20).sum() > 1000  # the peach tissue block, slave side
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
    shot.render(run / "replay.html", png, W, H)
    full = np.asarray(Image.open(png).convert("RGB"))
    check_labels_and_legend(full, has_slave=True, has_device=True)
    img = full[30:]  # below meshcat's "Open Controls" bar
    left, right = img[:, :640], img[:, 640:]
    counts = {
        "device": _near(left, COLORS["device"], 0.1, chroma=20).sum(),
        "master tool": _near(left, COLORS["tool"], 0.1).sum(),
        "slave tool": _near(right, COLORS["tool"], 0.1).sum(),
        "tissue": _near(right, COLORS["tissue"], 0.06, chroma=20).sum(),
        "contact arrow": _near(right, COLORS["contact"], 0.1).sum(),
    }
    least = {"device": 1000, "master tool": 500, "slave tool": 300, "tissue": 5000, "contact arrow": 100}
    missing = {k: int(v) for k, v in counts.items() if v < least[k]}
    assert not missing, (missing, {k: int(v) for k, v in counts.items()})
