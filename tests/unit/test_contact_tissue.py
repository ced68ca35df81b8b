"""Tissue block: normal force, cutting and lateral resistance, configuration errors."""

import numpy as np
import pytest

from teleop.contact import CuttingModel, TissueBlock
from teleop.util.errors import ConfigError

R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
O = np.array([0.5, 0.0, 0.2])


def test_no_force_above_the_surface():
    t = TissueBlock.from_dict({"origin_m": O.tolist()})
    rep = t.compute_contact(O + [0, 0, 0.001], R_CUT, np.array([0.01, 0, -0.01]), np.zeros(3))
    assert not rep.in_contact and np.all(rep.wrench == 0.0)


@pytest.mark.parametrize("model", ["hunt_crossley", "kelvin_voigt"])
def test_normal_force_pushes_out_and_grows_with_depth(model):
    t = TissueBlock.from_dict({"origin_m": O.tolist(), "model": model})
    f = [t.wrench(O - [0, 0, d], R_CUT, np.zeros(3), np.zeros(3))[2] for d in (0.001, 0.003, 0.005)]
    assert 0 < f[0] < f[1] < f[2]
    kv = TissueBlock(origin_m=O, model="kelvin_voigt", stiffness=1000.0, damping_Ns_per_m=0.0)
    assert np.isclose(kv.wrench(O - [0, 0, 0.004], R_CUT, np.zeros(3), np.zeros(3))[2], 4.0)
    hc = TissueBlock(origin_m=O, stiffness=1e4, exponent=1.5, alpha_s_per_m=0.0)
    assert np.isclose(hc.wrench(O - [0, 0, 0.004], R_CUT, np.zeros(3), np.zeros(3))[2], 1e4 * 0.004**1.5)
    # withdrawing fast: no sticking (force clamped at zero)
    sticky = TissueBlock(origin_m=O, model=model, alpha_s_per_m=100.0, damping_Ns_per_m=1e4)
    assert sticky.wrench(O - [0, 0, 0.001], R_CUT, np.array([0, 0, 1.0]), np.zeros(3))[2] == 0.0


def test_depth_is_clamped_to_the_thickness():
    t = TissueBlock(origin_m=O, thickness_m=0.01)
    assert t.compute_depth(O - [0, 0, 0.5]) == 0.01


def test_cutting_resists_motion_and_grows_with_depth_and_speed():
    t = TissueBlock(origin_m=O)

    def f_cut(d, v):
        return t.wrench(O - [0, 0, d], R_CUT, np.array([v, 0, 0]), np.zeros(3))[0]

    assert f_cut(0.005, 0.01) < 0 < f_cut(0.005, -0.01)
    assert f_cut(0.005, 0.01) < f_cut(0.002, 0.01) < 0
    assert f_cut(0.005, 0.05) < f_cut(0.005, 0.01)
    # lateral: moving sideways (world y, the blade's side axis) meets resistance along -y
    lat = t.compute_contact(O - [0, 0, 0.005], R_CUT, np.array([0, 0.01, 0]), np.zeros(3))
    assert lat.wrench[1] < 0 and lat.lateral_N > 0 and lat.cutting_N < 1e-6
    # twisting the blade in the cut meets a torque about the normal
    tw = t.wrench(O - [0, 0, 0.005], R_CUT, np.zeros(3), np.array([0, 0, 1.0]))
    assert tw[5] < 0


@pytest.mark.parametrize("d, key", [
    ({"thickness_m": -1}, "thickness_m"),
    ({"model": "spring"}, "model"),
    ({"normal": [0, 0, 0]}, "normal"),
    ({"color": 1}, "tissue.color"),
    ({"stiffness": "hard"}, "tissue.stiffness"),
    ({"cutting": {"f_N_per_m": -1}}, "f_N_per_m"),
    ({"cutting": {"edge": 1}}, "tissue.cutting"),
])
def test_bad_tissue_settings_name_the_key(d, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        TissueBlock.from_dict(d, "tissue")


def test_cutting_model_alone():
    F_cut, F_lat, tau, v_c = CuttingModel().compute_forces(0.0, np.array([0, 0, 1.0]), R_CUT, np.ones(3), np.ones(3))
    assert v_c == 0.0 and not F_cut.any() and not F_lat.any() and not tau.any()
