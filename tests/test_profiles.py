import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.integrate import quad
from scipy.special import gamma

import jaxcontact as jc


def mdr_quad(fprime, x):
    val, _ = quad(lambda r: fprime(r) / np.sqrt(x + r), 0.0, x, weight="alg", wvar=(0.0, -0.5))
    return x * val


@pytest.mark.parametrize("n", [0.7, 1.0, 1.5, 2.0, 3.0])
def test_power_law_transform_matches_quadrature(n):
    c = 2.3e3
    prof = jc.PowerLaw(c=c, n=n)
    for x in [1e-6, 3e-6]:
        ref = mdr_quad(lambda r: c * n * r ** (n - 1), x)
        np.testing.assert_allclose(prof.g(x), ref, rtol=1e-9)
    kappa = np.sqrt(np.pi) * gamma(n / 2 + 1) / gamma(n / 2 + 0.5)
    np.testing.assert_allclose(jc.power_law_factor(n), kappa, rtol=1e-13)


def test_parabola_and_cone_closed_forms():
    R = 1e-4
    p = jc.Parabola(R=R)
    x = np.linspace(0, 1e-5, 7)
    np.testing.assert_allclose(p.g(x), x**2 / R, rtol=1e-14)
    np.testing.assert_allclose(p.g(x), jc.PowerLaw(c=1 / (2 * R), n=2.0).g(x), rtol=1e-12)
    np.testing.assert_allclose(p.integral_g(2e-5), (2e-5) ** 3 / (3 * R), rtol=1e-14)
    alpha = 0.6
    cone = jc.Cone(half_angle=alpha)
    # f = r cot(alpha): g = (pi/2) x cot(alpha), check against quadrature
    ref = mdr_quad(lambda r: 1 / np.tan(alpha), 2e-6)
    np.testing.assert_allclose(cone.g(2e-6), ref, rtol=1e-10)
    np.testing.assert_allclose(cone.shape(1e-6), 1e-6 / np.tan(alpha), rtol=1e-14)


@pytest.mark.parametrize(
    "prof",
    [jc.Parabola(R=1e-4), jc.Cone(half_angle=0.4), jc.PowerLaw(c=1e4, n=2.5)],
    ids=["parabola", "cone", "powerlaw"],
)
def test_derivatives_consistent(prof):
    x = 2e-6
    np.testing.assert_allclose(prof.dg(x), jax.grad(prof.g)(x), rtol=1e-10)
    ig, _ = quad(lambda s: float(prof.g(s)), 0, x)
    np.testing.assert_allclose(prof.integral_g(x), ig, rtol=1e-10)
    check_grads(prof.g, (x,), order=2, modes=["fwd", "rev"], eps=1e-9)


def test_flat_punch():
    fp = jc.FlatPunch(radius=1e-5)
    assert float(fp.g(0.5e-5)) == 0.0
    assert np.isinf(fp.g(2e-5))
    assert float(fp.max_radius) == 1e-5
    assert float(fp.integral_g(1e-5)) == 0.0


def test_vmap_over_profile_parameters():
    Rs = jnp.array([1e-4, 2e-4])
    out = jax.vmap(lambda R: jc.Parabola(R=R).g(1e-5))(Rs)
    np.testing.assert_allclose(out, 1e-10 / Rs)


@pytest.mark.parametrize(
    "ctor, name",
    [
        (lambda: jc.Parabola(R=-1e-4), "R"),
        (lambda: jc.Parabola(R=float("nan")), "R"),
        (lambda: jc.Cone(half_angle=2.0), "half_angle"),
        (lambda: jc.PowerLaw(c=1.0, n=0.0), "n"),
        (lambda: jc.FlatPunch(radius=0.0), "radius"),
    ],
)
def test_bad_profile_parameters(ctor, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        ctor()


@pytest.mark.parametrize(
    "prof", [jc.Parabola(R=1e-4), jc.Cone(half_angle=1.2), jc.PowerLaw(c=3e5, n=3.7)],
    ids=["parabola", "cone", "power-law"])
def test_zero_force_radius_closed_form_against_root(prof):
    # the front's zero-force radius, a h(a) = I(a): the power laws' closed form against the
    # generic bracketed root of AbstractProfile (a second method), and the force there
    from jaxcontact._profiles import AbstractProfile, front_displacement

    c = 3e-4  # m^(1/2)
    a_fc = float(prof.critical_radius(c, 1.5))  # F_f is increasing beyond its minimum
    lo, hi = a_fc, 1e3 * a_fc
    closed = float(prof.zero_force_radius(c, lo, hi))
    root = float(AbstractProfile.zero_force_radius(prof, c, lo, hi))
    assert lo < closed < hi
    assert closed == pytest.approx(root, rel=1e-12)
    a = jnp.asarray(closed)
    force = a * front_displacement(prof, a, c) - prof.integral_g(a)
    assert abs(float(force)) <= 1e-12 * float(prof.integral_g(a))
    # outside the bracket: clipped to its ends
    assert float(prof.zero_force_radius(c, 2 * closed, 3 * closed)) == pytest.approx(2 * closed)


def test_power_law_front_radius_against_brent():
    """A power law's detachment front h(a) = K a^n - c sqrt(a) = m (K from Gamma functions
    here, not `power_law_factor`), n from 0.55 to 6 and c over nine decades, roots from
    1e-12 of the fold to 1e6 times it, against Brent's method: within the root's own
    conditioning (8 eps of the radius plus 16 eps |terms| / h', or at the fold
    sqrt(8 eps |terms| / h'') where smaller); as `fold_root` is traced (no loop)."""
    from scipy.optimize import brentq

    eps = np.finfo(float).eps
    worst = 0.0
    for n in (0.55, 0.7, 1.0, 1.5, 2.0, 3.0, 6.0):
        prof = jc.PowerLaw(c=2.0, n=n)
        K = np.sqrt(np.pi) * gamma(n / 2 + 1) / gamma(n / 2 + 0.5) * 2.0
        for c in (1e-6, 1e-3, 1.0, 1e3):
            fold = (c / (2 * n * K)) ** (1 / (n - 0.5))

            def h(a, c=c, K=K, n=n):
                return K * a**n - c * np.sqrt(a)

            def root(m, c=c, fold=fold, h=h):
                if h(fold) >= m:
                    return fold
                hi = 2 * fold
                while h(hi) < m:
                    hi *= 2
                return brentq(lambda x: h(x) - m, fold, hi, xtol=1e-300, rtol=8.9e-16,
                              maxiter=1000)

            a = np.concatenate([fold * (1 + np.geomspace(1e-12, 1e-1, 8)),
                                fold * np.geomspace(1.2, 1e6, 12)])
            m = h(a)
            want = np.array([root(mm) for mm in m])
            got = np.asarray(jax.jit(lambda m, c=c, fold=fold, prof=prof: prof.front_radius(
                m, c, jnp.asarray(fold)))(m))
            terms = K * a**n + c * np.sqrt(a)
            dh = n * K * a ** (n - 1) - 0.5 * c / np.sqrt(a)
            d2h = np.abs(n * (n - 1) * K * a ** (n - 2) + 0.25 * c * a**-1.5)
            tol = 8 * eps * a + np.minimum(16 * eps * terms / np.maximum(dh, 1e-300),
                                           np.sqrt(8 * eps * terms / d2h))
            worst = max(worst, float(np.max(np.abs(got - want) / tol)))
    assert worst <= 1.0, worst
    text = jax.jit(lambda m: jc.PowerLaw(c=2.0, n=1.5).front_radius(m, 1.0, 0.01)).lower(
        jnp.linspace(0.1, 1.0, 8)).as_text()
    assert "stablehlo.while" not in text
