"""Render a Meshcat HTML recording headless in chromium to a PNG.

    python tools/screenshot.py run.html run.png            # a recording saved by view.save_html()
    python tools/screenshot.py --demo docs/screenshot.png  # a synthetic run of both sides

Chromium (Debian package ``chromium``) draws meshcat's WebGL with SwiftShader; the flags are the
ones in the design notes. HOME and XDG_* point at a scratch directory and every run gets a fresh
profile, so nothing leaks between runs. The shot is taken once the page has loaded and
drawn; recordings made with ``save_html(..., autoplay=False)`` then show the run's last frame.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", "--hide-scrollbars", "--mute-audio")


def find_chromium() -> str:
    """The chromium executable; RuntimeError naming the package to install when there is none."""
    for name in ("chromium", "chromium-browser", "/usr/bin/chromium"):
        path = shutil.which(name)
        if path:
            return path
    raise RuntimeError("chromium not found: install it with `apt-get install -y chromium`")


def render(html, png, width: int = 1280, height: int = 720, budget_ms: int | None = None,
           timeout_s: float = 30.0, attempts: int = 3) -> float:
    """Screenshot ``html`` (a file, or the http(s) URL of a live view) into ``png`` at width x
    height px; returns the seconds taken.

    Chromium takes the shot once the page has loaded and drawn (about 1 s for a recording). A
    ``budget_ms`` of virtual time can be given, but chromium 150 hangs on about a third of such
    runs, so it is off by default; a run that hangs is killed (with its child processes) after
    ``timeout_s`` and tried again, ``attempts`` times in all. Record with
    ``save_html(..., autoplay=False)`` to see the last frame of a run.
    """
    png = Path(png).resolve()
    if str(html).startswith(("http://", "https://")):  # a live page (a view's url)
        target = str(html)
    else:
        html = Path(html).resolve()
        if not html.is_file():
            raise FileNotFoundError(f"no such HTML file: {html}")
        target = html.as_uri()
    png.parent.mkdir(parents=True, exist_ok=True)
    exe = find_chromium()
    errors = []
    for _ in range(attempts):
        if png.exists():
            png.unlink()
        with tempfile.TemporaryDirectory(prefix="teleop-chromium-") as scratch:
            env = dict(os.environ, HOME=scratch)
            for var in ("XDG_CONFIG_HOME", "XDG_CACHE_HOME", "XDG_DATA_HOME", "XDG_RUNTIME_DIR"):
                d = Path(scratch) / var.lower()
                d.mkdir(mode=0o700)
                env[var] = str(d)
            cmd = [exe, *FLAGS, f"--user-data-dir={Path(scratch) / 'profile'}",
                   f"--window-size={width},{height}", f"--screenshot={png}", target]
            if budget_ms:
                cmd.insert(-1, f"--virtual-time-budget={budget_ms}")
            t0 = time.perf_counter()
            proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE, start_new_session=True)
            try:
                _, err = proc.communicate(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)  # chromium and its renderer, gpu, ... children
                proc.communicate()
                errors.append(f"timed out after {timeout_s} s")
                continue
            took = time.perf_counter() - t0
        if png.is_file():
            return took
        errors.append(f"exit {proc.returncode}: {err.decode('utf-8', 'replace')[-1500:]}")
    raise RuntimeError(f"chromium wrote no screenshot of {html} in {attempts} attempts: {errors}")


def demo_recording(path, duration_s: float = 1.0, dt_s: float = 0.002, fixture: str = "sphere",
                   device: bool = False):
    """Record a synthetic run of both sides into ``path`` (HTML): a scalpel on the master side
    (on a sphere, or at a depth under a plane), the Panda cutting a tissue block on the slave
    side, force arrows and a cut trace; ``device`` adds the cobot master (gantry and wrist).
    Returns the path."""
    import example_robot_data as erd
    import pinocchio as pin

    from teleop.viz import VizFrame, VizScene, make_view

    panda = erd.load("panda")
    q0 = np.array([0.0, 0.2, 0.0, -2.0, 0.0, 2.2, 0.785, 0.02, 0.02])
    data = panda.model.createData()
    tcp = panda.model.getFrameId("panda_hand_tcp")
    blade = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.1]))  # the blade tip E, 0.1 m past the TCP
    pin.framesForwardKinematics(panda.model, data, q0)
    tip0 = (data.oMf[tcp] * blade).translation
    tissue = {"origin_m": (tip0[0] + 0.03, tip0[1], tip0[2] + 0.004), "normal": (0.0, 0.0, 1.0),
              "size_m": (0.2, 0.3), "thickness_m": 0.05}
    params = ({"radius_m": 0.05, "center_m": (0.0, 0.0, 0.0)} if fixture == "sphere"
              else {"plane_origin_m": (0.0, 0.0, 0.0), "plane_normal": (0.0, 0.0, 1.0), "depth_m": 0.005})
    cobot = device_robot = None
    if device:
        from teleop.master.cobot import CobotModel

        cobot = CobotModel()

        class Device:  # the cobot's model and the visuals of its URDF, as the runs draw it
            model, _, visual_model = pin.buildModelsFromUrdf(str(cobot.urdf_path))

        device_robot = Device()
    scene = VizScene(fixture, params, "scalpel", slave_robot=panda, slave_tool_frame="panda_hand_tcp",
                     tissue=tissue, master_robot=device_robot)
    trace = []
    with make_view("meshcat", scene, record=True) as view:
        for k in range(round(duration_s / dt_s) + 1):
            t = k * dt_s
            a = 0.6 * t / duration_s
            if fixture == "sphere":  # the tool's z axis along the sphere normal, origin on the sphere
                n = np.array([np.sin(a), 0.0, np.cos(a)])
                R = pin.rpy.rpyToMatrix(0.0, a, 0.0)
                p = 0.05 * n
            else:
                R = np.diag([1.0, -1.0, -1.0])
                p = np.array([0.04 * a - 0.01, 0.0, -0.005])
            q = q0.copy()
            q[0] = 0.25 * np.sin(2.0 * a)
            pin.framesForwardKinematics(panda.model, data, q)
            X = data.oMf[tcp] * blade
            trace.append(X.translation.copy())
            hand = (p + R @ [0.004, 0.0, -0.006], R)
            view.publish(VizFrame(master_q=cobot.compute_joints(*hand) if cobot else None,
                t=t, reference_pose=(p, R), virtual_pose=hand,
                operator_wrench=np.r_[2.0, 0.5, -1.0, 0.0, 0.0, 0.0],
                constraint_wrench=np.r_[R[:, 2] * -2.5, 0.0, 0.0, 0.0],
                slave_q=q, slave_tool_pose=(X.translation, X.rotation),
                contact_wrench=np.r_[-3.0, 0.0, 4.0, 0.0, 0.0, 0.0], cut_trace=np.array(trace)))
        return view.save_html(path, autoplay=False)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("html", nargs="?", help="a recording saved by view.save_html()")
    ap.add_argument("png", help="where to write the screenshot")
    ap.add_argument("--demo", action="store_true", help="record a synthetic run first")
    ap.add_argument("--fixture", default="sphere", choices=("sphere", "scalpel"))
    ap.add_argument("--device", action="store_true", help="draw the cobot master device (with --demo)")
    ap.add_argument("--size", default="1280x720", help="WxH pixels")
    ap.add_argument("--budget-ms", type=int, default=None, help="virtual time for the page (may hang)")
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        html = args.html
        if args.demo:
            t0 = time.perf_counter()
            html = demo_recording(Path(tmp) / "demo.html", fixture=args.fixture, device=args.device)
            print(f"recorded {html.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s")
        if html is None:
            ap.error("give an HTML file or --demo")
        took = render(html, args.png, w, h, args.budget_ms)
    print(f"wrote {args.png} ({w}x{h}) in {took:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
