"""The fitting objective's Jacobian with one column from the force's homogeneity
(`fitting._objective.residuals_jacobian`) against forward mode through every direction, a
central difference, and the homogeneity itself in the forward models."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fitting import TRUE, R, _curves
from test_fitting_history import _curve, _history

import fitting
from fitting import _optimise
from fitting._objective import effective_force, jacobian_fn, predict
from fitting._spec import make_spec, stress_scaled

STARTS = 6


@pytest.fixture(scope="module")
def retract_curves():
    return _curves(noise=0.01, seed=3)


@pytest.fixture(scope="module")
def history_curve():
    t, d, f, counts = _history(0.01, 2)
    return [_curve(t, d - 0.1e-6, f, counts)]


def _problem(curves, *, model, rheology="standard", contact_point="fit", **kw):
    options = fitting.FitOptions(radius=R, model=model, n_starts=STARTS, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _optimise._problem(curves, options, rheology=rheology,
                                  contact_point=contact_point, previous=None)


def _both(pb):
    """The residuals, Jacobian and model at the starts: every direction through the model
    (`jacobian_fn`), and `residuals_jacobian` (vmapped over the starts, jitted)."""
    fn = _optimise._fn(pb.spec)
    ctx = (pb.param, pb.data)
    Z = jnp.asarray(pb.zs[:STARTS])
    full = jax.jit(jax.vmap(
        lambda z: jacobian_fn(lambda zz: fn.with_model(zz, ctx), has_aux=True)(z)))(Z)
    own = jax.jit(jax.vmap(lambda z: fn.jacobian(z, ctx, True)))(Z)
    return fn, ctx, Z, full, own


CASES = [
    # (model, rheology, options, contact point, a column derived?)
    ("relaxed", "standard", {}, "fit", True),
    ("relaxed", "prony:2", {}, "fixed", True),  # the times are not in H
    ("relaxed", "elastic", {}, "fit", True),  # G from the work of adhesion's column
    ("relaxed", "standard", {"fixed": {"work_of_adhesion": 1e-3}}, "fit", False),
    ("history", "standard", {"cells": 8, "max_samples": 120}, "fit", True),
    ("history", "standard", {"cells": 8, "max_samples": 120, "force_drift": True}, "fit",
     True),
]


@pytest.mark.parametrize("model, rheology, options, contact_point, derived", CASES)
def test_the_derived_column_equals_forward_mode(retract_curves, history_curve, model,
                                                 rheology, options, contact_point, derived):
    """The same residuals and model (to round-off: two compiled programs); every column of the Jacobian as forward
    mode through every direction gives it, the derived one to round-off of the force (it
    is F minus the other columns of H)."""
    curves = retract_curves if model == "relaxed" else history_curve
    pb = _problem(curves, model=model, rheology=rheology, contact_point=contact_point,
                  **options)
    scaled = stress_scaled(pb.spec)
    assert (bool(scaled) and all(i in pb.param.free for i in scaled)) == derived
    _, _, _, (r0, J0, m0), (r1, J1, m1) = _both(pb)
    np.testing.assert_allclose(np.asarray(r1), np.asarray(r0), rtol=1e-11,
                               atol=1e-12 * np.abs(np.asarray(r0)).max())
    for a, b in zip(m1, m0, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-11,
                                   atol=1e-12 * np.abs(np.asarray(b)).max())
    J0, J1 = np.asarray(J0), np.asarray(J1)
    assert np.all(np.isfinite(J1))
    # per start and column, relative to the largest weighted force of the start
    force = np.abs(np.asarray(r0) + (np.sqrt(np.asarray(pb.data.weight))
                                     * np.asarray(pb.data.force) / np.asarray(pb.data.noise)
                                     ).ravel()[None, :]).max(axis=1)
    scale = np.maximum(force, np.abs(J0).max(axis=(1, 2)))[:, None, None]
    err = np.abs(J1 - J0) / scale
    assert err.max() < 1e-12, err.max(axis=(0, 1))
    if pb.spec.force_drift:  # the baseline's columns in closed form (not through the model)
        w = (np.sqrt(np.asarray(pb.data.weight)) / np.asarray(pb.data.noise)).ravel()
        du = np.stack([pb.param.dinternal_dz(np.asarray(z)) for z in pb.zs[:STARTS]])
        k_off, k_s = len(pb.param.free) - 2, len(pb.param.free) - 1
        scale_off = np.asarray(pb.param.scale)[pb.param.free[k_off]]
        scale_s = np.asarray(pb.param.scale)[pb.param.free[k_s]]
        np.testing.assert_allclose(J1[:, :, k_off], w[None] * (scale_off * du[:, k_off, None]),
                                   rtol=1e-12)
        np.testing.assert_allclose(
            J1[:, :, k_s],
            (w * np.asarray(pb.data.ts).ravel())[None] * (scale_s * du[:, k_s, None]),
            rtol=1e-12)


def test_the_derived_column_against_a_central_difference(retract_curves):
    """The derived column (G0's) of the relaxed standard model against a central difference
    of the residuals along z_G0 (a second method, not forward mode)."""
    pb = _problem(retract_curves, model="relaxed")
    fn, ctx, Z, _, (r1, J1, _) = _both(pb)
    k = pb.param.free.index(stress_scaled(pb.spec)[0])
    res = jax.jit(jax.vmap(lambda z: fn(z, ctx)))
    h = 1e-6
    E = jnp.zeros_like(Z).at[:, k].set(h)
    fd = (np.asarray(res(Z + E)) - np.asarray(res(Z - E))) / (2 * h)
    J1 = np.asarray(J1)[:, :, k]
    # away from the jump-off's kinks the residuals are smooth: compare on all samples whose
    # difference quotient does not jump (a kink inside +-h changes it by far more)
    scale = np.abs(J1).max(axis=1, keepdims=True)
    close = np.abs(fd - J1) <= 1e-5 * scale
    assert close.mean() > 0.97, close.mean()


@pytest.mark.parametrize("model", ["relaxed", "history"])
def test_the_model_force_is_homogeneous_in_the_stress_scale(retract_curves, history_curve,
                                                            model):
    """The physics the derived column rests on: with the moduli, the viscosity and the
    work of adhesion all multiplied by lambda (the contact offset and the times kept), the
    forward model's force is lambda times the force and its jump-off time the same."""
    curves = retract_curves if model == "relaxed" else history_curve
    options = {} if model == "relaxed" else {"cells": 8, "max_samples": 120}
    pb = _problem(curves, model=model, **options)
    spec, data = pb.spec, pb.data
    p = jnp.array([TRUE["G0"], TRUE["G1"], TRUE["eta1"], TRUE["work_of_adhesion"], 0.05e-6])
    H = np.zeros(p.shape[0], bool)
    H[list(stress_scaled(spec))] = True
    assert H.tolist() == [True, True, True, True, False]
    lam = 3.7
    a, b = predict(spec, p, data), predict(spec, jnp.where(H, lam * p, p), data)
    fa, fb = np.asarray(effective_force(a, data)), np.asarray(effective_force(b, data))
    assert np.abs(fa).max() > 0
    np.testing.assert_allclose(fb, lam * fa, rtol=1e-9, atol=1e-12 * np.abs(fa).max())
    np.testing.assert_allclose(np.asarray(b.jumpoff_time), np.asarray(a.jumpoff_time),
                               rtol=1e-10)


def test_no_stress_scale_under_compliant_loading():
    """A cantilever's stiffness [N/m] is a stress scale the fit does not vary: the force is
    not homogeneous in the material's parameters alone, and no column is derived."""
    assert stress_scaled(make_spec("history", compliant=True)) == ()
    assert stress_scaled(make_spec("history")) == (0, 1, 2, 3)
    assert stress_scaled(make_spec("relaxed", "prony:2", contact_offset=True)) == (0, 1, 2, 5)


def test_residuals_of_free_differentiate_through_the_one_jacobian(retract_curves):
    """`residuals_of_free` (the posterior's residuals): a JVP along any direction, and
    `jax.jacfwd` through a dense change of coordinates with more directions than free
    parameters (as numpyro's whitened coordinates and noise scales), equal forward mode
    through every direction."""
    from fitting._objective import residuals_of_free

    pb = _problem(retract_curves, model="relaxed")
    fn, ctx, Z, (r0, J0, _), _ = _both(pb)
    r_of = residuals_of_free(pb.spec, pb.param, pb.data)
    z, J = Z[1], np.asarray(J0[1])
    k = z.shape[0]
    t = jnp.linspace(-1.0, 1.5, k)
    r, dr = jax.jit(lambda zz, tt: jax.jvp(r_of, (zz,), (tt,)))(z, t)
    np.testing.assert_allclose(np.asarray(r), np.asarray(r0[1]), rtol=1e-12, atol=1e-12)
    scale = np.abs(J).max()
    np.testing.assert_allclose(np.asarray(dr), J @ np.asarray(t), atol=1e-11 * scale)
    C = np.random.default_rng(0).standard_normal((k, k + 2))  # 2 extra directions
    got = jax.jit(jax.jacfwd(lambda eta: r_of(z + jnp.asarray(C) @ eta)))(jnp.zeros(k + 2))
    np.testing.assert_allclose(np.asarray(got), J @ C, atol=1e-11 * scale * np.abs(C).max())
