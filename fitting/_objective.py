r"""The fitting objective: every selected sample is a weighted force residual.

Forward models (:func:`predict`)
--------------------------------
* ``model="relaxed"``: :func:`jaxcontact.retract` driven by the measured indentation
  (relaxed depth $d_0 + \delta$, input $\min(d, d_0) + \delta$).
* ``model="history"``: :func:`jaxcontact.simulate` on the foundation grid, driven by the
  measured indentation $d + \delta$ (displacement control: the tip position is measured,
  so it *is* the imposed indentation; a force-controlled hold is followed through its
  measured creep), or under :class:`jaxcontact.CompliantLoading` by the base position
  $z = d + F/k + \delta$.

Residuals (:func:`residuals`)
-----------------------------
$r_i = \sqrt{w_i}\,(F^\mathrm{eff}_i + F_0 - F_i)/\sigma_i$ ($\sigma_i$: the noise of the
sample, $w_i$: the number of measured samples it stands for; :class:`fitting.CurveBatch`)
for every sample $i$ of every curve, before
*and after* the model's jump-off: after it the model force is 0 and the residual is the
measured force, so a model that detaches early pays for every adhesive sample it drops
(nothing is discarded; a model cannot improve its loss by detaching earlier than the
data).

The model force jumps to 0 at the jump-off time $t^*(\theta)$, which the forward models
refine between samples. A plain $F_\mathrm{model}(t_i)$ would make each residual a step
function of the parameters where $t^*$ crosses $t_i$. Instead each sample stands for its
interval $[l_i, u_i]$ (halfway to its neighbours, the first and last ending at the first and
last sample, where the simulation starts and ends; :class:`fitting.CurveBatch`) and, for the
one sample whose interval contains $t^*$, the model force is the average over the
interval of the attached force followed by 0:

$$F^\mathrm{eff}_i = \frac{t^* - l_i}{u_i - l_i}\,F^\mathrm{att}_i,\qquad
F^\mathrm{att}_i = \begin{cases}F(t_i) & t_i < t^*\\ F(t^*) & t_i \ge t^*\end{cases}$$

(a measured sample is itself a short average: the instrument's low-pass filter). Every
other sample uses $F(t_i)$. The residuals are then continuous, piecewise smooth functions
of the parameters; their derivative with respect to $t^*$ carries the information where
the jump is. The same holds under compliant loading, where the tip jumps to the free
branch at $t^*$.

Non-finite model output (which the forward models report in ``.result``) becomes a large
finite residual ($10^6$), so the optimiser steps back.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxcontact as jc
from jaxcontact import _sharding
from jaxcontact._solvers import float64_scope

from ._prepare import CurveBatch
from ._spec import (
    ModelSpec,
    build_rheology,
    force_baseline,
    n_model_inputs,
    offsets,
    stress_scaled,
    work_of_adhesion,
)

__all__ = ["predict", "effective_force", "residuals", "residuals_and_model", "ModelAt",
           "jacobian_fn", "internal_jacobian", "residuals_jacobian", "residuals_of_free",
           "model_solution_at"]


def _predict_one(spec: ModelSpec, p, profile, ts, drive, depth, stiffness):
    rheology = build_rheology(spec, p)
    dgamma = work_of_adhesion(spec, p)
    delta, _ = offsets(spec, p)
    # the optimiser may try parameters outside the forward model's unit plausibility ranges
    # (e.g. a modulus below 1e-3 Pa for a soft gel): those are bounds of the fit
    # (`default_bounds`), not unit mistakes, so the traced model does not check them (the
    # data and the probe are checked eagerly by `prepare_curves`)
    with jc.plausibility_checks(False):
        if spec.model == "relaxed":
            return jc.retract(rheology, profile, work_of_adhesion=dgamma,
                              depth=depth + delta, ts=ts, displacement=drive + delta,
                              throw=False)
        loading = (jc.CompliantLoading(stiffness) if spec.compliant
                   else jc.DisplacementControl())
        return jc.simulate(rheology, profile, dgamma, ts, drive + delta, loading=loading,
                           grid=jc.FoundationGrid(cells=spec.cells), throw=False)


def predict(spec: ModelSpec, p: Float[Array, " p"], data: CurveBatch) -> jc.ContactSolution:
    """Forward model for every curve at natural parameters `p` (batched `ContactSolution`,
    leading axis = curve; the force without the force offset).

    One curve (every problem of a search) is not vmapped: the same operations with a
    leading axis of 1 added to the outputs, and one batching pass less over the model's
    trace (the history model's search program traces ~2.5 s faster)."""

    def one(ts, drive, depth, k):
        return _predict_one(spec, p, data.profile, ts, drive, depth, k)

    if data.ts.shape[0] == 1:
        sol = one(data.ts[0], data.drive[0], data.depth[0], data.stiffness[0])
        return jax.tree.map(lambda x: jnp.expand_dims(x, 0), sol)
    return jax.vmap(one)(data.ts, data.drive, data.depth, data.stiffness)


def effective_force(sol: jc.ContactSolution, data: CurveBatch) -> Float[Array, "C n"]:
    """$F^\\mathrm{eff}$ of the module docstring: the model force per sample [N], with the
    jump-off resolved inside the sample interval that contains it (no force offset)."""
    t_jump = jnp.where(jnp.isfinite(sol.jumpoff_time), sol.jumpoff_time, jnp.inf)[:, None]
    f_jump = jnp.where(jnp.isfinite(sol.jumpoff_force), sol.jumpoff_force, 0.0)[:, None]
    force = jnp.where(jnp.isfinite(sol.force), sol.force, 0.0)
    width = jnp.maximum(data.upper - data.lower, jnp.finfo(data.ts.dtype).tiny)
    inside = (data.lower <= t_jump) & (t_jump < data.upper)
    frac = jnp.clip((jnp.where(inside, t_jump, data.lower) - data.lower) / width, 0.0, 1.0)
    attached = jnp.where(data.ts < t_jump, force, f_jump)
    return jnp.where(inside, frac * attached, force)


def residuals(p: Float[Array, " p"], data: CurveBatch, spec: ModelSpec) -> Float[Array, " m"]:
    """Weighted force residuals at natural parameters `p`, curve-major, length `C*n`
    (padding samples give 0). Pure and jittable."""
    return residuals_and_model(p, data, spec)[0]


def residuals_and_model(p: Float[Array, " p"], data: CurveBatch, spec: ModelSpec):
    r""":func:`residuals` and, from the same evaluation, what a fit reports of the model
    (:class:`ModelAt`): the model force at the sample times and the force as fitted
    ($F^\mathrm{eff}$), both with the fitted baseline [N] (the force offset and drift,
    :func:`fitting._spec.force_baseline`), and the contact radius [m], each of shape
    `(C, n)` like ``data.force``."""
    return _evaluate(p, data, spec)[:2]


def _evaluate(p, data: CurveBatch, spec: ModelSpec):
    """At natural parameters `p`: the residuals (flat; a non-finite one is $10^6$), the
    :class:`ModelAt`, the finite residuals' mask and the effective force
    (:func:`effective_force`, without the baseline)."""
    sol = predict(spec, p, data)
    force = effective_force(sol, data)
    f0 = force_baseline(spec, p, data.ts)
    fitted = force + f0
    r = (jnp.sqrt(data.weight) * (fitted - data.force) / data.noise).ravel()
    point = jnp.where(jnp.isfinite(sol.force), sol.force, 0.0) + f0
    ok = jnp.isfinite(r)
    return jnp.where(ok, r, 1e6), ModelAt(point, fitted, sol.contact_radius), ok, force


class ModelAt(NamedTuple):
    """The model at a fit's parameters, as the finish of a fit reports it (shapes `(C, n)`
    of ``data.force``): `force` (at the sample times, with the force offset [N]), `fitted`
    (the force as fitted, :func:`effective_force` with the offset [N]), `contact_radius`
    [m]."""

    force: Array
    fitted: Array
    contact_radius: Array


def jacobian_fn(fn, *, has_aux: bool = False):
    """`z -> (r, J)`: `fn(z)` and its Jacobian by forward mode (the project's one helper);
    with `has_aux`, `fn(z)` returns `(r, aux)` and the result is `(r, J, aux)` (`aux` from
    the same evaluation, not differentiated).

    `jax.jacfwd` pushes every free direction through the model at once (a vmapped JVP);
    the residuals come back as the auxiliary output of the same pass. On both models it
    compiles and runs faster than `jax.linearize` followed by a vmap of the linear map.
    Reverse mode is not used: through the forward models' jump-off refinement it gives NaN.
    """

    def fn_jac(z):
        def both(z):
            out = fn(z)
            return (out[0] if has_aux else out), out

        J, out = jax.jacfwd(both, has_aux=True)(z)
        return (out[0], J, out[1]) if has_aux else (out, J)

    return fn_jac


@eqx.filter_jit
def internal_jacobian(spec: ModelSpec, param, u, data: CurveBatch):
    """Residuals at internal coordinates `u` and their Jacobian with respect to the internal
    coordinates of the free parameters (`param`: a `Parameterisation`)."""
    idx = jnp.asarray(param.free)

    def fn(uf):
        return residuals(param.to_natural(u.at[idx].set(uf)), data, spec)

    return jacobian_fn(fn)(u[idx])


def residuals_jacobian(spec: ModelSpec):
    r"""`(z, ctx, with_model) -> (r, J, model)`: the residuals at the free vector `z`
    (`ctx = (param, data)`), their Jacobian with respect to `z` and, with `with_model`, the
    :class:`ModelAt` of the same evaluation (else `None`), as :func:`jacobian_fn` gives them,
    with fewer directions pushed through the forward model:

    - the model force is homogeneous of degree one in the parameters that carry the stress
      scale ($H$, :func:`fitting._spec.stress_scaled`): in their internal coordinates
      $u_i = \log p_i$, $\sum_{i\in H} \partial F/\partial u_i = F$ (Euler). When every
      parameter of $H$ is free, the column of the first of them is $F$ minus the others'
      (weighted like the residuals), so one direction fewer goes through the model (of the
      standard model's five with the contact point: a step of the full-history search ~15 %
      cheaper; ``benchmarks/results/fit_each.md``, "One direction fewer");
    - the force offset and drift are not inputs of the model: their columns come from the
      baseline $F_0 + s\,t$ alone.

    The derived column agrees with the model's own to round-off relative to $F$ (tested
    against :func:`jacobian_fn` on both models); rows of non-finite residuals are 0, as the
    derivative of their replacement $10^6$ is.
    """
    scaled = stress_scaled(spec)
    n_model = n_model_inputs(spec)

    def jac(z, ctx, with_model: bool = False):
        param, data = ctx
        free = list(param.free)
        k = len(free)
        # the derived column: the first parameter of H, when all of H is free (in logs)
        derived = scaled[0] if scaled and all(i in free and param.log[i] for i in scaled) \
            else None
        push = [i for i in free if i < n_model and i != derived]
        base = [i for i in free if i >= n_model]
        weight = jnp.sqrt(data.weight) / data.noise

        u, du = jax.jvp(param.internal, (z,), (jnp.ones_like(z),))  # u_i depends on z_i only

        def evaluate(uu):
            r, model, ok, force = _evaluate(param.to_natural(uu), data, spec)
            return r, (model, ok, jnp.where(ok, (weight * force).ravel(), 0.0))

        def with_pushed(up):
            # u with the pushed parameters from `up` (contiguous runs, static slices)
            parts, start = [], 0
            for a, i in enumerate(push):
                if i > start:
                    parts.append(u[start:i])
                parts.append(up[a:a + 1])
                start = i + 1
            if start < u.shape[0]:
                parts.append(u[start:])
            return jnp.concatenate(parts)

        # the pushed directions in internal coordinates (a saturated logistic, du/dz = 0,
        # loses no derivative of the model there: the identity needs them all)
        if push:
            def along(t):  # (rows of the transposed Jacobian: contiguous, no layout change)
                return jax.jvp(lambda x: evaluate(with_pushed(x)), (up,), (t,), has_aux=True)

            up = jnp.stack([u[i] for i in push])
            with _sharding.forward_only():  # no reverse mode through this trace
                r, Gt, (model, ok, weighted) = jax.vmap(along, out_axes=(None, 0, None))(
                    jnp.eye(len(push), dtype=up.dtype))
        else:  # (no free parameter of the model: the offsets' columns alone)
            r, (model, ok, weighted) = evaluate(u)
            Gt = jnp.zeros((0, r.shape[0]), r.dtype)
        # the model's columns, J^T = diag(du/dz) A X, X = [the pushed rows; the weighted
        # model force] (a product with the lane's own matrix, not a sum of rows: XLA would
        # fuse the rows' last operations into the sum once per use, or lay X out across
        # the lanes for a constant one)
        A = np.zeros((k, len(push) + 1))
        for a, i in enumerate(push):
            A[free.index(i), a] = 1.0
        if derived is not None:  # sum over H of dF/du_i = F
            A[free.index(derived), -1] = 1.0
            for i in scaled:
                if i != derived:
                    A[free.index(derived), push.index(i)] = -1.0
        du_free = du[np.asarray(free)]
        J = ((du_free[:, None] * jnp.asarray(A, r.dtype))
             @ jnp.concatenate([Gt, weighted[None]], axis=0)).T
        if base:
            def baseline(ub):
                f0 = force_baseline(spec, param.to_natural(ub), data.ts)
                return jnp.where(ok, (weight * jnp.broadcast_to(f0, data.force.shape)).ravel(),
                                 0.0)

            mask = np.array([i in base for i in free])
            B = jax.jacfwd(baseline)(u)[:, np.asarray(free)]  # (cheap: no model)
            J = J + B * (mask * du_free)[None, :]
        return r, J, (model if with_model else None)

    return jac


def residuals_of_free(spec: ModelSpec, param, data: CurveBatch):
    """`z -> r`: the residuals at the free vector `z` of `param` (`param`, `data` fixed),
    differentiable in forward mode through :func:`residuals_jacobian` (a `jax.custom_jvp`):
    a JVP, or a `jax.jacfwd` over any number of directions that all enter through `z` (the
    posterior's whitened coordinates and noise scales, :mod:`fitting._posterior`), costs
    the one Jacobian, its directions fewer than the free parameters, instead of a pass
    through the model per direction. Reverse mode is not defined (as for the models)."""
    jac = residuals_jacobian(spec)

    @jax.custom_jvp
    def r_of(z):
        return residuals(param.natural(z), data, spec)

    @r_of.defjvp
    def _jvp(primals, tangents):
        (z,), (tz,) = primals, tangents
        r, J, _ = jac(z, (param, data))
        return r, J @ tz

    return r_of


@float64_scope
def model_solution_at(u, spec: ModelSpec, param, data: CurveBatch) -> jc.ContactSolution:
    """The forward model's batched `ContactSolution` at internal coordinates `u` of `param`
    (:attr:`fitting.FitResult.model_solution`; numpy leaves)."""
    return jax.device_get(_model_solution_at(spec, param, jnp.asarray(u), data))


@eqx.filter_jit
def _model_solution_at(spec, param, u, data):
    return predict(spec, param.to_natural(u), data)
