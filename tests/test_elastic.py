import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.integrate import quad
from scipy.optimize import minimize_scalar

import jaxcontact as jc

E, DG, R = 2e6, 0.04, 5e-5
KW = dict(effective_modulus=E, work_of_adhesion=DG)


def test_jkr_parabola_closed_forms():
    p = jc.Parabola(R=R)
    a = np.linspace(1e-7, 2e-5, 9)
    np.testing.assert_allclose(
        jc.jkr_displacement(p, a, **KW), a**2 / R - np.sqrt(2 * np.pi * a * DG / E), rtol=1e-12
    )
    np.testing.assert_allclose(
        jc.jkr_force(p, a, **KW),
        4 * E * a**3 / (3 * R) - np.sqrt(8 * np.pi * E * DG * a**3),
        rtol=1e-11,
        atol=1e-20,
    )


def test_hertz_limit():
    p = jc.Parabola(R=R)
    a = 1e-5
    d = jc.jkr_displacement(p, a, effective_modulus=E, work_of_adhesion=0.0)
    F = jc.jkr_force(p, a, effective_modulus=E, work_of_adhesion=0.0)
    np.testing.assert_allclose(d, a**2 / R, rtol=1e-14)
    # Hertz: F = (4/3) E* R^(1/2) d^(3/2)
    np.testing.assert_allclose(F, 4 / 3 * E * np.sqrt(R) * d**1.5, rtol=1e-12)


def test_pull_off_parabola():
    p = jc.Parabola(R=R)
    fc = jc.pull_off(p, control="force", **KW)
    dc = jc.pull_off(p, control="displacement", **KW)
    np.testing.assert_allclose(fc.force, -1.5 * np.pi * DG * R, rtol=1e-12)
    np.testing.assert_allclose(fc.radius, (9 * np.pi * DG * R**2 / (8 * E)) ** (1 / 3), rtol=1e-12)
    np.testing.assert_allclose(dc.force, -5 / 6 * np.pi * DG * R, rtol=1e-12)
    np.testing.assert_allclose(dc.radius, (np.pi * DG * R**2 / (8 * E)) ** (1 / 3), rtol=1e-12)


def test_pull_off_numerical_minimisation_second_method():
    """The critical points are the minima of d(a) and F(a), found here by scipy."""
    cone = jc.Cone(half_angle=1.2)
    for control, fn in [("displacement", jc.jkr_displacement), ("force", jc.jkr_force)]:
        po = jc.pull_off(cone, control=control, **KW)
        res = minimize_scalar(
            lambda loga, fn=fn: float(fn(cone, np.exp(loga), **KW)) * 1e9,
            bounds=(np.log(1e-10), np.log(1e-4)),
            method="bounded",
            options={"xatol": 1e-10},
        )
        np.testing.assert_allclose(po.radius, np.exp(res.x), rtol=1e-5)
    # cone closed form for force control: a = 18 dgamma / (pi E* tan^2 theta), theta = pi/2 - alpha
    slope = 1 / np.tan(1.2)
    np.testing.assert_allclose(
        jc.pull_off(cone, control="force", **KW).radius, 18 * DG / (np.pi * E * slope**2), rtol=1e-12
    )


def test_kendall_flat_punch():
    a0 = 3e-6
    fp = jc.FlatPunch(radius=a0)
    for control in ["force", "displacement"]:
        po = jc.pull_off(fp, control=control, **KW)
        np.testing.assert_allclose(po.force, -np.sqrt(8 * np.pi * E * DG * a0**3), rtol=1e-12)
        np.testing.assert_allclose(po.radius, a0)


def test_numerical_path_matches_closed_forms():
    """The generic (bracketed-root) path for an arbitrary profile against the parabola."""
    tab_r = np.linspace(0, 4e-5, 2001)
    tab = jc.Tabulated(r=tab_r, f=tab_r**2 / (2 * R))
    p = jc.Parabola(R=R)
    for control in ["force", "displacement"]:
        np.testing.assert_allclose(
            jc.pull_off(tab, control=control, **KW).force,
            jc.pull_off(p, control=control, **KW).force,
            rtol=1e-8,
        )
    d = np.linspace(float(jc.pull_off(p, **KW).displacement) * 0.999, 2e-6, 6)
    np.testing.assert_allclose(
        jc.jkr_contact_radius(tab, d, **KW), jc.jkr_contact_radius(p, d, **KW), rtol=1e-7
    )
    np.testing.assert_allclose(
        jc.jkr_contact_radius(jc.PowerLaw(c=0.5 / R, n=2.0), d, **KW),
        jc.jkr_contact_radius(p, d, **KW),
        rtol=1e-9,
    )


def test_contact_radius_inverts_displacement_and_detaches():
    p = jc.Parabola(R=R)
    po = jc.pull_off(p, **KW)
    d = jnp.linspace(po.displacement, 3e-6, 50)[1:]
    a = jc.jkr_contact_radius(p, d, **KW)
    np.testing.assert_allclose(jc.jkr_displacement(p, a, **KW), d, rtol=1e-9, atol=1e-18)
    assert np.all(a >= po.radius * (1 - 1e-8))
    below = jc.jkr_contact_radius(p, po.displacement - 1e-10, **KW)
    assert float(below) == 0.0
    g = jax.grad(lambda dd: jc.jkr_contact_radius(p, dd, **KW))(po.displacement - 1e-10)
    assert np.isfinite(g) and float(g) == 0.0


def test_pressure_hertz_and_boussinesq():
    p = jc.Parabola(R=R)
    a = 1e-5
    r = np.linspace(0, 0.99 * a, 11)
    hertz = 2 * E / (np.pi * R) * np.sqrt(a**2 - r**2)
    np.testing.assert_allclose(
        jc.contact_pressure(p, r, a, effective_modulus=E), hertz, rtol=1e-12, atol=1e-9
    )
    fp = jc.FlatPunch(radius=a)
    d = 1e-7
    np.testing.assert_allclose(
        jc.contact_pressure(fp, r, a, effective_modulus=E, displacement=d),
        E * d / (np.pi * np.sqrt(a**2 - r**2)),
        rtol=1e-12,
    )
    assert float(jc.contact_pressure(p, 1.5 * a, a, effective_modulus=E)) == 0.0


@pytest.mark.parametrize(
    "prof", [jc.Parabola(R=R), jc.Cone(half_angle=1.3), jc.PowerLaw(c=3e8, n=3.0)]
)
def test_force_from_pressure_equals_mdr_force(prof):
    """2 pi int p r dr of the back-transformed pressure equals F(a) (substitution r = a sin t)."""
    a = 8e-6

    def integrand(t):
        r = a * np.sin(t)
        # p(r) r dr with the edge singularity cancelled by dr = a cos t dt
        return float(jc.contact_pressure(prof, r, a, **KW)) * r * a * np.cos(t)

    val, _ = quad(integrand, 0, np.pi / 2, limit=200, epsabs=0, epsrel=1e-11)
    np.testing.assert_allclose(2 * np.pi * val, jc.jkr_force(prof, a, **KW), rtol=1e-8)


def test_gradients_elastic_relations():
    p_R = 5e-5

    def F(a, E_, dg, R_):
        return jc.jkr_force(jc.Parabola(R=R_), a, effective_modulus=E_, work_of_adhesion=dg)

    # compiled: the same derivatives (custom rules included) as op by op, at 40 % of the
    # CPU time (every eager operation of the second-order checks compiles on its own)
    check_grads(jax.jit(F), (1e-5, E, DG, p_R), order=2, modes=["fwd", "rev"],
                eps=1e-9 * 0 + 1e-10)

    def pulloff(E_, dg, R_):
        return jc.pull_off(jc.Parabola(R=R_), effective_modulus=E_, work_of_adhesion=dg).force

    g = jax.grad(pulloff, argnums=(0, 1, 2))(E, DG, R)
    np.testing.assert_allclose(g[0], 0.0, atol=1e-20)
    np.testing.assert_allclose(g[1], -5 / 6 * np.pi * R, rtol=1e-10)
    np.testing.assert_allclose(g[2], -5 / 6 * np.pi * DG, rtol=1e-10)

    def radius(d, dg):
        return jc.jkr_contact_radius(jc.Parabola(R=R), d, effective_modulus=E, work_of_adhesion=dg)

    d = 1e-6
    eps = 1e-13
    fd = (radius(d + eps, DG) - radius(d - eps, DG)) / (2 * eps)
    np.testing.assert_allclose(jax.grad(radius)(d, DG), fd, rtol=1e-6)
    tab_r = np.linspace(0, 4e-5, 801)
    tab = jc.Tabulated(r=tab_r, f=tab_r**2 / (2 * R))
    g_tab = jax.grad(lambda dd: jc.jkr_contact_radius(tab, dd, **KW))(d)
    np.testing.assert_allclose(g_tab, fd, rtol=1e-5)


def test_bad_inputs():
    p = jc.Parabola(R=R)
    with pytest.raises(ValueError, match="effective_modulus"):
        jc.jkr_force(p, 1e-6, effective_modulus=-1.0, work_of_adhesion=DG)
    with pytest.raises(ValueError, match="work_of_adhesion"):
        jc.pull_off(p, effective_modulus=E, work_of_adhesion=0.0)
    with pytest.raises(ValueError, match="control"):
        jc.pull_off(p, control="speed", **KW)


@pytest.mark.parametrize("dtype, ulps", [(np.float64, 4), (np.float32, 4)])
def test_reciprocal_cube_root_against_numpy(dtype, ulps):
    # the multiply-only y^(-1/3) behind the parabola's front root, over the whole range of
    # normal numbers whose cube stays representable
    from jaxcontact._profiles import _rcbrt_positive

    lim = 90 if dtype == np.float32 else 300
    rng = np.random.default_rng(3)
    y = np.concatenate([10.0 ** rng.uniform(-lim / 3, lim / 3, 100_000),
                        rng.uniform(1 / 16, 4, 100_000)]).astype(dtype)
    got = np.asarray(jax.jit(_rcbrt_positive)(jnp.asarray(y))).astype(np.float64)
    exact = 1.0 / np.cbrt(y.astype(np.float64))
    assert got.dtype == np.float64 and np.all(np.isfinite(got))
    assert np.max(np.abs(got / exact - 1)) < ulps * np.finfo(dtype).eps


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_parabola_front_root_solves_the_quartic(dtype):
    # a^2/R - c sqrt(a) = m on the stable branch, from the fold to deep compression (weak
    # adhesion: a / a_fold up to 1e9, where Cardano's u + v cancels if written naively and
    # mu^3 overflows float32)
    from jaxcontact._profiles import parabola_stable_radius

    R, c = 1e-4, 3e-5
    a_fold = (c * R / 4) ** (2 / 3)
    a = a_fold * np.concatenate([1 + np.logspace(-6, 0, 50), np.logspace(0.3, 9, 60)])
    m = a**2 / R - c * np.sqrt(a)
    args = (jnp.asarray(m, dtype), jnp.asarray(c, dtype), jnp.asarray(R, dtype))
    got = np.asarray(jax.jit(parabola_stable_radius)(*args))
    assert got.dtype == dtype  # no silent promotion
    got = got.astype(np.float64)
    # the tolerance follows the root's relative condition number: rounding m's two terms
    # (relative eps) moves a by eps * kappa, kappa = (a^2/R + c sqrt(a)) / (a |h'(a)|),
    # h'(a) = 2a/R - c / (2 sqrt(a)); kappa is 0.5 deep in compression and grows without
    # bound at the fold (a double root). Measured: error <= 14 eps kappa with both of
    # XLA's CPU code generators (fitting.XLA_CPU_FLAGS), <= 2 eps deep in compression.
    eps = np.finfo(dtype).eps
    kappa = (a**2 / R + c * np.sqrt(a)) / (a * np.abs(2 * a / R - c / (2 * np.sqrt(a))))
    tol = eps * (4 + 20 * kappa)
    assert np.all(np.abs(got / a - 1) < tol), np.max(np.abs(got / a - 1) / tol)
