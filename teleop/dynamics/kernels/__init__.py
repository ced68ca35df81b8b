"""Compiled kernels (numba) of the engine, each piece of math written once:

* :mod:`.rows` - the constraint rows G, their velocity-product terms and residuals, by kind code;
* :mod:`.motion` - the chart terms, one evaluation of eqs. 8-9 from given rows (G, b), the
  kinetic-energy projection of twists and rates, and the flat (affine psi) parametric step;
* :mod:`.so3` - log3 and exp3.

They compile on first use and are cached on disk; ``NUMBA_DISABLE_JIT=1`` runs the same code as
plain Python, for a debugger. They are tested against independent oracles (finite differences,
Pinocchio's constrained dynamics, the chart-coordinate form of eqs. 8-9, energy).
"""

from teleop.dynamics.kernels.motion import (  # noqa: E402
    SOLVE_CHOLESKY, SOLVE_NONE, SOLVE_PINV, cholesky, constraint_terms, effect_params, evaluate,
    flat_advance, left_pinv, newton_euler, pose_terms, project_parameter_rates, project_rates,
    project_twist, rate_map_terms,
)
from teleop.dynamics.kernels.rows import NPAR  # noqa: E402


def row_params(c):
    from teleop.dynamics.constraints import compiled_kind
    k = compiled_kind(c)
    return None if k is None else (k, c.kernel_params())
