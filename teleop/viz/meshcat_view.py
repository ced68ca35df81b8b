"""The Meshcat view: both sides of the teleoperator in one page, updated at <= 30 Hz of simulated
time from a background thread, optionally recorded into a self-contained HTML animation.

Meshcat 0.3.2 facts this relies on: commands go over a ZMQ REQ socket to a server subprocess that
outlives its parent unless stopped (we start it with a watchdog that exits when its parent dies,
and stop it in ``close()``, in a finalizer and at exit); ``vis.wait()`` is never called;
``set_animation`` followed by ``static_html()`` gives a recording that plays without a server.
The server is meshcat's own with the pages of :mod:`teleop.viz.meshcat_server`: the live page and
the recording both hold the whole scene drawn so far when they load (labels, legend, meshes).
"""

from __future__ import annotations

import logging
import os
import queue
import subprocess
import sys
import threading
import time
import weakref
from pathlib import Path

import numpy as np
import zmq
from meshcat import Visualizer
from meshcat import geometry as g
from meshcat import transformations as tf
from meshcat.animation import Animation
from meshcat.visualizer import ViewerWindow

from teleop.util.errors import ConfigError, TeleopError
from teleop.viz.frames import VizFrame, VizScene
from teleop.viz.layout import Drawing
from teleop.viz.shapes import COLORS, VIEW_HEIGHT_M, VIEW_WIDTH_M, polyline

log = logging.getLogger(__name__)

#: the meshcat server (teleop/viz/meshcat_server.py), run by its path: a page it serves, and a
#: recording it writes, hold the whole scene when they load; it exits when its parent is gone
_SERVER = "import runpy, sys; sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')"
#: the address the viewer's web server binds unless the command line asks for another
DEFAULT_HOST = "127.0.0.1"
SOCKET_TIMEOUT_MS = 10000


def start_server(timeout_s: float = 30.0, host: str = DEFAULT_HOST):
    """Start a meshcat server subprocess whose web server binds ``host``; returns (process,
    zmq_url, web_url)."""
    script = str(Path(__file__).with_name("meshcat_server.py"))
    proc = subprocess.Popen([sys.executable, "-u", "-c", _SERVER, script, str(os.getpid()), host],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    lines: queue.Queue = queue.Queue()

    def drain():  # read the urls, then keep the pipe empty so the server never blocks on it
        for raw in proc.stdout:
            lines.put(raw.decode("utf-8", "replace").strip())
        lines.put(None)

    threading.Thread(target=drain, daemon=True, name="meshcat-stdout").start()
    urls = {}
    try:
        while len(urls) < 2:
            line = lines.get(timeout=timeout_s)
            if line is None:
                raise TeleopError(f"meshcat server exited early with code {proc.wait()}")
            for key in ("zmq_url", "web_url"):
                if line.startswith(key + "="):
                    urls[key] = line.split("=", 1)[1]
    except queue.Empty:
        stop_server(proc, None)
        raise TeleopError(f"meshcat server did not report its urls within {timeout_s} s") from None
    except BaseException:
        stop_server(proc, None)
        raise
    return proc, urls["zmq_url"], urls["web_url"]


def stop_server(proc, socket) -> None:
    """Close the socket and end the server process (terminate, then kill). Safe to repeat."""
    if socket is not None and not socket.closed:
        socket.close(linger=0)
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=3.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _tracks(M: np.ndarray):
    """(position, quaternion xyzw, scale) of a transform R diag(s) + p, for animation tracks."""
    A = M[:3, :3]
    s = np.linalg.norm(A, axis=0)
    R = np.eye(4)
    R[:3, :3] = A / s
    w, x, y, z = tf.quaternion_from_matrix(R)
    return [float(v) for v in M[:3, 3]], [float(x), float(y), float(z), float(w)], [float(v) for v in s]


class MeshcatView:
    """A live Meshcat page of a VizScene; ``publish()`` is cheap and never waits for the server.

    rate_hz: frames closer than 1/rate_hz s of simulated time are dropped (at most 60 Hz).
    record: keep the accepted frames so ``save_html()`` can write a recording.
    """

    def __init__(self, scene: VizScene, record: bool = False, open_browser: bool = False,
                 rate_hz: float = 30.0, host: str = DEFAULT_HOST):
        if not isinstance(scene, VizScene):
            raise ConfigError(f"MeshcatView.scene: expected a VizScene, got {type(scene).__name__}")
        if not 1.0 <= rate_hz <= 60.0:
            raise ConfigError(f"MeshcatView.rate_hz: expected 1..60 Hz, got {rate_hz}")
        self.scene, self.record, self.period = scene, bool(record), 1.0 / rate_hz
        self.drawing = Drawing(scene)
        self.pushes = self.sent = self.dropped = 0
        self._closed, self._broken = False, None
        self._last_t = None
        self._latest = None
        self._frames: list = []        # (t, states, cut length) of the accepted frames
        self._trace = None             # the latest cut trace, (n, 3) m
        self._sent_cut = -1
        self._nodes: dict = {}
        self._lock = threading.Lock()  # one user of the ZMQ socket at a time
        self._cv = threading.Condition()
        self._pending, self._queued, self._done, self._stopping = None, 0, 0, False
        proc, zmq_url, self.url = start_server(host=host)
        window = ViewerWindow.__new__(ViewerWindow)  # connect to our server without its prints
        window.server_proc, window.zmq_url, window.web_url = proc, zmq_url, self.url
        window.connect_zmq()
        for opt, val in ((zmq.RCVTIMEO, SOCKET_TIMEOUT_MS), (zmq.SNDTIMEO, SOCKET_TIMEOUT_MS), (zmq.LINGER, 0)):
            window.zmq_socket.setsockopt(opt, val)
        self._window = window
        self._finalizer = weakref.finalize(self, stop_server, proc, window.zmq_socket)
        try:
            self.vis = Visualizer(window=window)
            self.root = self.vis["teleop"]
            self._build()
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._worker, daemon=True, name="meshcat-view")
        self._thread.start()
        if open_browser:
            import webbrowser

            try:
                webbrowser.open(self.url, new=2)
            except Exception as e:  # a missing browser must not stop a run
                log.warning("could not open a browser at %s: %s", self.url, e)

    # -- scene ----------------------------------------------------------------------------------
    def _node(self, path: str) -> Visualizer:
        node = self._nodes.get(path)
        if node is None:
            node = self._nodes[path] = self.root[path]
        return node

    def _build(self) -> None:
        with self._lock:
            self.vis["/Grid"].set_property("visible", False)
            self.vis["/Axes"].set_property("visible", False)
            self.vis["/Background"].set_property("visible", False)  # the page's white shows
            for path, M in self.drawing.fixed.items():
                (self.root if path == "root" else self._node(path)).set_transform(M)
            for path, obj, M in self.drawing.parts:
                node = self._node(path)
                node.set_object(obj)
                if not np.allclose(M, np.eye(4)):
                    node.set_transform(M)
            for path, M in self.drawing.hidden().items():
                self._node(path).set_transform(M)
            if self.scene.view == "side":  # level and orthographic: verticals stay vertical
                w, h = 0.5 * VIEW_WIDTH_M, 0.5 * VIEW_HEIGHT_M
                self.vis["/Cameras/default/rotated"].set_object(g.OrthographicCamera(-w, w, h, -h, -100.0, 100.0))
                self.vis["/Cameras/default/rotated/<object>"].set_property("position", [3.0, 0.0, 0.0])

    # -- publishing -----------------------------------------------------------------------------
    def publish(self, frame: VizFrame) -> bool:
        """Offer a frame; True if it was accepted (>= 1/rate_hz s of simulated time after the
        last accepted one, or time went backwards), False if dropped. Never waits for meshcat."""
        if not isinstance(frame, VizFrame):
            raise ConfigError(f"publish: expected a VizFrame, got {type(frame).__name__}")
        if self._closed:
            raise TeleopError("publish: the view is closed")
        last = self._last_t
        if last is not None and 0.0 <= frame.t - last < self.period - 1e-9:
            self.dropped += 1
            self._latest = frame
            return False
        self._accept(frame)
        return True

    def _accept(self, frame: VizFrame) -> None:
        self._last_t, self._latest = frame.t, None
        states = self.drawing.states(frame)
        if frame.cut_trace is not None:
            self._trace = frame.cut_trace
        ncut = -1 if self._trace is None else len(self._trace)
        if self.record:
            self._frames.append((frame.t, states, ncut))
        self.pushes += 1
        with self._cv:
            self._pending = (states, self._trace)
            self._queued += 1
            self._cv.notify()

    def _worker(self) -> None:
        while True:
            with self._cv:
                while self._pending is None and not self._stopping:
                    self._cv.wait()
                if self._pending is None:
                    return
                item, self._pending, seq = self._pending, None, self._queued
            try:
                if self._broken is None:
                    self._send(*item)
                    self.sent += 1
            except Exception as e:  # the run goes on without its viewer
                self._broken = e
                log.warning("meshcat view stopped updating: %s", e)
            with self._cv:
                self._done = seq
                self._cv.notify_all()

    def _send(self, states: dict, trace) -> None:
        with self._lock:
            for path, M in states.items():
                self._node(path).set_transform(M)
            if trace is not None and len(trace) != self._sent_cut:
                if len(trace) >= 2:
                    self._node("slave/cut/live").set_object(polyline(trace))
                else:
                    self._node("slave/cut/live").delete()
                self._sent_cut = len(trace)
            mt = self.drawing.trace_master
            if mt is not None and len(mt) >= 2 and len(mt) % 10 == 0:  # a user fixture's tool path
                self._node("master/trace").set_object(polyline(mt, COLORS["trace"]))

    def flush(self, timeout_s: float = 10.0) -> None:
        """Accept the newest dropped frame, then wait until the server has everything."""
        if self._latest is not None:
            self._accept(self._latest)
        with self._cv:
            self._cv.wait_for(lambda: self._done >= self._queued, timeout=timeout_s)

    # -- recording ------------------------------------------------------------------------------
    def save_html(self, path, autoplay: bool = True) -> Path:
        """Write the recorded frames as a self-contained HTML page: a meshcat animation that plays
        once and holds the last frame (``autoplay``), or waits on the last frame for its "play"
        button (``autoplay=False``: what a screenshot should see). Needs ``record=True``."""
        if not self.record:
            raise ConfigError("save_html: this view does not record; make it with record=True")
        if self._closed:
            raise TeleopError("save_html: the view is closed")
        self.flush()
        if self._broken is not None:
            raise TeleopError(f"save_html: the meshcat server stopped answering: {self._broken}")
        fps = 30
        anim = Animation(default_framerate=fps)
        t0 = self._frames[0][0] if self._frames else 0.0
        for t, states, _ in self._frames:
            with anim.at_frame(self.root, (t - t0) * fps) as at:
                for p, M in states.items():
                    pos, quat, scale = _tracks(M)
                    at[p].set_property("position", "vector3", pos)
                    at[p].set_property("quaternion", "quaternion", quat)
                    at[p].set_property("scale", "vector3", scale)
        chunks = self._cut_chunks(anim, t0, fps)
        with self._lock:
            self._node("slave/cut").delete()
            for name, pts in chunks:
                self._node(f"slave/cut/{name}").set_object(polyline(pts))
            mt = self.drawing.trace_master
            if mt is not None and len(mt) >= 2:
                self._node("master/trace").set_object(polyline(mt, COLORS["trace"]))
            self.vis.set_animation(anim, play=bool(autoplay), repetitions=1)
            html = self.vis.static_html()
            self.vis.set_animation(Animation(), play=False)  # live browsers go back to live frames
            self._node("slave/cut").delete()
            self._sent_cut = -1
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(html, encoding="utf-8")
        return out

    def _cut_chunks(self, anim: Animation, t0: float, fps: int, most: int = 40) -> list:
        """Split the final cut trace into <= ``most`` line strips, each shown from the first
        recorded frame whose trace reached its end."""
        trace = self._trace
        if trace is None or len(trace) < 2:
            return []
        n = len(trace)
        ends = sorted({min(c, n) for _, _, c in self._frames if c >= 2} | {n})
        if len(ends) > most:
            ends = [ends[round(i)] for i in np.linspace(0, len(ends) - 1, most)]
        chunks, start = [], 0
        for k, end in enumerate(ends):
            if end - start < 1:
                continue
            pts = trace[max(start - 1, 0): end]
            if len(pts) < 2:
                continue
            shown = next((t for t, _, c in self._frames if c >= end), t0)
            name = f"chunk{k}"
            anim.at_frame(self.root, 0.0)[f"slave/cut/{name}"].set_property("visible", "boolean", bool(shown <= t0))
            anim.at_frame(self.root, (shown - t0) * fps)[f"slave/cut/{name}"].set_property("visible", "boolean", True)
            chunks.append((name, pts))
            start = end
        return chunks

    # -- lifetime -------------------------------------------------------------------------------
    def hold(self, say=None) -> None:
        """Keep the page served (its last frame) until Ctrl-C; ``say(url)`` is told where."""
        self.flush()
        if say is not None:
            say(self.url)
        try:
            while self.server_process.poll() is None:
                time.sleep(0.25)
        except KeyboardInterrupt:
            pass

    @property
    def server_process(self):
        """The meshcat server's ``subprocess.Popen`` (for tests and diagnostics)."""
        return self._window.server_proc

    def close(self) -> None:
        """Stop the updater thread and the meshcat server. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        with self._cv:
            self._stopping = True
            self._cv.notify_all()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            thread.join(timeout=SOCKET_TIMEOUT_MS / 1000.0 + 1.0)
        self._finalizer()

    def __enter__(self) -> MeshcatView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
