"""Compiled kernels (numba) of the engine, each piece of math written once:

* :mod:`.rows` - the constraint rows G, their velocity-product terms and residuals, by kind code;
* :mod:`.motion` - the chart terms, one evaluation of eqs. 8-9 from given rows (G, b), the
  kinetic-energy projection of twists and rates, and the flat (affine psi) parametric step;
* :mod:`.steps` - a whole step in one call (the flat parametric and energy steps, one
  evaluation), chaining the kernels above, for a model whose rows and effects are all compiled;
* :mod:`.so3` - log3, exp3 and the Euler angles of a rotation in a chart.

They compile on first use and are cached on disk; ``NUMBA_DISABLE_JIT=1`` runs the same code as
plain Python, for a debugger. They are tested against independent oracles (finite differences,
Pinocchio's constrained dynamics, the chart-coordinate form of eqs. 8-9, energy).
"""
