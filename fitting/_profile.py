r"""Profile likelihoods: refit the other parameters with one held at each of several values.

All values run in one compiled, `vmap`-ed call (the held value enters as data, so one
compilation serves any values of the same count), each started from the optimum.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._objective import Parameterisation, canonical_name, residuals
from ._optimise import solve

__all__ = ["profile_likelihood"]


@eqx.filter_jit
def _profile_solve(spec, param, data, references, z0, max_steps):
    """One compiled solve for all profile values: `vmap` over the references.

    The profiled parameter is fixed, so it lives only in `param.reference`, an array
    (data, not a static field): the trace, and the compilation, serve every value.
    """
    def one(ref):
        z, chi2, ok, steps = solve(spec, eqx.tree_at(lambda q: q.reference, param, ref), data,
                                   z0[None], max_steps=max_steps)
        return z[0], chi2[0], ok[0], steps[0]

    return jax.vmap(one)(references)


@eqx.filter_jit
def _chi2_batch(spec, data, thetas):
    return jax.vmap(lambda th: jnp.sum(residuals(th, data, spec) ** 2))(thetas)


def profile_likelihood(result, name: str, values, *, max_steps: int = 200) -> dict:
    r"""Profile $\chi^2$ of one parameter: refit the others with it fixed at each value.

    All values are refitted in one compiled call (`vmap` over the values; the fixed value
    enters as data, so one compilation serves any values of the same count), each started
    from the optimum of `result`. Parameters fixed in `result` stay fixed, bounds of the
    fit are kept.

    **Arguments:** `result` (a :class:`fitting.FitResult`), `name` (a parameter, short
    ``"eta1"`` or with its unit ``"eta1_Pa_s"``), `values` (natural units, finite and > 0),
    `max_steps` (Levenberg–Marquardt steps per value).

    **Returns:** `{"values": (k,), "chi2": (k,), "delta_chi2": (k,), "others": (k, p),
    "converged": (k,)}` where $\Delta\chi^2 = \chi^2 - \chi^2_\min$ and `others` holds
    all parameters (natural units, the profiled one at its value). For a well-determined
    parameter $\Delta\chi^2/\chi^2_\mathrm{red} \approx (\delta/\sigma)^2$ near the
    optimum, with $\sigma$ the Gauss–Newton standard error (about 1 at one standard
    error; divide by `result.reduced_chi2` to scale the data weights to
    $\chi^2_\mathrm{red} = 1$).
    """
    names = list(result.names)
    try:
        j = names.index(canonical_name(name, names))
    except KeyError as exc:
        raise ValueError(f"name: {exc.args[0]}") from None
    values = np.atleast_1d(np.asarray(values, dtype=float))
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"values must be a non-empty 1-D array; got shape {values.shape}")
    if not np.all(np.isfinite(values) & (values > 0)):
        bad = values[~(np.isfinite(values) & (values > 0))][0]
        raise ValueError(f"values of {names[j]!r} must be finite and > 0; got {bad!r}")
    theta_hat = np.log(np.asarray(result.values, dtype=float))
    references = np.repeat(theta_hat[None], values.size, axis=0)
    references[:, j] = np.log(values)
    fit_param = result.parameterisation
    fit_free = tuple(fit_param.free) if fit_param is not None else tuple(
        i for i, f in enumerate(result.fixed) if not f)
    free = tuple(i for i in fit_free if i != j)
    if not free:
        chi2 = np.asarray(_chi2_batch(result.spec, result.data, jnp.asarray(references)))
        others = np.exp(references)
        converged = np.ones(values.size, dtype=bool)
    else:
        k = len(names)
        lower = (np.asarray(fit_param.lower) if fit_param is not None
                 else np.full(k, -np.inf))
        upper = (np.asarray(fit_param.upper) if fit_param is not None
                 else np.full(k, np.inf))
        param = Parameterisation(free=free, reference=jnp.asarray(theta_hat),
                                 lower=jnp.asarray(lower), upper=jnp.asarray(upper))
        # the free entries of every start are those of the optimum: z0 is common
        z0 = jnp.asarray(param.z_of(theta_hat))
        z, chi2, ok, _ = _profile_solve(result.spec, param, result.data,
                                        jnp.asarray(references), z0, int(max_steps))
        thetas = jax.vmap(lambda ref, zz: eqx.tree_at(lambda q: q.reference, param, ref)
                          .theta(zz))(jnp.asarray(references), z)
        others = np.exp(np.asarray(thetas))
        chi2 = np.asarray(chi2)
        converged = np.asarray(ok)
    return dict(values=values, chi2=chi2, delta_chi2=chi2 - result.chi2, others=others,
                converged=converged)
