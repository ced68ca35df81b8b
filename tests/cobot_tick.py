"""The bilateral tick on the master side, as the run loop does it, for the master tests: operator
wrench -> master.sense -> reference tool step -> master.command."""

import numpy as np

from teleop.master import CobotConfig, CobotMaster


def make_cobot(tool, cfg: CobotConfig, dt_s: float, rng) -> CobotMaster:
    """A cobot master for ``tool`` (its start pose and mass)."""
    return CobotMaster(cfg, dt_s, rng, *tool.pose(), tool.body.mass_kg)


def tick(master, tool, hand_wrench_W, contact_wrench_W=None) -> str:
    """One period; returns the master's status if it is not "ok", else the tool's."""
    f_v = master.sense(hand_wrench_W)
    p_r, R_r = tool.pose()
    v_r, w_r = tool.twist()
    st = tool.step(master.dt_s, f_v if contact_wrench_W is None else f_v + contact_wrench_W)
    st_master = master.command(p_r, R_r, np.concatenate([v_r, w_r]), tool.acceleration_W)
    return st_master if st_master != "ok" else st
