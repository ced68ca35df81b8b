"""The slave half of a teleoperation tick: map the virtual tool to a target, follow it with the QP
under the patient-frame fixtures, cut the tissue, and return the contact wrench for the master.

Metrics, all in the patient frame, each tick:

* ``tip_tracking_rms_m`` - RMS distance of the slave's tool frame from its target;
* ``cut_depth_error_max_m`` - max |depth of the blade tip - fixture depth| while in tissue;
* ``cut_direction_error_max_rad`` - max angle between the slave's and the target's cutting axes;
* ``contact_force_max_N`` - max |tissue force| at the blade tip;
* ``rcm_error_max_m`` - max distance of the shaft from the trocar (laparoscopic scenes only).
"""

from __future__ import annotations

import math

import numpy as np

from teleop.dynamics.constraints import RemoteCenter
from teleop.dynamics.rotations import cross
from teleop.errors import ConfigError, SceneError
from teleop.slave.projection import project_onto_fixture
from teleop.dynamics.rows import RowStack


class SlaveSide:
    """Arm, tissue and mapping of one scene; ``step`` runs one tick, ``result`` gives the metrics."""

    def __init__(self, scene, n_ticks: int):
        from dataclasses import replace

        from teleop.contact import TissueBlock
        from teleop.contact.cutting import CuttingModel
        from teleop.scenario.build import build_fixture, build_registration
        from teleop.slave import SlaveArm, SlaveConfig

        self.reg = build_registration(scene)
        self.spec = scene.fixture
        self.constraints = build_fixture(scene.fixture).constraints
        try:
            self.arm = SlaveArm(SlaveConfig.from_dict(scene.extra["slave"], "slave"), self.constraints, scene.dt_s)
            self.tissue = None
            if "tissue" in scene.effects:
                tissue = TissueBlock.from_dict(scene.extra.get("tissue", {}), "tissue")
                if "cutting" not in scene.effects:  # normal contact only: no cutting resistance
                    tissue = replace(tissue, cutting=CuttingModel(0.0, 0.0, 0.0, 0.0))
                self.tissue = tissue
        except ConfigError as e:
            key, _, reason = str(e).partition(": ")
            raise SceneError(scene.path, key, reason) from None
        self.tip_B = np.asarray(scene.fixture.tip_m, dtype=float)
        # Force feedback through a first-order low-pass. The cutting force is steep in velocity
        # (~2000 N*s/m below 1 mm/s); fed raw to a light reference tool integrated explicitly with
        # a one-tick delay it makes a limit cycle (the tool and the arm chatter). 20 Hz keeps the
        # cut's feel and removes it; 0 turns the filter off.
        fc = scene.extra.get("mapping", {}).get("feedback_cutoff_hz", 20.0)
        if not isinstance(fc, (int, float)) or isinstance(fc, bool) or not math.isfinite(fc) or fc < 0:
            raise SceneError(scene.path, "mapping.feedback_cutoff_hz", f"expected a number >= 0, got {fc!r}")
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * fc * scene.dt_s) if fc > 0 else 1.0
        self._feedback = np.zeros(6)
        self.rcm = [c for c in self.constraints if isinstance(c, RemoteCenter)]
        self._rows = RowStack(self.constraints)  # the fixture's rows, for project_target
        normal = np.asarray(self.spec.plane_normal, dtype=float)
        self._normal = normal / np.linalg.norm(normal)
        self._plane_origin = np.asarray(self.spec.plane_origin_m, dtype=float)
        self.n = 0
        series = ("track_m", "depth_err_m", "dir_err_rad", "contact_N") + (("rcm_m",) if self.rcm else ())
        self.log = {k: np.zeros(n_ticks) for k in series}
        self.log["q"] = np.zeros((n_ticks, self.arm.nv))
        self.log["tip"] = np.zeros((n_ticks, 3))
        self.statuses: dict[str, int] = {}

    def reset(self, p_v, R_v) -> str:
        p, R, _, _ = self.reg.target(p_v, R_v, np.zeros(3), np.zeros(3))
        return self.arm.reset((p, R))

    def project_target(self, p, R, v, w):
        """The target moved onto the patient-frame fixture
        (:func:`teleop.slave.projection.project_onto_fixture`)."""
        return project_onto_fixture(self._rows, p, R, v, w)

    def step(self, p_v, R_v, v_v, w_v) -> np.ndarray:
        """One tick toward the mapped virtual tool (projected onto the fixture); returns the contact
        wrench for the master (6,), world of the master, at the master tool's origin."""
        p_t, R_t, v_t, w_t = self.project_target(*self.reg.target(p_v, R_v, v_v, w_v))
        st = self.arm.step(p_t, R_t, v_t, w_t, self._last_contact if self.n else None)
        self.statuses[st] = self.statuses.get(st, 0) + 1
        p, R = self.arm.tool_pose()
        v, w = self.arm.tool_twist()
        # the slave's tool frame sits at the blade tip (the scene's tip_m is then 0); allow an offset
        d = R @ (self.tip_B / self.reg.scale)
        tip, v_tip = p + d, v + cross(w, d)
        contact = self.tissue.wrench(tip, R, v_tip, w) if self.tissue is not None else np.zeros(6)
        self._last_contact = contact
        i = self.n
        depth = -float(self._normal @ (tip - self._plane_origin))
        self.log["track_m"][i] = float(np.linalg.norm(p - p_t))
        # error while the blade is in the tissue; a tiny floor marks "inside" for the cut length
        self.log["depth_err_m"][i] = max(abs(depth - self.spec.depth_m), 1e-15) if depth > 0 else 0.0
        c = float(np.clip(R[:, 0] @ R_t[:, 0], -1.0, 1.0))
        self.log["dir_err_rad"][i] = math.acos(c)
        self.log["contact_N"][i] = float(np.linalg.norm(contact[:3]))
        if self.rcm:
            self.log["rcm_m"][i] = max(float(np.linalg.norm(r.residual(p, R))) for r in self.rcm)
        self.log["q"][i] = self.arm.q
        self.log["tip"][i] = tip
        self.n += 1
        # to the master: scaled, in master axes, moved from the slave tip to the master tool origin
        F = self.reg.wrench_to_master(contact)
        r_M = self.reg.X_PM_R.T @ d * self.reg.scale
        F[3:] += cross(r_M, F[:3])
        self._feedback = self._feedback + self._alpha * (F - self._feedback)
        return self._feedback

    def result(self) -> dict:
        k = self.n
        out = {
            "tip_tracking_rms_m": float(np.sqrt(np.mean(self.log["track_m"][:k] ** 2))) if k else 0.0,
            "cut_depth_error_max_m": float(self.log["depth_err_m"][:k].max(initial=0.0)),
            "cut_direction_error_max_rad": float(self.log["dir_err_rad"][:k].max(initial=0.0)),
            "contact_force_max_N": float(self.log["contact_N"][:k].max(initial=0.0)),
        }
        tip = self.log["tip"][:k]
        inside = self.log["depth_err_m"][:k] > 0  # tip below the surface
        if k > 1:
            steps = np.linalg.norm(np.diff(tip, axis=0), axis=1)
            out["cut_length_m"] = float(steps[inside[1:] & inside[:-1]].sum())
        if self.rcm:
            out["rcm_error_max_m"] = float(self.log["rcm_m"][:k].max(initial=0.0))
        return out

    def trimmed_log(self) -> dict:
        return {f"slave_{k}": v[: self.n] for k, v in self.log.items()}
