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


@pytest.fixture(autouse=True)
def _teleop_log_reaches_caplog():
    """The CLI's configure_logging (run by any test that calls main) stops the "teleop" logger
    from propagating, and a library's logging.config (dask's) disables the loggers that exist;
    each test starts with them enabled and propagating to pytest's caplog again, so a test's log
    assertions do not depend on which tests ran before it in the same worker."""
    import logging

    log = logging.getLogger("teleop")
    saved = (log.propagate, list(log.handlers), log.level)
    log.propagate, log.handlers[:] = True, []
    for name, other in list(logging.root.manager.loggerDict.items()):  # a library's dictConfig (dask's)
        if name.startswith("teleop") and isinstance(other, logging.Logger):  # may have disabled them
            other.disabled = False
    yield
    log.propagate, log.handlers[:], log.level = saved[0], saved[1], saved[2]
