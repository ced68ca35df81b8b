"""Pinocchio's own constrained forward dynamics for a free rigid body, as an oracle."""

import numpy as np
import pinocchio as pin


def free_flyer_model(mass: float, J: np.ndarray):
    model = pin.Model()
    jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "tool")
    model.appendBodyToJoint(jid, pin.Inertia(mass, np.zeros(3), J), pin.SE3.Identity())
    model.gravity = pin.Motion.Zero()
    return model


def pin_constrained(model, p, R, v_W, w_W, wrench_W, G, bias):
    """World (vdot, wdot) and multipliers from pin.forwardDynamics with constraint Jacobian G.

    Pinocchio's free-flyer velocity is body-frame (v_B, w_B); its Jacobian is G blockdiag(R, R)
    and the drift gamma = bias + G_v (w x v) (J a + gamma = 0) converts the world-frame bias.
    """
    data = model.createData()
    quat = pin.Quaternion(R)
    q = np.concatenate([p, quat.coeffs()])
    v = np.concatenate([R.T @ v_W, R.T @ w_W])
    tau = np.concatenate([R.T @ wrench_W[:3], R.T @ wrench_W[3:]])
    X = np.zeros((6, 6))
    X[:3, :3] = R
    X[3:, 3:] = R
    J = G @ X
    gamma = bias + G[:, :3] @ np.cross(w_W, v_W)  # pinocchio solves J a = -gamma
    a = pin.forwardDynamics(model, data, q, v, tau, J, gamma, 0.0)
    w_B = R.T @ w_W
    vdot = R @ (a[:3] + np.cross(w_B, v[:3]))  # classical acceleration of the origin
    wdot = R @ a[3:]
    return np.concatenate([vdot, wdot]), np.array(data.lambda_c)
