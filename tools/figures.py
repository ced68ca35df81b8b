"""Figure 8- and Figure 10-style PNGs of any run.

    python tools/figures.py LOG.npz [--out DIR]          # a log written by `teleop run --out`
    python tools/figures.py SCENE [--out DIR] [--master cobot|ideal] [--duration S]   # run, then plot

A scene is run on the cobot master by default: the figures then show device data (what the
encoders measure), as the paper's Figures 8 and 10 do. ``--master ideal`` plots the ideal master's
reference tool, which keeps the fixture exactly (round-off only).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from teleop.app.plots import plot_log


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", help="a log.npz, or a scene name/path to run first")
    ap.add_argument("--out", default="figures", help="output folder (default: figures)")
    ap.add_argument("--master", choices=["cobot", "ideal"], default="cobot",
                    help="the master a scene is run on (default: cobot, device data as in the paper)")
    ap.add_argument("--duration", type=float)
    args = ap.parse_args(argv)
    src = Path(args.source)
    if src.suffix == ".npz":
        log = src
    else:
        from teleop.app.runtime import run_scene
        from teleop.scenario.schema import load_scene

        result = run_scene(load_scene(args.source).with_overrides(master=args.master, duration_s=args.duration))
        log = Path(tempfile.mkdtemp()) / "log.npz"
        result.write_log(log)
    for p in plot_log(log, args.out):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
