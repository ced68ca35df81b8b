"""One sweep runner for the studies: a pure point function mapped over a list of points on Dask.

    from teleop.app.sweep import add_sweep_args, run_sweep
    results = run_sweep(run_point, points, workers=2, scheduler=None, desc="my study")

By default the points run on a local Dask cluster of ``workers`` single-threaded processes (no
dashboard, bound to 127.0.0.1); ``scheduler="tcp://HOST:PORT"`` sends them to a running Dask
scheduler instead (its workers need ``teleop`` installed; the point function's own tools module
travels with the task). A tqdm bar counts finished points on a terminal and stays silent in a pipe.
Results come back in the points' order.

Results do not depend on the number of workers: before each point the runner seeds Python's and
numpy's global generators from the point itself (``point_seed``: a hash of its parameters), so
even a library that draws from the global state draws the same numbers wherever the point runs.
A point function should still take its randomness from its own parameters (a seed in the point,
or the scene's seed), through its own ``numpy.random.Generator``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import sys
from collections.abc import Callable, Sequence
from functools import partial

import cloudpickle
import numpy as np
from dask.distributed import Client, LocalCluster, as_completed
from tqdm import tqdm

#: no dashboard; the scheduler's small HTTP server (health checks) on a free port of 127.0.0.1
#: rather than 8787, which another cluster may hold (a warning on every run)
QUIET_SCHEDULER = {"dashboard": False, "dashboard_address": "127.0.0.1:0"}


def point_seed(point) -> int:
    """A 32-bit seed that depends only on the point's parameters (sha256 of its canonical JSON)."""
    text = json.dumps(point, sort_keys=True, default=repr)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")


def _seeded_call(fn: Callable, point):
    """fn(point) with the global generators seeded from the point (see the module docstring)."""
    s = point_seed(point)
    random.seed(s)
    np.random.seed(s)  # noqa: NPY002 - the global generator a point function draws from, seeded per point
    return fn(point)


def _ship_by_value(fn: Callable) -> None:
    """A point function from a tools script (not an installed package) is pickled by value, so
    that the workers of an external cluster need only ``teleop``, not this checkout's tools/."""
    mod = sys.modules.get(getattr(fn, "__module__", "") or "")
    if mod is None or fn.__module__ == "__main__" or fn.__module__.split(".")[0] == "teleop":
        return  # __main__ goes by value anyway; teleop is on every worker
    cloudpickle.register_pickle_by_value(mod)


def run_sweep(fn: Callable, points: Sequence, workers: int = 2, scheduler: str | None = None,
              desc: str = "sweep") -> list:
    """``[fn(p) for p in points]`` through Dask: a local cluster of ``workers`` processes, or the
    scheduler at ``scheduler`` (an address such as ``tcp://127.0.0.1:8786``). Results in the
    points' order; a point that raises re-raises here. A tqdm bar on a terminal."""
    points = list(points)
    if not points:
        return []
    if scheduler is None and workers < 1:
        raise ValueError(f"workers: expected at least 1, got {workers}")
    _ship_by_value(fn)
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, scheduler_kwargs=QUIET_SCHEDULER)
    try:
        with Client(scheduler or cluster) as client:
            futures = client.map(partial(_seeded_call, fn), points, pure=False)
            with tqdm(total=len(futures), desc=desc, unit="point", disable=None) as bar:
                for _ in as_completed(futures):
                    bar.update(1)
            return client.gather(futures)
    finally:
        if cluster is not None:
            cluster.close()


def add_sweep_args(ap: argparse.ArgumentParser, workers: int = 2) -> None:
    """``--workers N`` and ``--scheduler ADDRESS`` on a tool's command line."""
    ap.add_argument("--workers", type=int, default=workers,
                    help=f"local Dask worker processes, one thread each (default {workers})")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="send the points to the Dask scheduler at ADDRESS (e.g. tcp://HOST:8786) "
                         "instead of a local cluster")


def check_sweep_args(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """One-line argparse error (exit 2) for a worker count below 1."""
    if args.workers < 1:
        ap.error(f"--workers: expected at least 1, got {args.workers}")
