r"""Standard errors, correlations, identifiability and profile likelihoods.

At the optimum $\hat p$ the Jacobian of the weighted residuals with respect to the free
*natural* parameters is computed by forward-mode AD (`fitting._objective.log_jacobian`).
It is evaluated as $J_\mathrm{rel} = \partial r/\partial\log p$ (well scaled: moduli in
Pa and $\Delta\gamma$ in J/m² differ by many decades) and converted exactly:
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

A free work of adhesion with no detaching curve is reported the same way, with an infinite
standard error (:func:`detachment_message`): the data then bound $\Delta\gamma$ only from
below, and the optimum sits on or above that bound, where the local standard error (often
small) means nothing.
"""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np

from ._objective import CurveBatch, ModelSpec, log_jacobian

__all__ = ["IdentifiabilityWarning", "detachment_message", "gauss_newton"]


class IdentifiabilityWarning(UserWarning):
    """The data cannot determine a parameter (named in the message)."""


def _n_data(data: CurveBatch) -> int:
    return int(np.sum(np.asarray(data.valid) > 0) + data.n_curves
               + np.sum(np.asarray(data.has_jump)))


def detachment_message(data: CurveBatch, names, free) -> str | None:
    """The identifiability message when the work of adhesion is free but no curve detaches.

    Without a jump-off in the data the work of adhesion is bounded only from below (the
    contact held at least until the end of the lift): the least-squares optimum sits on or
    above that bound, and the local (Gauss–Newton) standard error means nothing. `None`
    when the work of adhesion is fixed or some curve detaches.
    """
    names = list(names)
    if "work_of_adhesion" not in names or names.index("work_of_adhesion") not in free:
        return None
    if np.any(np.asarray(data.has_jump) > 0):
        return None
    return ("work_of_adhesion is not determined by the data: no curve detaches (the force "
            "never jumps back to zero after its most tensile value), so the data bound it "
            "only from below; lift until the contact jumps off, or fix it "
            "(fixed={'work_of_adhesion': value})")


def gauss_newton(spec: ModelSpec, p, data: CurveBatch, free, names, *,
                 max_relative_error: float = 0.5, max_condition: float = 1e10,
                 warn: bool = True, jacobian=None) -> dict:
    """Gauss–Newton covariance at natural parameters `p` for the `free` indices.

    `jacobian`: optionally `(r, J)`, the residuals at `p` and their Jacobian with respect
    to the log of the free parameters (e.g. from the optimiser's last step); computed
    here (forward mode) when `None`.
    """
    p = np.asarray(p, dtype=float)
    free = list(free)
    if jacobian is None:
        r, jac = log_jacobian(spec, tuple(free), jnp.log(jnp.asarray(p)), data)
    else:
        r, jac = jacobian
        if np.shape(jac) != (np.size(r), len(free)):
            raise ValueError(f"jacobian: J must have shape ({np.size(r)}, {len(free)}); "
                             f"got {np.shape(jac)}")
    r = np.asarray(r)
    J = np.array(jac)
    # a derivative that is not finite (the model fails next to the optimum) carries no
    # information: that parameter is reported as undetermined, the others stay usable
    bad = ~np.all(np.isfinite(J), axis=0)
    J[:, bad] = 0.0
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
    var_rel = np.diag(cov_rel)
    # relative standard errors (of log p); 0 variance: a direction the data cannot see
    rel = np.where(var_rel > 0, np.sqrt(np.maximum(var_rel, 0.0)), np.inf)
    k = len(p)
    cov = np.full((k, k), np.nan)
    stderr = np.full(k, np.nan)
    with np.errstate(over="ignore", invalid="ignore"):  # a runaway parameter gives inf
        cov[np.ix_(free, free)] = cov_rel * np.outer(pf, pf)
        stderr[free] = pf * rel
    corr = np.full((k, k), np.nan)
    d = np.sqrt(np.maximum(var_rel, 1e-300))
    corr[np.ix_(free, free)] = np.clip(cov_rel / np.outer(d, d), -1.0, 1.0)

    messages = []
    no_jump = detachment_message(data, names, free)
    if no_jump is not None:
        # a lower bound only: no standard error
        j = names.index("work_of_adhesion")
        stderr[j] = np.inf
        cov[j, :] = cov[:, j] = np.nan
        messages.append(no_jump)
    for i, j in enumerate(free):
        if no_jump is not None and names[j] == "work_of_adhesion":
            continue
        if bad[i]:
            messages.append(f"{names[j]} is not determined by the data: the derivative of the "
                            "residuals with respect to it is not finite at the optimum")
        elif not np.isfinite(rel[i]) or rel[i] > max_relative_error:
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
