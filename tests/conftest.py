"""Shared test helpers: paper bodies and a deterministic random state generator."""

import numpy as np
import pytest

from teleop.dynamics.body import RigidBody


@pytest.fixture
def paper_body() -> RigidBody:
    """The paper's tool: 0.25 kg, every principal inertia 0.0025 kg m^2."""
    return RigidBody(0.25, [0.0025, 0.0025, 0.0025])


@pytest.fixture
def lopsided_body() -> RigidBody:
    """An asymmetric body (distinct principal inertias, off-diagonal terms) to exercise Coriolis."""
    J = np.array([[0.004, 0.0003, -0.0002], [0.0003, 0.0025, 0.0001], [-0.0002, 0.0001, 0.0011]])
    return RigidBody(0.4, J)
