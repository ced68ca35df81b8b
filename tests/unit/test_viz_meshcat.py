"""The Meshcat view: a real server, throttled publishing, a recording, and a server that always
goes away (close, close again, and a parent killed with SIGKILL)."""

import base64
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import umsgpack

from teleop.util.errors import ConfigError, TeleopError
from teleop.viz import VizFrame, VizScene, make_view


def _commands(html: str) -> list:
    """The meshcat commands embedded in a static_html() page, decoded."""
    blobs = re.findall(r'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"', html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def _frame(k: int, dt: float = 0.001) -> VizFrame:
    t = k * dt
    c, s = np.cos(t), np.sin(t)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return VizFrame(t=t, reference_pose=(np.array([0.05 * np.sin(t), 0.0, 0.05 * np.cos(t)]), R),
                    virtual_pose=(np.array([0.0, 0.01, 0.05]), R),
                    operator_wrench=np.r_[1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                    constraint_wrench=np.r_[0.0, 0.0, 2.0, 0.0, 0.0, 0.0] if k % 2 else None,
                    slave_tool_pose=(np.array([0.5, 0.0, 0.1]), np.diag([1.0, -1.0, -1.0])),
                    contact_wrench=np.r_[0.0, 0.0, 3.0, 0.0, 0.0, 0.0],
                    cut_trace=np.column_stack([np.linspace(0.45, 0.45 + t, k + 1), np.zeros(k + 1),
                                               np.full(k + 1, 0.095)]))


@pytest.fixture
def scene():
    return VizScene("sphere", {"radius_m": 0.05}, "scalpel",
                    tissue={"origin_m": (0.5, 0.0, 0.1), "size_m": (0.2, 0.2), "thickness_m": 0.03})


def test_publish_throttles_records_and_saves_an_animation(scene, tmp_path):
    with make_view("meshcat", scene, record=True) as view:
        assert view.url.startswith("http://")
        t0 = time.perf_counter()
        accepted = [view.publish(_frame(k)) for k in range(100)]  # 1 kHz for 0.1 s
        cost = (time.perf_counter() - t0) / 100
        assert sum(accepted) == 3 == view.pushes  # t = 0, 0.034, 0.068: >= 1/30 s apart
        assert view.dropped == 97
        assert cost < 0.005  # publish never waits for the server
        view.flush()  # takes the newest dropped frame (t = 0.099) too
        assert view.pushes == 4 and 1 <= view.sent <= 4
        out = view.save_html(tmp_path / "run.html")
    html = out.read_text()
    assert "MeshCat.Viewer" in html and len(html) > 100_000  # the viewer's javascript is inlined
    anims = [c for c in _commands(html) if c["type"] == "set_animation"]
    assert len(anims) == 1
    tracks = {a["path"]: a["clip"]["tracks"] for a in anims[0]["animations"]}
    ref = {t["name"]: t for t in tracks["/meshcat/teleop/master/reference"]}
    assert set(ref) == {".position", ".quaternion", ".scale"}
    times = [k["time"] for k in ref[".position"]["keys"]]
    assert np.allclose(times, np.array([0.0, 0.034, 0.068, 0.099]) * 30)  # frames at 30 fps
    assert np.allclose(ref[".position"]["keys"][-1]["value"], _frame(99).reference_pose[0])
    assert any(p.startswith("/meshcat/teleop/slave/cut/chunk") for p in tracks)  # the cut appears over time
    assert "/meshcat/teleop/slave/arrows/contact/shaft" in tracks


def test_close_twice_stops_the_server_and_refuses_more_frames(scene, tmp_path):
    view = make_view("meshcat", scene)
    proc = view.server_process
    assert proc.poll() is None
    view.publish(_frame(0))
    with pytest.raises(ConfigError, match="record=True"):
        view.save_html(tmp_path / "x.html")
    view.close()
    assert proc.poll() is not None  # the server process is gone
    view.close()
    with pytest.raises(TeleopError, match="closed"):
        view.publish(_frame(1))


def test_a_bad_frame_is_refused(scene):
    with make_view("meshcat", scene) as view:
        with pytest.raises(ConfigError, match="VizFrame"):
            view.publish({"t": 0.0})
        assert view.pushes == 0


def _alive(pid: int) -> bool:
    """True while pid runs (a zombie waiting for its new parent to reap it counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


CHILD = """
import sys, time
from teleop.viz import VizScene, make_view
view = make_view("meshcat", VizScene("free"))
print(view.server_process.pid, flush=True)
time.sleep(60)
"""


def test_server_dies_with_a_killed_parent():
    child = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, text=True)
    try:
        pid = int(child.stdout.readline())
        assert _alive(pid)
        child.send_signal(signal.SIGKILL)  # no finally, no atexit in the parent
        child.wait()
        deadline = time.time() + 5.0
        while _alive(pid) and time.time() < deadline:
            time.sleep(0.1)
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)
            pytest.fail("the meshcat server outlived its killed parent")
    finally:
        if child.poll() is None:
            child.kill()


def test_the_side_view_is_level_and_orthographic(tmp_path):
    """--view side: the layout is not tipped (a vertical stays world-vertical) and the page's
    camera is orthographic, looking level along the world x axis; the default is a perspective
    from above."""
    from teleop.viz.layout import Drawing

    kw = dict(tissue={"origin_m": (0.5, 0.0, 0.1), "size_m": (0.2, 0.2), "thickness_m": 0.03})
    up_side = Drawing(VizScene("scalpel", {}, "scalpel", view="side", **kw)).fixed["root"][:3, :3] @ [0, 0, 1.0]
    up_persp = Drawing(VizScene("scalpel", {}, "scalpel", **kw)).fixed["root"][:3, :3] @ [0, 0, 1.0]
    assert np.allclose(up_side[:2], 0.0) and up_side[2] > 0  # a vertical blade draws vertical
    assert abs(up_persp[0]) > 0.1 * np.linalg.norm(up_persp)  # tipped toward the camera
    with make_view("meshcat", VizScene("scalpel", {}, "scalpel", view="side", **kw), record=True) as view:
        view.publish(_frame(0))
        html = view.save_html(tmp_path / "side.html").read_text()
    cams = [c for c in _commands(html) if c.get("type") == "set_object" and "Cameras" in c.get("path", "")]
    assert any(c["object"]["object"]["type"] == "OrthographicCamera" for c in cams)
    pos = [c for c in _commands(html) if c.get("type") == "set_property" and c.get("property") == "position"
           and "Cameras" in c.get("path", "")]
    assert pos and pos[-1]["value"][1] == 0.0  # level: no height above the target


def test_the_page_labels_both_sides_and_carries_a_legend(scene, tmp_path):
    with make_view("meshcat", scene, record=True) as view:
        view.publish(_frame(0))
        html = view.save_html(tmp_path / "labels.html").read_text()
    paths = {c.get("path", "") for c in _commands(html) if c.get("type") == "set_object"}
    for part in ("labels/master/sign", "labels/slave/sign", "labels/legend"):
        assert any(p.endswith(part) for p in paths), part


def test_a_recording_applies_its_whole_scene_while_it_loads(scene, tmp_path):
    """save_html: the viewer's javascript inline and every command applied by the page's own
    script, in order, as the page loads (meshcat's own page applies each through a fetch() whose
    promise settles after the load event: a screenshot then missed the labels); no websocket."""
    with make_view("meshcat", scene, record=True) as view:
        view.publish(_frame(0))
        html = view.save_html(tmp_path / "run.html").read_text()
    cmds = _commands(html)
    assert html.count('teleop_command("data:application/octet-binary;base64,') == len(cmds) > 20
    assert ".then(buffer => viewer.handle_command_bytearray" not in html
    assert "/?since=" not in html  # a recording connects to nothing
    objects = [c["path"] for c in cmds if c["type"] == "set_object"]
    for part in ("labels/master/sign", "labels/slave/sign", "labels/legend", "slave/tissue/block"):
        assert any(p.endswith(part) for p in objects), part
    assert sum(c["type"] == "set_animation" for c in cmds) == 1  # its tracks find their nodes by path


def _ws_messages(url: str, query: str, idle_s: float = 1.0) -> list:
    """The decoded commands a websocket to a view's server gets until it is quiet for idle_s."""
    import asyncio

    from tornado.websocket import websocket_connect

    async def read():
        conn = await websocket_connect(url.replace("http://", "ws://").replace("/static/", "/") + query)
        out = []
        while True:
            try:
                msg = await asyncio.wait_for(conn.read_message(), idle_s)
            except TimeoutError:
                break
            if msg is None:
                break
            out.append(umsgpack.unpackb(msg))
        conn.close()
        return out

    return asyncio.run(read())


def test_the_live_page_holds_the_scene_and_its_socket_sends_only_what_came_after(scene):
    """The page at the view's url holds the scene drawn so far (complete when it loads) and
    connects asking for the commands after those it holds; a socket that says nothing gets the
    whole scene, as meshcat's own does."""
    import urllib.request

    with make_view("meshcat", scene) as view:
        view.publish(_frame(0))
        view.flush()
        with urllib.request.urlopen(view.url, timeout=10) as r:
            html = r.read().decode("utf-8")
        held = _commands(html)
        objects = {c["path"] for c in held if c["type"] == "set_object"}
        for part in ("labels/master/sign", "labels/legend", "master/fixture/sphere", "slave/tissue/block"):
            assert any(p.endswith(part) for p in objects), part
        assert '<script src="main.min.js"></script>' in html
        since = int(re.search(r'"/\?since=(\d+)"', html).group(1))
        assert since > 0
        view.publish(_frame(100))  # 0.1 s later: a new frame, moving nodes only
        view.flush()
        later = _ws_messages(view.url, f"?since={since}")
        assert later and {c["type"] for c in later} <= {"set_transform", "set_object", "delete"}
        assert not any(c["path"].endswith("labels/legend") for c in later)
        assert any(c["path"].endswith("master/reference") for c in later)
        whole = _ws_messages(view.url, "")
        assert any(c.get("path", "").endswith("labels/legend") for c in whole) and len(whole) > len(later)
        assert len(_ws_messages(view.url, "?since=999999999")) == len(whole)  # not one this server gave
