"""Options of `simulate`: the foundation grid (the loading systems are in `_loading.py`)."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import ArrayLike, Float

from .._validate import check_positive

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

    - `cells`: number of cells $n$ (static). Default `DEFAULT_CELLS` = 64, which keeps the
      discretisation error of the force at about $2.5\times10^{-5}$ of its peak for an
      approach-hold-lift history (measured in `benchmarks/bench_foundation.py`; second
      order, $\propto n^{-2}$, over approach and hold: $1.9\times10^{-5}$ with 64 cells,
      $7.6\times10^{-5}$ with 32; less regular on the lift, where springs are released
      between nodes: $2.1\times10^{-4}$ with 32 cells). The elastic solid and a
      lift from a fully relaxed state are exact on any grid. Use
      `simulate(..., estimate_error=True)` for an estimate for a given history.
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
    depth: Float[ArrayLike, ""] | None = None

    def __check_init__(self):
        if int(self.cells) < 2:
            raise ValueError(f"`cells` must be >= 2; got {self.cells}.")
        if self.depth is not None:
            check_positive("depth", self.depth, "m")
