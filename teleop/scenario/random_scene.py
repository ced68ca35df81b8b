"""Random but valid scenes, for fuzzing the runtime: other masses, radii, loads, effects, periods.

Valid means physically plausible too (:mod:`teleop.scenario.plausibility`): the inertias are a real
body's (the triangle inequality, a radius of gyration under 1 m) and every value is in its range.

``random_scene(rng)`` returns a scene *dict* in the file format (so it also exercises the loader);
``parse_scene`` turns it into a :class:`Scene`. Everything is drawn from the given generator.
"""

from __future__ import annotations

import math

import numpy as np

from teleop.dynamics.integrators import INTEGRATORS
from teleop.scenario.tables import MAX_FORCE_N, MAX_STIFFNESS_N_PER_M, MAX_TORQUE_NM

ENGINE_EFFECTS = ("coriolis", "damping", "gravity", "springs")


def _log_uniform(rng, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def random_scene(rng: np.random.Generator, duration_s: float = 0.2) -> dict:
    fixture = str(rng.choice(["free", "rolling_disk", "sphere", "scalpel"]))
    mass = _log_uniform(rng, 1e-3, 10.0)
    # a real body's principal inertias, from its mass distribution's second moments S (kg*m^2) about
    # the principal axes: J_x = S_y + S_z etc., so J1 + J2 >= J3 always; S up to 1e3 apart (from a
    # ball to a thin rod or a lamina), J / m at most 0.1 m^2 (and J <= 1 kg*m^2 at 10 kg)
    base = mass * _log_uniform(rng, 1e-6, 5e-5)
    s = [base * _log_uniform(rng, 1.0, 1e3) for _ in range(3)]
    inertia = [s[1] + s[2], s[0] + s[2], s[0] + s[1]]
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
            # clipped to what a hand can push and twist (teleop.scenario.tables.MAX_FORCE_N, MAX_TORQUE_NM)
            "force_N": np.clip(rng.normal(size=3) * load, -MAX_FORCE_N, MAX_FORCE_N).tolist(),
            "torque_Nm": np.clip(rng.normal(size=3) * torque, -MAX_TORQUE_NM, MAX_TORQUE_NM).tolist(),
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
        k = min(mass * (2 * math.pi / _log_uniform(rng, 20 * dt, 5.0)) ** 2, MAX_STIFFNESS_N_PER_M)
        scene["springs"] = [{"anchor_m": (rng.normal(size=3) * 0.05).tolist(), "k_N_per_m": k}]
    return scene
