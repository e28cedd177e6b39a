"""Options of `simulate`: the foundation grid (the loading systems are in `_loading.py`)."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from .._solvers import as_float
from .._validate import Constraint

#: Default number of cells of the foundation grid (see `FoundationGrid`).
DEFAULT_CELLS = 64


class FoundationGrid(eqx.Module):
    r"""The spring grid of the MDR foundation.

    Springs sit at $x_j$ with $g(x_j) = j\,g_\max/n$, $j = 0..n$: uniform in the *touch depth*,
    so every cell spans the same increment of indentation and the springs of one cell touched
    within the same fraction of the approach. For the parabola $x_j = L\sqrt{j/n}$ (densest at
    the contact edge), for the cone the grid is uniform. The flat punch uses a uniform grid
    on $[0, a_0]$ (all its springs share one history, so any grid is exact).

    **Arguments:**

    - `cells`: number of cells $n$ (static). Default `DEFAULT_CELLS` = 64. The error of the
      force is second order, $\propto n^{-2}$, over approach and hold (less regular on the
      lift, where springs are released between nodes); its table for an approach-hold-lift
      history against a 1,024-cell reference is measured by `benchmarks/bench_foundation.py`
      (results in `benchmarks/results/forward.md`). The elastic solid and a lift from a
      fully relaxed state are exact on any grid. `simulate(..., estimate_error=True)`
      estimates the error for a given history.
    - `depth`: largest indentation $g_\max$ [m] the grid covers. Default, times $(1 + 1/n)$:
      under displacement control the largest input (the contact never extends beyond
      $g(x) = \max_t d(t)$); under compliant loading the indentation at which the relaxed
      force balances the spring at the largest drive position (an upper bound, since the
      viscoelastic force on a loading branch is never below the relaxed one), rounded up to
      1/8 of an octave so that the grid is piecewise constant in the parameters. When fitting
      with compliant loading pass `depth` explicitly: the grid is then fixed and the
      gradients are those of one discretised model.
    """

    cells: int = eqx.field(static=True, default=DEFAULT_CELLS)
    depth: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda d: None if d is None else as_float(d)
    )

    def __check_init__(self):
        if int(self.cells) < 2:
            raise ValueError(f"`cells` must be >= 2; got {self.cells}.")
        for constraint in self.domain():
            constraint.check()

    def domain(self):
        """The grid depth, when given: finite and > 0 [m]."""
        if self.depth is None:
            return ()
        return (Constraint("depth", self.depth, "m", kind="length"),)
