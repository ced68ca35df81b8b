"""teleop.app.sweep and the studies on it: results in the points' order, each point seeded from itself,
the same answers with 1 and 2 workers (and as in-process), and --scheduler reaching an external
Dask cluster."""

import csv
import importlib.util
import time
from pathlib import Path

import numpy as np
import pytest
from dask.distributed import LocalCluster, get_worker

from teleop.app.sweep import QUIET_SCHEDULER, point_seed, run_sweep

TOOLS = Path(__file__).resolve().parents[2] / "tools"
MEASURED = ("tick_median_us", "tick_p99_us", "cpu_load_pct")  # CPU timings: differ run to run


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(f"teleop_tools_{name}", TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def draw_late_first(p: int) -> tuple:
    """The point, a draw from numpy's global generator and the worker's address; the first
    points sleep longest, so they finish last."""
    time.sleep(0.05 * (6 - p))
    return p, float(np.random.random()), get_worker().address  # noqa: NPY002 - the generator run_sweep seeds


def test_point_seed_depends_on_the_parameters_only():
    assert point_seed({"a": 1, "b": [2.0, "x"]}) == point_seed({"b": [2.0, "x"], "a": 1})
    assert point_seed({"a": 1}) != point_seed({"a": 2})
    assert point_seed(3) == point_seed(3) and 0 <= point_seed(3) < 2**32


def test_results_come_in_input_order_and_draws_follow_the_point_not_the_worker():
    """The default local cluster (2 processes): the first points finish last yet come first, and
    each draw is the one seeded from its point (as in-process, whichever worker ran it)."""
    pts = list(range(6))
    two = run_sweep(draw_late_first, pts, workers=2)
    assert [r[0] for r in two] == pts
    expected = []
    for p in pts:
        np.random.seed(point_seed(p))  # noqa: NPY002 - as run_sweep seeds it, in-process
        expected.append(np.random.random())  # noqa: NPY002 - the draw the point gets
    assert [r[1] for r in two] == expected
    assert len({r[2] for r in two}) == 2  # both workers took points


def test_scheduler_reaches_an_external_cluster():
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs=QUIET_SCHEDULER) as cluster:
        res = run_sweep(draw_late_first, [4, 5], scheduler=cluster.scheduler_address)
        assert [r[0] for r in res] == [4, 5]
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        assert {r[2] for r in res} <= set(cluster.scheduler_info["workers"])


def test_an_empty_sweep_and_a_bad_worker_count():
    assert run_sweep(draw_late_first, []) == []
    with pytest.raises(ValueError, match="workers"):
        run_sweep(draw_late_first, [1], workers=0)


def _rows(path: Path) -> list:
    out = []
    for r in csv.DictReader(open(path)):
        for k in MEASURED:
            r.pop(k)
        out.append(r)
    return out


@pytest.mark.long
def test_accuracy_study_gives_the_same_table_with_1_and_2_workers(tmp_path):
    """A small study through the tool's command line: the same CSV apart from the measured CPU
    columns (proxqp is left out: its iterates depend on the heap's alignment, run to run in one
    process). Then the same points in-process give the same numbers."""
    acc = _tool("accuracy_vs_time")
    acc.SOLVERS = (("daqp", None),)
    args = ["--scenes", "paper_disk_on_sphere", "undamped_rolling_disk", "--integrators", "energy", "explicit_euler",
            "--periods", "1", "2", "--seconds", "0.2", "--incision-seconds", "0.1"]
    assert acc.main([*args, "--out", str(tmp_path / "w1"), "--workers", "1"]) == 0
    assert acc.main([*args, "--out", str(tmp_path / "w2"), "--workers", "2"]) == 0
    one, two = _rows(tmp_path / "w1" / "accuracy.csv"), _rows(tmp_path / "w2" / "accuracy.csv")
    assert len(one) == 2 * 2 * 2 + 3 + 2 + 1 + 1 == len(two)  # runs, effect sets, incision
    assert one == two
    assert [r["integrator"] for r in one if r["default"] == "True"] == ["energy"] * 3  # two scenes, the incision
    points = acc.sweep_points(0.2, 0.1, ["paper_disk_on_sphere"], ["energy"], [1.0], solvers=())
    direct = acc.assemble(points, [acc.run_point(p) for p in points])
    swept = acc.assemble(points, run_sweep(acc.run_point, points, workers=2))
    strip = [{k: v for k, v in r.items() if k not in MEASURED} for r in direct]
    np.testing.assert_equal(strip, [{k: v for k, v in r.items() if k not in MEASURED} for r in swept])  # NaN == NaN


@pytest.mark.long
def test_fuzzer_tally_is_the_same_with_1_and_2_workers():
    bench = _tool("bench")
    one = bench.fuzz_scenes(4, workers=1)
    assert one == bench.fuzz_scenes(4, workers=2)
    assert one["scenes"] == 4 and sum(one["statuses"].values()) == 4
    assert [bench.fuzz_point(s) for s in range(2)] == run_sweep(bench.fuzz_point, range(2), workers=2)


@pytest.mark.long
def test_delay_study_rows_are_the_same_with_1_and_2_workers(tmp_path):
    study = _tool("delay_study")
    args = ["--scenes", "stiff_contact", "--walls", "1e4", "--delays", "0", "50", "--losses", "0", "--guards", "off",
            "tdpa", "--seconds", "0.3"]
    assert study.main([*args, "--out", str(tmp_path / "w1"), "--workers", "1"]) == 0
    assert study.main([*args, "--out", str(tmp_path / "w2"), "--workers", "2"]) == 0

    def rows(p):
        return [{k: v for k, v in r.items() if k not in ("tick_us", "wall_s")} for r in csv.DictReader(open(p))]

    one, two = rows(tmp_path / "w1" / "delay.csv"), rows(tmp_path / "w2" / "delay.csv")
    assert len(one) == 4 and one == two
    assert [(r["delay_ms"], r["guard"]) for r in one] == [("0.0", "off"), ("0.0", "tdpa"), ("50.0", "off"),
                                                          ("50.0", "tdpa")]
