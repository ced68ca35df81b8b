"""tools/stability_map.py: a point is a seeded lockstep run (the same answer twice, and through
Dask the same as in-process, whatever the worker count), classified as the map states."""

import importlib.util
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[2] / "tools" / "stability_map.py"


@pytest.fixture(scope="module")
def smap():
    spec = importlib.util.spec_from_file_location("teleop_tools_stability_map", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def point(mass, comp, index):
    return {"sweep": "zwidth", "axis": "linear", "mass": mass, "damping": 0.0, "stiffness": 0.0,
            "inertia_compensation": comp, "seed": 0, "index": index}


def test_a_point_is_deterministic_and_classified(smap):
    light = smap.run_point(point(0.02, "commanded", 0))
    assert not light["stable"] and light["status"] == "tracking_error"  # below the 0.041 kg boundary
    ok = smap.run_point(point(0.08, "commanded", 1))
    assert ok["stable"] and ok["rms_tail"] < 5e-5
    assert smap.run_point(point(0.08, "commanded", 1)) == ok


def test_the_analytic_params_follow_the_point(smap):
    p = smap.analytic_params({**point(0.05, "servo_model", 0), "latency_ms": 1.5, "dt_s": 1e-3, "handle_scale": 2.0})
    assert p.latency_periods == 2 and p.handle_mass == pytest.approx(0.3) and p.compensation == "servo_model"


@pytest.mark.long
def test_dask_gives_the_in_process_answers_for_any_worker_count(smap):
    pts = [point(0.02, "commanded", 0), point(0.08, "servo_model", 1), point(0.01, "servo_model", 2)]
    direct = [smap.run_point(p) for p in pts]
    assert smap.run_points(pts, workers=1) == direct
    assert smap.run_points(pts, workers=2) == direct
