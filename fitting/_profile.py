r"""Profile likelihoods: refit the other parameters with one held at each of several values.

All values run in one compiled, `vmap`-ed call (the held value enters as data, so one
compilation serves any values of the same count), each started from the optimum.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxcontact._validate import plain

from ._objective import residuals
from ._optimise import solve
from ._parameters import Parameterisation
from ._spec import canonical_name

__all__ = ["profile_likelihood"]


@eqx.filter_jit
def _profile_solve(spec, param, data, references, z0, max_steps):
    """One compiled solve for all profile values: `vmap` over the references.

    The profiled parameter is fixed, so it lives only in `param.reference`, an array
    (data, not a static field): the trace, and the compilation, serve every value.
    """
    def one(ref):
        sol = solve(spec, param.with_reference(ref), data, z0[None], max_steps=max_steps)
        return sol.z[0], sol.chi2[0], sol.converged[0], sol.steps[0]

    return jax.vmap(one)(references)


@eqx.filter_jit
def _chi2_batch(spec, param, data, us):
    return jax.vmap(lambda u: jnp.sum(residuals(param.to_natural(u), data, spec) ** 2))(us)


def profile_likelihood(result, name: str, values, *, max_steps: int = 200) -> dict:
    r"""Profile $\chi^2$ of one parameter: refit the others with it fixed at each value.

    All values are refitted in one compiled call, each started from the optimum of
    `result`. Parameters fixed in `result` stay fixed, bounds of the fit are kept.

    **Arguments:** `result` (a :class:`fitting.FitResult`), `name` (a parameter, short
    ``"eta1"`` or with its unit ``"eta1_Pa_s"``), `values` (natural units; finite, and > 0
    for the positive parameters), `max_steps` (Levenberg–Marquardt steps per value).

    **Returns:** `{"values": (k,), "chi2": (k,), "delta_chi2": (k,), "others": (k, p),
    "converged": (k,)}` where $\Delta\chi^2 = \chi^2 - \chi^2_\min$ and `others` holds
    all parameters (natural units, the profiled one at its value). For a well-determined
    parameter $\Delta\chi^2/\chi^2_\mathrm{red} \approx (\delta/\sigma)^2$ near the
    optimum, with $\sigma$ the Gauss–Newton standard error.
    """
    names = list(result.names)
    try:
        j = names.index(canonical_name(name, names))
    except KeyError as exc:
        raise ValueError(f"name: {exc.args[0]}") from None
    fit_param: Parameterisation = result.parameterisation
    values = np.atleast_1d(np.asarray(values, dtype=float))
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"values must be a non-empty 1-D array; got shape {values.shape}")
    ok = np.isfinite(values) & ((values > 0) | (not fit_param.log[j]))
    if not np.all(ok):
        need = "finite and > 0" if fit_param.log[j] else "finite"
        raise ValueError(f"values of {names[j]!r} must be {need}; got {plain(values[~ok][0])}")
    u_hat = fit_param.to_internal(result.values)
    references = np.repeat(u_hat[None], values.size, axis=0)
    references[:, j] = [fit_param.to_internal(_with(result.values, j, v))[j] for v in values]
    free = tuple(i for i in fit_param.free if i != j)
    if not free:
        chi2 = np.asarray(_chi2_batch(result.spec, fit_param, result.data,
                                      jnp.asarray(references)))
        others = np.stack([_with(result.values, j, v) for v in values])
        converged = np.ones(values.size, dtype=bool)
    else:
        param = Parameterisation(free=free, log=fit_param.log, reference=jnp.asarray(u_hat),
                                 scale=fit_param.scale, lower=fit_param.lower,
                                 upper=fit_param.upper)
        z0 = jnp.asarray(param.z_of(u_hat))
        z, chi2, ok, _ = _profile_solve(result.spec, param, result.data,
                                        jnp.asarray(references), z0, int(max_steps))
        nat = jax.vmap(lambda ref, zz: param.with_reference(ref).natural(zz))(
            jnp.asarray(references), z)
        others = np.asarray(nat)
        chi2 = np.asarray(chi2)
        converged = np.asarray(ok)
    return dict(values=values, chi2=chi2, delta_chi2=chi2 - result.chi2, others=others,
                converged=converged)


def _with(values, j, v):
    out = np.array(values, dtype=float)
    out[j] = v
    return out
