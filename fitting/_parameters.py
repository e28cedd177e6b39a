r"""The map between the optimiser's free vector $z$ and the natural parameters $p$.

Every parameter has an *internal coordinate* $u$: $u = \log p$ for the positive ones
(moduli, viscosities, times, $\Delta\gamma$; decades apart, so logs make the problem well
scaled and keep them positive) and $u = p/s$ for the offsets (any sign; $s$ a data scale:
the indentation range for the contact offset, the force range for the force offset).

Free, unbounded: $u_i = u^\mathrm{ref}_i + z_i$. Free and bounded in $[l_i, h_i]$ (internal
coordinates): $u_i = l_i + (h_i - l_i)\,\sigma(z_i)$ with the logistic $\sigma$, so no
step can leave the bounds. Fixed: $u_i = u^\mathrm{ref}_i$.

A bounded parameter whose logistic is saturated (within $10^{-4}$ of the span from a
bound, :meth:`Parameterisation.at_bound`) is reported *at its bound*: the data push it
there, and no standard error is given for it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from scipy import special

from jaxcontact._validate import plain

from ._host import rebuild
from ._spec import normalise_names

__all__ = ["Parameterisation", "make_parameterisation", "AT_BOUND"]

#: Fraction of the bounded span within which a parameter is reported at its bound.
AT_BOUND = 1e-4


class _host_method:
    """A method of the host path (numpy, called per start and per curve): accessed on an
    instance it is a plain `functools.partial`, not the equinox bound method (a module
    built at every access, which dominated the per-curve host work of a force map). Not
    for functions passed to JAX transformations."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __get__(self, obj, owner=None):
        return self.fn if obj is None else functools.partial(self.fn, obj)


def free_to_internal(xp, z, lo, hi, ref):
    r"""The free coordinates `z` to internal coordinates (`xp`: `jax.numpy`, traceable, or
    `numpy` on the host), with the free parameters' internal bounds `lo`, `hi` (±inf:
    unbounded) and reference `ref` (broadcast against `z`): the logistic
    $u = l + (h - l)\,\sigma(z)$ when bounded, $u = u_\mathrm{ref} + z$ otherwise.
    Returns `(bounded, lo_s, hi_s, sigma, u)`."""
    bounded = xp.isfinite(lo) & xp.isfinite(hi)
    lo_s = xp.where(bounded, lo, 0.0)
    hi_s = xp.where(bounded, hi, 1.0)
    sig = jax.nn.sigmoid(z) if xp is jnp else special.expit(z)  # the logistic
    return bounded, lo_s, hi_s, sig, xp.where(bounded, lo_s + (hi_s - lo_s) * sig, ref + z)


def internal_to_free(th, lo, hi, ref) -> np.ndarray:
    """The inverse of :func:`free_to_internal` in numpy: free coordinates of the free
    parameters' internal coordinates `th` (clipped strictly inside the bounds)."""
    bounded = np.isfinite(lo) & np.isfinite(hi)
    if not bounded.any():
        return th - ref
    # (per curve of a map, so the numpy calls are few: every parameter bounded needs no
    # selection, and np.clip's numbers come from two ufunc calls)
    every = bounded.all()
    span = hi - lo if every else np.where(bounded, hi - lo, 1.0)
    s = np.minimum(np.maximum((th - (lo if every else np.where(bounded, lo, 0.0))) / span,
                              1e-9), 1 - 1e-9)
    out = np.log(s) - np.log1p(-s)
    return out if every else np.where(bounded, out, th - ref)


class Parameterisation(eqx.Module):
    """Free vector ↔ internal coordinates ↔ natural parameters (see the module docstring).

    **Fields:** `free` (indices of the free parameters), `log` (per parameter: internal
    coordinate is $\\log p$, else $p/s$), `reference` (internal coordinates of the
    reference point: fixed values and the origin of unbounded free ones), `scale` ($s$ of
    the linear parameters, 1 for log ones), `lower`, `upper` (internal bounds, ±inf when
    unbounded).
    """

    free: tuple[int, ...] = eqx.field(static=True)
    log: tuple[bool, ...] = eqx.field(static=True)
    reference: Float[Array, " p"]
    scale: Float[Array, " p"]
    lower: Float[Array, " p"]
    upper: Float[Array, " p"]

    def _internal(self, xp, z):
        # (called as `Parameterisation._internal(self, ...)`: an equinox bound method is a
        # module built at every access, on the host path of every curve)
        # one transform for jax.numpy (traced, differentiable) and numpy (host: no
        # dispatch of eager device operations, per start and per curve)
        idx = xp.asarray(list(self.free))
        return free_to_internal(xp, z, xp.asarray(self.lower)[idx],
                                xp.asarray(self.upper)[idx], xp.asarray(self.reference)[idx])

    def internal(self, z: Float[Array, " k"]) -> Float[Array, " p"]:
        """Internal coordinates $u$ of all parameters at the free vector `z` (traceable)."""
        val = Parameterisation._internal(self, jnp, z)[-1]
        return jnp.asarray(self.reference).at[jnp.asarray(self.free, dtype=int)].set(val)

    @_host_method
    def internal_host(self, z) -> np.ndarray:
        """:meth:`internal` in numpy on the host (`z`: shape `(k,)` or `(..., k)`)."""
        z = np.asarray(z, dtype=float)
        val = Parameterisation._internal(self, np, z)[-1]
        out = np.broadcast_to(np.asarray(self.reference), z.shape[:-1] + (len(self.log),))
        out = out.copy()
        out[..., list(self.free)] = val
        return out

    @_host_method
    def dinternal_dz(self, z) -> np.ndarray:
        r"""$\mathrm du_i/\mathrm dz_i$ of the free parameters at `z` (numpy, shape of
        `z`): $(h - l)\,\sigma(z)(1 - \sigma(z))$ when bounded, 1 otherwise."""
        bounded, lo, hi, sig, _ = Parameterisation._internal(self, np, np.asarray(z, dtype=float))
        return np.where(bounded, (hi - lo) * sig * (1.0 - sig), 1.0)

    def to_natural(self, u: Float[Array, " p"]) -> Float[Array, " p"]:
        """Natural parameters of internal coordinates `u`."""
        is_log = jnp.asarray(self.log)
        return jnp.where(is_log, jnp.exp(jnp.where(is_log, u, 0.0)), u * self.scale)

    @_host_method
    def to_natural_host(self, u) -> np.ndarray:
        """:meth:`to_natural` in numpy on the host."""
        u = np.asarray(u, dtype=float)
        is_log = np.asarray(self.log)
        return np.where(is_log, np.exp(np.where(is_log, u, 0.0)), u * np.asarray(self.scale))

    def natural(self, z: Float[Array, " k"]) -> Float[Array, " p"]:
        """Natural parameters at the free vector `z`."""
        return self.to_natural(self.internal(z))

    @_host_method
    def to_internal(self, p) -> np.ndarray:
        """Internal coordinates of natural parameters `p` (numpy)."""
        p = np.asarray(p, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            if all(self.log):  # (the selection's numbers, in one call: per curve of a map)
                return np.log(p)
            is_log = np.asarray(self.log)
            return np.where(is_log, np.log(np.where(is_log, p, 1.0)),
                            p / np.asarray(self.scale))

    @_host_method
    def dnatural(self, u) -> np.ndarray:
        """$\\mathrm dp/\\mathrm du$ per parameter ($p$ for log ones, $s$ for linear)."""
        u = np.asarray(u, dtype=float)
        return np.where(np.asarray(self.log), np.exp(np.where(self.log, u, 0.0)),
                        np.asarray(self.scale))

    @_host_method
    def z_of(self, u) -> np.ndarray:
        """Free vector of internal coordinates `u` (clipped strictly inside the bounds;
        `u`: shape `(p,)` or `(..., p)`)."""
        u = np.asarray(u, dtype=float)
        lo, hi, ref = (np.asarray(self.lower), np.asarray(self.upper),
                       np.asarray(self.reference))
        if self.free == tuple(range(len(lo))):  # every one free: no selection (no copies)
            return internal_to_free(u, lo, hi, ref)
        idx = list(self.free)
        return internal_to_free(u[..., idx], lo[idx], hi[idx], ref[idx])

    @_host_method
    def at_bound(self, u) -> list[str | None]:
        """Per parameter: "lower", "upper" (saturated at that bound) or None."""
        u = np.asarray(u, dtype=float)
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        out: list[str | None] = [None] * len(u)
        for i in self.free:
            if math.isfinite(lo[i]) and math.isfinite(hi[i]):
                s = (u[i] - lo[i]) / (hi[i] - lo[i])
                out[i] = "lower" if s < AT_BOUND else ("upper" if s > 1 - AT_BOUND else None)
        return out

    def with_reference(self, u) -> Parameterisation:
        """The same parameterisation around other internal reference coordinates."""
        return eqx.tree_at(lambda q: q.reference, self, jnp.asarray(u, dtype=float))


def make_parameterisation(
    info: Sequence[tuple[str, str, str]],
    reference: Mapping[str, float],
    *,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    scales: Mapping[str, float] | None = None,
    host: bool = False,
) -> Parameterisation:
    """Parameterisation for the parameters `info` (:func:`fitting._spec.parameter_info`).

    `reference`: natural values (the reference point; a fixed parameter's value comes
    from `fixed`). `bounds`: `{name: (lower, upper)}` natural (positive for the log
    parameters). `scales`: $s$ of the linear parameters (default 1). `host`: keep the
    arrays in numpy (for parameterisations stacked later, e.g. a chunk of
    :func:`fitting.fit_each`: one transfer to the device per chunk, not one per curve).
    """
    names = [n for n, _, _ in info]
    is_log = tuple(not kind.startswith("offset") for _, _, kind in info)
    fixed = normalise_names(fixed, names, "fixed")
    bounds = normalise_names(bounds, names, "bounds")
    scales = dict(scales or {})
    # the per-parameter work in Python floats, one array each at the end (per curve of a
    # map: the overhead of numpy calls on single entries counts)
    ref_f = [float(fixed.get(n, reference[n])) for n in names]
    scale_f = [1.0 if lg else float(scales.get(n, 1.0))
               for n, lg in zip(names, is_log, strict=True)]
    for n, v, lg in zip(names, ref_f, is_log, strict=True):
        if not math.isfinite(v) or (lg and v <= 0):
            what = "fixed" if n in fixed else "initial"
            rng = "(0, inf)" if lg else "(-inf, inf)"
            raise ValueError(f"{what} value of {n!r} must be finite and in {rng}; got {plain(v)}")
    lo_f = [-math.inf] * len(names)
    hi_f = [math.inf] * len(names)
    for n, pair in bounds.items():
        i = names.index(n)
        try:
            a, b = (float(x) for x in pair)
        except (TypeError, ValueError):
            raise ValueError(f"bounds for {n!r} must be a pair (lower, upper); got "
                             f"{plain(pair)}") from None
        ok = math.isfinite(a) and math.isfinite(b) and a < b and (a > 0 or not is_log[i])
        if not ok:
            need = "0 < lower < upper" if is_log[i] else "finite lower < upper"
            raise ValueError(f"bounds for {n!r} must satisfy {need}; got {plain((a, b))}")
        lo_f[i], hi_f[i] = ((math.log(a), math.log(b)) if is_log[i]
                            else (a / scale_f[i], b / scale_f[i]))
    ref, scale, lo, hi = np.array(ref_f), np.array(scale_f), np.array(lo_f), np.array(hi_f)
    free = tuple(i for i, n in enumerate(names) if n not in fixed)
    if not free:
        raise ValueError("fixed: every parameter is fixed; nothing to fit")
    u = np.where(is_log, np.log(np.where(is_log, ref, 1.0)), ref / scale)
    # a reference outside its bounds starts at the nearest bound (inside, by the clip of
    # z_of); np.clip's numbers in two ufunc calls
    u = np.minimum(np.maximum(u, lo), hi)
    reference, sc, lower, upper = (u, scale, lo, hi) if host else \
        jax.device_put((u, scale, lo, hi))
    # built without equinox's `__init__` (per curve of a map; `fitting._host`)
    return rebuild(lambda v: Parameterisation(free=free, log=is_log, **v),
                   {"reference": reference, "scale": sc, "lower": lower, "upper": upper},
                   key=("Parameterisation", free, is_log))
