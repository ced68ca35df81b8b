"""Compiled kernels (numba) of the engine's hot path, each one call per use:

* :mod:`.rows` - the constraint rows G and their velocity-product terms, by kind code;
* :mod:`.motion` - the pose terms, one evaluation of eqs. 8-9, the kinetic-energy projection of
  the rates, and the flat (affine psi) parametric step.

The readable definitions stay in Python and are the reference; tests/unit/test_kernels.py holds
every kernel equal to them. Kernels compile on first use and are cached on disk.
"""

from teleop.dynamics.kernels.motion import (
    SOLVE_CHOLESKY,
    SOLVE_NONE,
    SOLVE_PINV,
    cholesky,
    constraint_terms,
    effect_params,
    evaluate,
    flat_advance,
    left_pinv,
    newton_euler,
    pose_terms,
    project_parameter_rates,
    project_rates,
    project_twist,
    rate_map_terms,
)
from teleop.dynamics.kernels.rows import (
    KIND_AXIS_ALONG,
    KIND_AXIS_IN_PLANE,
    KIND_KNIFE_EDGE,
    KIND_POINT_DEPTH,
    KIND_REMOTE_CENTER,
    KIND_SPHERE,
    NPAR,
    row_params,
    stack_rows,
)

__all__ = [
    "KIND_AXIS_ALONG", "KIND_AXIS_IN_PLANE", "KIND_KNIFE_EDGE", "KIND_POINT_DEPTH", "KIND_REMOTE_CENTER",
    "KIND_SPHERE", "NPAR", "SOLVE_CHOLESKY", "SOLVE_NONE", "SOLVE_PINV", "cholesky", "constraint_terms",
    "effect_params", "evaluate", "flat_advance", "left_pinv", "newton_euler", "pose_terms",
    "project_parameter_rates", "project_rates", "project_twist", "rate_map_terms", "row_params", "stack_rows",
]
