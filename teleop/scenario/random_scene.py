"""Random but valid scenes, for fuzzing the runtime: other masses, radii, loads, effects, periods.

``random_scene(rng)`` returns a scene *dict* in the file format (so it also exercises the loader);
``parse_scene`` turns it into a :class:`Scene`. Everything is drawn from the given generator.
"""

from __future__ import annotations

import math

import numpy as np

from teleop.dynamics.integrators import INTEGRATORS

ENGINE_EFFECTS = ("coriolis", "damping", "gravity", "springs")


def _log_uniform(rng, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def random_scene(rng: np.random.Generator, duration_s: float = 0.2) -> dict:
    fixture = str(rng.choice(["free", "rolling_disk", "sphere", "scalpel"]))
    mass = _log_uniform(rng, 1e-3, 10.0)
    # principal inertias with ratios up to 1e3, scaled to the mass
    base = mass * _log_uniform(rng, 1e-5, 1e-2)
    inertia = [base * _log_uniform(rng, 1.0, 1e3) for _ in range(3)]
    radius = _log_uniform(rng, 0.005, 0.2)
    effects = [e for e in ENGINE_EFFECTS if rng.random() < 0.5]
    integrator = str(rng.choice(sorted(INTEGRATORS)))
    if fixture in ("rolling_disk", "scalpel") and integrator == "explicit_euler":
        integrator = "parametric"
    dt = float(rng.choice([0.25e-3, 0.5e-3, 1e-3, 2e-3]))
    jitter = rng.normal(scale=1e-4, size=6)  # the loader projects the start onto the fixture
    if fixture == "rolling_disk":
        q0 = [0.0, 0.0, radius, float(rng.uniform(-3, 3)), math.pi / 2, float(rng.uniform(-3, 3))]
        fx = {"type": fixture, "radius_m": radius}
    elif fixture == "sphere":
        q0 = [0.0, -radius, 0.0, 0.0, math.pi / 2, 0.0]
        fx = {"type": fixture, "radius_m": radius}
    elif fixture == "scalpel":
        tip = float(rng.uniform(0.0, 0.2))
        depth = float(rng.uniform(0.0, 0.01))
        q0 = [0.0, 0.0, tip - depth, float(rng.uniform(-3, 3)), 0.0, 0.0]
        fx = {"type": fixture, "depth_m": depth, "tip_m": [0.0, 0.0, tip], "knife_edge": bool(rng.random() < 0.8)}
    else:
        q0 = [0.0, 0.0, 0.0, *rng.uniform(-1, 1, 3).tolist()]
        fx = {"type": fixture, "euler_sequence": str(rng.choice(["ZYX", "ZXZ", "XYZ", "YXY"]))}
    q0 = (np.array(q0) + jitter).tolist()
    load = mass * _log_uniform(rng, 0.1, 50.0)  # up to 50 g of push
    torque = min(inertia) * _log_uniform(rng, 0.1, 50.0)  # up to 50 rad/s^2 about any axis
    phases = []
    t = 0.0
    while t < duration_s:
        end = t + float(rng.uniform(0.02, duration_s))
        phases.append({
            "start_s": t, "end_s": end, "frame": str(rng.choice(["world", "tool", "task"])),
            "force_N": (rng.normal(size=3) * load).tolist(), "torque_Nm": (rng.normal(size=3) * torque).tolist(),
            "ramp_s": float(rng.uniform(0, (end - t) / 2)),
        })
        t = end
    scene = {
        "name": "fuzzed", "duration_s": duration_s, "dt_s": dt, "seed": int(rng.integers(0, 2**31)),
        "integrator": integrator, "effects": effects,
        "tool": {"mass_kg": mass, "inertia_kgm2": inertia, "q0": q0},
        "fixture": fx, "operator": {"phases": phases},
    }
    if "damping" in effects:
        # time constants from 5 periods to 10 s: stiff but inside the explicit stability limit
        scene["damping"] = {
            "linear_Ns_per_m": mass / _log_uniform(rng, 5 * dt, 10.0),
            "angular_Nms_per_rad": min(inertia) / _log_uniform(rng, 5 * dt, 10.0),
        }
    if "springs" in effects:
        k = mass * (2 * math.pi / _log_uniform(rng, 20 * dt, 5.0)) ** 2
        scene["springs"] = [{"anchor_m": (rng.normal(size=3) * 0.05).tolist(), "k_N_per_m": k}]
    return scene
