r"""Standard errors, correlations, identifiability and profile likelihoods.

At the optimum $\hat p$ the Jacobian of the weighted residuals with respect to the free
*natural* parameters is computed by forward-mode AD (`jax.jacfwd`). It is evaluated as
$J_\mathrm{rel} = \partial r/\partial\log p$ (well scaled: moduli in Pa and $\Delta\gamma$
in J/m² differ by many decades) and converted exactly:
$\mathrm{cov}(p) = s^2\,\mathrm{diag}(p)\,(J_\mathrm{rel}^\top J_\mathrm{rel})^{-1}\,
\mathrm{diag}(p) = s^2 (J^\top J)^{-1}$, with $s^2 = \chi^2/(m - n_\mathrm{free})$ the reduced
$\chi^2$ ($m$: force samples plus event residuals). Standard errors are the square roots of
the diagonal; the correlation matrix is the normalised covariance.

Identifiability: an :class:`IdentifiabilityWarning` names a parameter when its relative
standard error exceeds `max_relative_error` (default 0.5), or when $J_\mathrm{rel}^\top
J_\mathrm{rel}$ has a condition number above `max_condition` (default $10^{10}$), naming the
parameter that dominates the eigenvector of the smallest eigenvalue (the direction the
data cannot see). Typical case: $\eta_1$ when the lift is much slower than the relaxation
(the material is relaxed throughout and only $G_\infty$ matters).
"""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._objective import CurveBatch, ModelSpec, residuals

__all__ = ["IdentifiabilityWarning", "gauss_newton", "profile_likelihood"]


class IdentifiabilityWarning(UserWarning):
    """The data cannot determine a parameter (named in the message)."""


def _n_data(data: CurveBatch) -> int:
    return int(np.sum(np.asarray(data.valid) > 0) + data.n_curves
               + np.sum(np.asarray(data.has_jump)))


@eqx.filter_jit
def _jacobian(spec, free, theta, data):
    """Residuals and their Jacobian with respect to log p of the free entries."""
    idx = jnp.asarray(free)

    def r_of(log_free):
        r = residuals(theta.at[idx].set(log_free), data, spec)
        return r, r

    J, r = jax.jacfwd(r_of, has_aux=True)(theta[idx])
    return r, J


def gauss_newton(spec: ModelSpec, p, data: CurveBatch, free, names, *,
                 max_relative_error: float = 0.5, max_condition: float = 1e10,
                 warn: bool = True) -> dict:
    """Gauss–Newton covariance at natural parameters `p` for the `free` indices."""
    p = np.asarray(p, dtype=float)
    free = list(free)
    r, jac = _jacobian(spec, tuple(free), jnp.log(jnp.asarray(p)), data)
    r = np.asarray(r)
    J = np.asarray(jac)
    n_data = _n_data(data)
    dof = max(n_data - len(free), 1)
    chi2 = float(np.sum(r * r))
    s2 = chi2 / dof
    A = J.T @ J
    w, V = np.linalg.eigh(A)
    wmax = float(np.max(w)) if w.size else 0.0
    cond = wmax / float(np.min(w)) if w.size and np.min(w) > 0 else np.inf
    tiny = wmax * 1e-14
    inv = (V / np.where(w > tiny, w, np.inf)) @ V.T
    cov_rel = s2 * inv
    pf = p[free]
    cov_free = cov_rel * np.outer(pf, pf)
    k = len(p)
    cov = np.full((k, k), np.nan)
    cov[np.ix_(free, free)] = cov_free
    stderr = np.full(k, np.nan)
    stderr[free] = np.sqrt(np.maximum(np.diag(cov_free), 0.0))
    stderr[free] = np.where(np.diag(cov_rel) > 0, stderr[free], np.inf)
    corr = np.full((k, k), np.nan)
    d = np.sqrt(np.maximum(np.diag(cov_rel), 1e-300))
    corr[np.ix_(free, free)] = np.clip(cov_rel / np.outer(d, d), -1.0, 1.0)

    messages = []
    rel = stderr[free] / pf
    for i, j in enumerate(free):
        if not np.isfinite(rel[i]) or rel[i] > max_relative_error:
            messages.append(
                f"{names[j]} is not determined by the data: relative standard error "
                f"{rel[i]:.3g} (> {max_relative_error:g})"
            )
    if cond > max_condition and w.size:
        i = int(np.argmax(np.abs(V[:, 0])))
        name = names[free[i]]
        if not any(m.startswith(name + " ") for m in messages):
            messages.append(
                f"{name} is not determined by the data: the Gauss-Newton matrix has "
                f"condition number {cond:.3g} and its weakest direction is mostly {name}"
            )
    if warn:
        for m in messages:
            warnings.warn(m, IdentifiabilityWarning, stacklevel=3)
    return dict(stderr=stderr, covariance=cov, correlation=corr, reduced_chi2=s2,
                chi2=chi2, n_data=n_data, condition_number=cond, warnings=messages)


def profile_likelihood(result, name: str, values, *, max_steps: int = 200) -> dict:
    r"""Profile $\chi^2$ of one parameter: refit the others with it fixed at each value.

    All values are refitted in one vmapped call, each started from the optimum.

    **Returns:** `{"values": ..., "chi2": ..., "delta_chi2": ..., "others": (len, p)}` where
    $\Delta\chi^2 = \chi^2 - \chi^2_\min$ (about 1 at one standard error for a well-
    determined parameter, with the data weights scaled to reduced $\chi^2 = 1$, i.e.
    divide by `result.reduced_chi2`).
    """
    from ._optimise import _short, make_parameterisation, solve

    names = result.names
    n = _short(name, names)
    values = np.atleast_1d(np.asarray(values, dtype=float))
    ref = result.as_dict()
    fixed = {m: ref[m] for m, f in zip(names, result.fixed, strict=True) if f}

    def one(v):
        param = make_parameterisation(names, ref, {**fixed, n: float(v)}, None)
        z0 = jnp.asarray(param.z_of(np.asarray(param.reference)))[None]
        z, chi2, _, _ = solve(result.spec, param, result.data, z0, max_steps=max_steps)
        return float(chi2[0]), np.exp(np.asarray(param.theta(z[0])))

    out = [one(v) for v in values]
    chi2 = np.array([c for c, _ in out])
    return dict(values=values, chi2=chi2, delta_chi2=chi2 - result.chi2,
                others=np.stack([o for _, o in out]))
