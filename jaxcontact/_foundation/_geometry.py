"""Profile operations in the interpolation coordinate, and the node positions."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from .._elastic import _power_law_params
from .._profiles import AbstractProfile, FlatPunch
from .._root import bracketed_root


class _Geometry:
    """Profile operations in the interpolation coordinate zeta (g, or x for the flat punch)."""

    def __init__(self, profile: AbstractProfile):
        self.profile = profile
        self.flat = isinstance(profile, FlatPunch)
        self.power = None if self.flat else _power_law_params(profile)

    def g(self, x):
        if self.flat:
            return jnp.zeros_like(x)
        return self.profile.g(x)

    def integral_g(self, x):
        if self.flat:
            return jnp.zeros_like(x)
        return self.profile.integral_g(x)

    def zeta(self, x):
        return x if self.flat else self.profile.g(x)

    def zeta_integral(self, x):
        return 0.5 * x**2 if self.flat else self.profile.integral_g(x)

    def zeta_inverse(self, y, lo, hi):
        """x in [lo, hi] with zeta(x) = y (zeta increasing)."""
        if self.flat:
            return y
        if self.power is not None:
            K, n = self.power
            return (jnp.maximum(y, 0.0) / K) ** (1.0 / n)
        return bracketed_root(lambda x: self.profile.g(x) - y, lo, hi, steps=48)

    def stationary(self, q, lo, hi):
        r"""Solution of $\sqrt{x}\,\zeta'(x) = q$ (maximiser of $-\beta\zeta + c\sqrt x$,
        $q = c/(2\beta)$), clipped to [lo, hi]; not differentiated."""
        q = lax.stop_gradient(q)
        lo = lax.stop_gradient(lo)
        hi = lax.stop_gradient(hi)
        if self.flat:
            x = q**2
        elif self.power is not None:
            K, n = lax.stop_gradient(self.power)
            x = (q / (n * K)) ** (1.0 / (n - 0.5))
        else:
            def h(x):
                return jnp.sqrt(x) * self.profile.dg(x) - q

            root = bracketed_root(h, lo, hi, steps=48)
            x = jnp.where(h(hi) <= 0, hi, jnp.where(h(lo) >= 0, lo, root))
        x = jnp.where(jnp.isfinite(x), x, hi)
        return jnp.clip(x, lo, hi)



def _grid_nodes(geo: _Geometry, cells: int, depth) -> Array:
    """Node positions x_j (cells + 1,), uniform in zeta = g (in x for the flat punch)."""
    frac = jnp.linspace(0.0, 1.0, cells + 1)
    if geo.flat:
        return jnp.asarray(geo.profile.radius, dtype=float) * frac
    depth = jnp.asarray(depth, dtype=float)
    if geo.power is not None:
        K, n = geo.power
        return (frac * depth / K) ** (1.0 / n)
    amax = jnp.asarray(geo.profile.max_radius, dtype=float)
    top = jnp.where(jnp.isfinite(amax), amax, 1.0)

    def one(y):
        return bracketed_root(lambda xx: geo.profile.g(xx) - y, 0.0 * top, top, steps=80)

    return jax.vmap(one)(frac * depth)
