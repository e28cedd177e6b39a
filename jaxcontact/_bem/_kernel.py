"""The grid and the elastic kernel of the BEM: Love's displacement under a uniformly
loaded rectangle and its FFT convolution on the zero-padded grid (`jaxcontact._bem`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._solvers import as_float, float64_scope, floats_to_arrays
from .._validate import (
    check_positive,
)

__all__ = ["BEMGrid", "love_displacement"]

class BEMGrid(eqx.Module):
    r"""A square grid of $n\times n$ cells covering $[-L/2, L/2]^2$, centred on the axis.

    **Arguments:**

    - `cells`: number of cells $n$ per side (static), >= 2. Even $n$ puts the axis on a cell
      corner, so an axisymmetric problem keeps the grid's full symmetry.
    - `extent`: side $L$ [m] of the simulated square, > 0; the cell side is
      $\Delta = L/n$. The half-space outside the square is unloaded (not periodic).
    """

    cells: int = eqx.field(static=True)
    # an array (never a Python float): compiled programs are shared by all extents
    extent: Float[Array, ""] = eqx.field(converter=lambda x: floats_to_arrays(as_float(x)))

    def __check_init__(self):
        if int(self.cells) < 2:
            raise ValueError(f"`cells` must be an integer >= 2; got {self.cells}.")
        check_positive("extent", self.extent, "m")

    @property
    def cell_size(self) -> Array:
        r"""Cell side $\Delta = L/n$ [m]."""
        return self.extent / self.cells

    def coordinates(self) -> tuple[Array, Array]:
        """Cell-centre coordinates `(x, y)` [m], each of shape `(n, n)` (`x` along axis 0)."""
        c = (jnp.arange(self.cells) + 0.5 - 0.5 * self.cells) * self.cell_size
        return jnp.meshgrid(c, c, indexing="ij")


def _primitive(X, Y):
    ax, ay = jnp.abs(X), jnp.abs(Y)
    safe_x = jnp.where(ax > 0, ax, 1.0)
    safe_y = jnp.where(ay > 0, ay, 1.0)
    val = jnp.where(ax > 0, ax * jnp.arcsinh(ay / safe_x), 0.0) + jnp.where(
        ay > 0, ay * jnp.arcsinh(ax / safe_y), 0.0
    )
    return jnp.sign(X) * jnp.sign(Y) * val


@float64_scope
def love_displacement(
    x: Float[ArrayLike, "..."],
    y: Float[ArrayLike, "..."],
    half_width: Float[ArrayLike, ""],
    half_height: Float[ArrayLike, ""],
) -> Float[Array, "..."]:
    r"""Surface displacement under a uniformly loaded rectangle (Love), per unit $p/E^*$ [m].

    $$u(x, y) = \frac{1}{\pi}\int_{-a}^{a}\int_{-b}^{b}
      \frac{\mathrm{d}x'\,\mathrm{d}y'}{\sqrt{(x-x')^2 + (y-y')^2}},$$
    the displacement (positive into the half-space) of a half-space with $E^* = 1$ under a
    unit pressure on $|x'|\le a$, $|y'|\le b$; multiply by $p/E^*$ for pressure $p$ [Pa].

    **Arguments:**

    - `x`, `y`: surface points [m] (broadcast against each other).
    - `half_width`, `half_height`: $a$, $b$ [m], > 0.
    """
    x, y = as_float(x), as_float(y)
    a, b = as_float(half_width), as_float(half_height)
    total = (
        _primitive(x + a, y + b)
        - _primitive(x - a, y + b)
        - _primitive(x + a, y - b)
        + _primitive(x - a, y - b)
    )
    return total / jnp.pi


def _kernel_hat(n: int, delta) -> Array:
    """rfft2 of the unit-modulus influence of one cell on the zero-padded (2n)^2 grid."""
    k = jnp.arange(2 * n)
    off = jnp.where(k < n, k, k - 2 * n).astype(float) * delta
    ox, oy = jnp.meshgrid(off, off, indexing="ij")
    kern = love_displacement(ox, oy, 0.5 * delta, 0.5 * delta)
    # the offset +-n never pairs two cells of the n x n grid: zero it (not periodic)
    mask = (k == n)
    kern = jnp.where(mask[:, None] | mask[None, :], 0.0, kern)
    return jnp.fft.rfft2(kern)


def _convolve(khat: Array, q: Array) -> Array:
    n = q.shape[0]
    qp = jnp.zeros((2 * n, 2 * n), q.dtype).at[:n, :n].set(q)
    return jnp.fft.irfft2(jnp.fft.rfft2(qp) * khat, s=(2 * n, 2 * n))[:n, :n]
