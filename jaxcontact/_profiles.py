r"""Axisymmetric indenter profiles and their MDR transforms.

A profile is the gap $f(r)$ between the indenter and the flat surface, in metres, as a
function of the in-plane radius $r$ (metres), with $f(0) = 0$. The Method of Dimensionality
Reduction replaces it by the plane profile (paper, eq. 1)

$$g(x) = |x| \int_0^{|x|} \frac{f'(r)}{\sqrt{x^2 - r^2}}\,\mathrm{d}r,$$

which is pressed into a one-dimensional foundation of independent springs.

Every profile is an `equinox.Module` (a pytree), so it can be passed through `jit`, `vmap`
and `grad`. Each one provides

- `shape(r)`: the 3D profile $f(r)$ [m];
- `g(x)`: the MDR profile $g(x)$ [m] (even in $x$);
- `dg(x)`: $g'(x)$ for $x \ge 0$ [dimensionless];
- `integral_g(a)`: $\int_0^a g(x)\,\mathrm{d}x$ [m²], needed for the normal force;
- `max_radius`: the largest possible contact radius [m] (`inf` except for the flat punch).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
from jax.scipy.special import gammaln
from jaxtyping import Array, ArrayLike, Float

from ._solvers import as_float
from ._validate import check_positive

__all__ = [
    "AbstractProfile",
    "Parabola",
    "Cone",
    "PowerLaw",
    "FlatPunch",
    "power_law_factor",
]


def power_law_factor(n: ArrayLike) -> Array:
    r"""The MDR stretch factor $\kappa(n) = \sqrt\pi\,\Gamma(n/2+1)/\Gamma(n/2+1/2)$.

    For $f(r) = c r^n$ the MDR profile is $g(x) = \kappa(n)\,c\,|x|^n$. $\kappa(2) = 2$
    (parabola), $\kappa(1) = \pi/2$ (cone).
    """
    n = jnp.asarray(n)
    return jnp.sqrt(jnp.pi) * jnp.exp(gammaln(n / 2 + 1) - gammaln(n / 2 + 0.5))


class AbstractProfile(eqx.Module):
    """Base class of all axisymmetric profiles. See the module docstring for the interface."""

    def shape(self, r: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """The 3D gap $f(r)$ [m] at radius `r` [m]."""
        raise NotImplementedError

    def g(self, x: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """The MDR plane profile $g(x)$ [m] at `x` [m]; even in `x`."""
        raise NotImplementedError

    def dg(self, x: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """The slope $g'(x)$ [1] for $x \\ge 0$."""
        raise NotImplementedError

    def integral_g(self, a: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        r"""$\int_0^a g(x)\,\mathrm{d}x$ [m²] for contact radius `a` [m]."""
        raise NotImplementedError

    @property
    def max_radius(self) -> Array:
        """Largest contact radius [m] the profile admits (`inf` unless bounded)."""
        return jnp.asarray(jnp.inf)


class PowerLaw(AbstractProfile):
    r"""Power-law profile $f(r) = c\,r^n$.

    **Arguments:**

    - `c`: prefactor [m^(1-n)], > 0.
    - `n`: exponent [1], > 0 (n = 2: paraboloid, n = 1: cone).

    MDR profile: $g(x) = \kappa(n)\,c\,|x|^n$ with `power_law_factor`.
    """

    c: Float[ArrayLike, ""]
    n: Float[ArrayLike, ""]

    def __check_init__(self):
        check_positive("c", self.c, "m^(1-n)")
        check_positive("n", self.n, "1")

    def shape(self, r):
        return self.c * jnp.abs(jnp.asarray(r)) ** self.n

    def _gc(self):
        return power_law_factor(self.n) * self.c

    def g(self, x):
        return self._gc() * jnp.abs(jnp.asarray(x)) ** self.n

    def dg(self, x):
        x = jnp.abs(jnp.asarray(x))
        return self.n * self._gc() * x ** (self.n - 1)

    def integral_g(self, a):
        return self._gc() * jnp.asarray(a) ** (self.n + 1) / (self.n + 1)



class Parabola(AbstractProfile):
    r"""Paraboloid $f(r) = r^2/(2R)$ (sphere of radius $R$ in the small-slope limit).

    **Arguments:**

    - `R`: radius of curvature [m], > 0.

    MDR profile: $g(x) = x^2/R$, $\int_0^a g = a^3/(3R)$.
    """

    R: Float[ArrayLike, ""]

    def __check_init__(self):
        check_positive("R", self.R, "m")

    def shape(self, r):
        return jnp.asarray(r) ** 2 / (2 * self.R)

    def g(self, x):
        return jnp.asarray(x) ** 2 / self.R

    def dg(self, x):
        return 2 * jnp.abs(jnp.asarray(x)) / self.R

    def integral_g(self, a):
        return jnp.asarray(a) ** 3 / (3 * self.R)



class Cone(AbstractProfile):
    r"""Cone with half-opening angle $\alpha$ (between the axis and the flank).

    $f(r) = r\cot\alpha$, so the flank inclination is $\theta = \pi/2 - \alpha$ and
    $g(x) = \frac{\pi}{2}\,|x|\cot\alpha$.

    **Arguments:**

    - `half_angle`: $\alpha$ [rad], in (0, π/2).
    """

    half_angle: Float[ArrayLike, ""]

    def __check_init__(self):
        check_positive("half_angle", self.half_angle, "rad", upper=math.pi / 2)

    def _slope(self):
        return 1.0 / jnp.tan(self.half_angle)

    def shape(self, r):
        return jnp.abs(jnp.asarray(r)) * self._slope()

    def g(self, x):
        return 0.5 * jnp.pi * jnp.abs(jnp.asarray(x)) * self._slope()

    def dg(self, x):
        return jnp.zeros_like(as_float(x)) + 0.5 * jnp.pi * self._slope()

    def integral_g(self, a):
        return 0.25 * jnp.pi * self._slope() * jnp.asarray(a) ** 2



class FlatPunch(AbstractProfile):
    r"""Flat-ended cylindrical punch of radius $a_0$.

    $g(x) = 0$ for $|x| \le a_0$; the contact radius cannot exceed $a_0$
    (`max_radius`). Outside the punch $g$ is $+\infty$.

    **Arguments:**

    - `radius`: punch radius $a_0$ [m], > 0.
    """

    radius: Float[ArrayLike, ""]

    def __check_init__(self):
        check_positive("radius", self.radius, "m")

    def shape(self, r):
        r = jnp.abs(as_float(r))
        return jnp.where(r <= self.radius, 0.0, jnp.inf)

    def g(self, x):
        return self.shape(x)

    def dg(self, x):
        return jnp.zeros_like(as_float(x))

    def integral_g(self, a):
        return jnp.zeros_like(as_float(a))

    @property
    def max_radius(self):
        return jnp.asarray(self.radius)

