"""Tabulated profiles: MDR transform of a table against the closed forms."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import jaxcontact as jc

N = 4000  # table points
RMAX = 2e-6  # table range [m]
R_TAB = np.linspace(0.0, RMAX, N)
H = RMAX / (N - 1)


def _rel(got, want):
    got, want = np.asarray(got), np.asarray(want)
    return float(np.max(np.abs(got - want) / np.abs(want)))


def _x_grid(x_min):
    # fixed size (the compiled kernels are reused across tests)
    return np.concatenate([np.geomspace(x_min, RMAX, 60), np.linspace(x_min, RMAX, 61)])


def _closed_forms():
    """(name, f(r), exact profile, x_min, tol): profiles the not-a-knot spline reproduces
    exactly are tested from the first node on; the others from x = 0.03 r_max on."""
    R = 1e-5
    tan_t = 0.4
    out = [
        ("parabola", R_TAB**2 / (2 * R), jc.Parabola(R), H, 1e-9),
        ("cone", tan_t * R_TAB, jc.Cone(np.arctan(1 / tan_t)), H, 1e-9),
        ("cubic", 3e4 * R_TAB**3, jc.PowerLaw(3e4, 3.0), H, 1e-9),
    ]
    for n, c in [(1.5, 30.0), (2.5, 1e8), (4.0, 1e17)]:
        out.append((f"power{n}", c * R_TAB**n, jc.PowerLaw(c, n), 0.03 * RMAX, 1e-6))
    return [pytest.param(*case, id=case[0]) for case in out]


@pytest.mark.parametrize(("name", "f", "exact", "x_min", "tol"), _closed_forms())
def test_closed_forms(name, f, exact, x_min, tol):
    p = jc.Tabulated(R_TAB, f)
    x = _x_grid(x_min)
    assert _rel(p.g(x), exact.g(x)) < tol
    assert _rel(p.dg(x), exact.dg(x)) < tol
    assert _rel(p.integral_g(x), exact.integral_g(x)) < tol
    assert _rel(p.shape(x), exact.shape(x)) < tol
    # evenness of g, odd integral
    np.testing.assert_allclose(p.g(-x), p.g(x), rtol=1e-15)
    np.testing.assert_allclose(p.integral_g(-x), -p.integral_g(x), rtol=1e-15)


def test_measured_accuracy_power_law():
    """The error that the docstring quotes (N = 4000 uniform, n = 4, x >= 0.01 r_max)."""
    c, n = 1e17, 4.0
    p = jc.Tabulated(R_TAB, c * R_TAB**n)
    exact = jc.PowerLaw(c, n)
    x = _x_grid(0.01 * RMAX)
    assert _rel(p.g(x), exact.g(x)) < 1e-7
    assert _rel(p.integral_g(x), exact.integral_g(x)) < 1e-7
    assert _rel(p.dg(x), exact.dg(x)) < 1e-5
    xs = _x_grid(0.1 * RMAX)
    assert _rel(p.g(xs), exact.g(xs)) < 1e-10
    assert _rel(p.dg(xs), exact.dg(xs)) < 1e-7


def test_curvature():
    x = _x_grid(H)
    p = jc.Tabulated(R_TAB, R_TAB**2 / 2e-5)
    assert _rel(p.d2g(x), 2 / 1e-5 + 0 * x) < 1e-6
    p3 = jc.Tabulated(R_TAB, 3e4 * R_TAB**3)
    exact = jc.PowerLaw(3e4, 3.0)
    assert _rel(p3.d2g(x), 3 * 2 * jc.power_law_factor(3.0) * 3e4 * x) < 1e-6
    assert _rel(p3.d2g(x), jax.vmap(jax.grad(exact.dg))(x)) < 1e-6


def test_nonuniform_table():
    # clustered towards the axis; power law with n = 2.5 is singular there
    r = RMAX * np.linspace(0.0, 1.0, 1500) ** 2
    c, n = 1e8, 2.5
    p = jc.Tabulated(r, c * r**n)
    exact = jc.PowerLaw(c, n)
    x = _x_grid(1e-3 * RMAX)
    assert _rel(p.g(x), exact.g(x)) < 1e-7
    assert _rel(p.dg(x), exact.dg(x)) < 1e-6
    assert _rel(p.integral_g(x), exact.integral_g(x)) < 1e-7


# --- small dimensionless tables (derivatives, ends, jit); shapes are shared between tests
# so that the compiled kernels are reused

R_S = np.linspace(0.0, 1.0, 40)
F_S = np.exp(R_S) - np.cos(R_S) - R_S  # f'(0) = 0, not a polynomial


def test_ends_and_nodes_are_finite():
    p = jc.Tabulated(R_S, 3.0 * R_S**2 + 0.05 * R_S)  # f'(0) != 0: g has a kink at 0
    special = jnp.array([0.0, R_S[1], R_S[17], R_S[-2], 1.0, 1.2, -1.0])
    sign = np.sign(special)
    v = {m: getattr(p, m)(special) for m in ("g", "dg", "d2g", "integral_g")}
    assert all(np.all(np.isfinite(val)) for val in v.values())
    dg_ad = jax.vmap(jax.grad(p.g))(special)
    d2g_ad = jax.vmap(jax.grad(jax.grad(p.g)))(special)
    g_ad = jax.vmap(jax.grad(p.integral_g))(special)
    for val in (dg_ad, d2g_ad, g_ad):
        assert np.all(np.isfinite(val))
    # g(0) = 0, g'(0+) = (pi/2) f'(0), g''(0) = 2 f''(0); the table end is r = 1
    assert float(v["g"][0]) == 0.0
    assert float(v["integral_g"][0]) == 0.0
    assert float(v["dg"][0]) == pytest.approx(np.pi / 2 * 0.05, rel=1e-12)
    assert float(v["d2g"][0]) == pytest.approx(2 * 6.0, rel=1e-12)
    assert float(p.max_radius) == 1.0
    # cone + parabola is reproduced exactly (also extrapolated): g = (pi/2) 0.05 |x| + 6 x^2
    ax = np.abs(special)
    np.testing.assert_allclose(v["g"], np.pi / 2 * 0.05 * ax + 6 * ax**2, rtol=1e-13)
    np.testing.assert_allclose(v["dg"], np.pi / 2 * 0.05 + 12 * ax, rtol=1e-11)
    np.testing.assert_allclose(v["d2g"], 12.0, rtol=1e-10)
    np.testing.assert_allclose(
        v["integral_g"], sign * (np.pi / 4 * 0.05 * ax**2 + 2 * ax**3), rtol=1e-13
    )
    # autodiff at the nodes and at the table end equals the closed-form derivatives
    np.testing.assert_allclose(dg_ad, sign * v["dg"], rtol=1e-13)
    np.testing.assert_allclose(d2g_ad[1:], v["d2g"][1:], rtol=1e-10)
    np.testing.assert_allclose(g_ad, v["g"], rtol=1e-13)


def test_offset_is_removed():
    p0, p1 = jc.Tabulated(R_S, F_S), jc.Tabulated(R_S, F_S + 0.25)
    x = jnp.linspace(0.05, 1.0, 7)
    for method in ("g", "dg", "integral_g", "shape"):
        np.testing.assert_allclose(getattr(p1, method)(x), getattr(p0, method)(x), rtol=1e-9)
    assert float(p1.shape(jnp.zeros(7))[0]) == 0.0


def test_grads_wrt_x():
    p = jc.Tabulated(R_S, F_S)
    x0 = 0.37
    check_grads(p.g, (x0,), order=2, modes=["rev"], eps=1e-5)
    check_grads(p.integral_g, (x0,), order=1, modes=["fwd", "rev"], eps=1e-5)
    # autodiff equals the closed-form derivatives, near the axis, between and at nodes
    x = jnp.array([0.0137, 0.37, R_S[11], 0.99, 1.0, 0.5, 0.7])
    np.testing.assert_allclose(jax.vmap(jax.grad(p.g))(x), p.dg(x), rtol=1e-13)
    np.testing.assert_allclose(jax.vmap(jax.grad(p.dg))(x), p.d2g(x), rtol=1e-13)
    np.testing.assert_allclose(jax.vmap(jax.grad(p.integral_g))(x), p.g(x), rtol=1e-13)
    # and the closed-form derivatives against central differences
    e = 1e-6
    for fun, deriv, tol in [
        (p.g, p.dg, 1e-8),
        (p.dg, p.d2g, 1e-6),
        (p.integral_g, p.g, 1e-8),
        (p.shape, jax.vmap(jax.grad(p.shape)), 1e-8),
    ]:
        np.testing.assert_allclose(deriv(x), (fun(x + e) - fun(x - e)) / (2 * e), rtol=tol)


def test_grads_wrt_table_values():
    x0 = 0.37

    def make(method):
        return lambda fv: getattr(jc.Tabulated(R_S, fv), method)(x0)

    f = jnp.asarray(F_S)
    check_grads(make("g"), (f,), order=1, modes=["rev"], eps=1e-5)
    # the others against central differences along a random direction
    direction = jnp.asarray(np.random.default_rng(0).normal(size=F_S.shape))
    e = 1e-6
    for method in ("dg", "integral_g"):
        fun = make(method)
        fd = (fun(f + e * direction) - fun(f - e * direction)) / (2 * e)
        ad = jnp.dot(jax.grad(fun)(f), direction)
        assert float(ad) == pytest.approx(float(fd), rel=1e-7)
    # mixed second derivative d/dx d/df g = d/df dg, also at a node
    x = R_S[11]  # at a node
    mixed = jax.jacfwd(jax.grad(lambda fv, xx: jc.Tabulated(R_S, fv).g(xx)), argnums=1)(f, x)
    direct = jax.grad(lambda fv, xx: jc.Tabulated(R_S, fv).dg(xx))(f, x)
    np.testing.assert_allclose(mixed, direct, rtol=1e-10, atol=1e-14)


def test_grad_through_module():
    p = jc.Tabulated(R_S, F_S)
    grads = eqx.filter_grad(lambda prof: prof.integral_g(0.6))(p)
    expected = jax.grad(lambda fv: jc.Tabulated(R_S, fv).integral_g(0.6))(jnp.asarray(F_S))
    np.testing.assert_allclose(grads.f, expected, rtol=1e-13)
    # g is linear in f
    p2 = jc.Tabulated(R_S, 2 * F_S + 1.0)
    np.testing.assert_allclose(p2.g(0.4), 2 * p.g(0.4), rtol=1e-13)


def test_jit_vmap_shapes():
    p = jc.Tabulated(R_S, F_S)
    x = jnp.linspace(0.0, 1.0, 14).reshape(2, 7)
    for method in ("g", "dg", "d2g", "integral_g", "shape"):
        assert getattr(p, method)(x).shape == (2, 7)
    direct = p.integral_g(x)
    jitted = eqx.filter_jit(lambda prof, xx: prof.integral_g(xx))(p, x)
    np.testing.assert_allclose(jitted, direct, rtol=1e-11)
    mapped = jax.vmap(p.integral_g)(x.ravel())
    np.testing.assert_allclose(mapped, direct.ravel(), rtol=1e-11)
    assert p.g(0.5).shape == ()
    # a batch of tables
    fs = jnp.stack([F_S, 3 * F_S])
    out = jax.jit(jax.vmap(lambda fv: jc.Tabulated(R_S, fv).g(jnp.linspace(0.1, 0.9, 7))))(fs)
    np.testing.assert_allclose(out[1], 3 * out[0], rtol=1e-13)


@pytest.mark.parametrize(
    ("r", "f", "match"),
    [
        (np.array([0.0, 1.0, 2.0, 3.0]), np.zeros(5), "`f`"),
        (np.array([0.1, 1.0, 2.0, 3.0]), np.zeros(4), "`r`.*r\\[0\\] = 0"),
        (np.array([0.0, 1.0, 1.0, 3.0]), np.zeros(4), "`r`.*strictly increasing"),
        (np.array([0.0, 2.0, 1.0, 3.0]), np.zeros(4), "`r`.*strictly increasing"),
        (np.array([0.0, 1.0, np.nan, 3.0]), np.zeros(4), "`r`"),
        (np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.0, np.inf, 1.0, 2.0]), "`f`"),
        (np.array([0.0, 1.0, 2.0]), np.zeros(3), "at least 4"),
        (np.zeros((4, 2)), np.zeros((4, 2)), "1-D"),
    ],
)
def test_bad_inputs(r, f, match):
    with pytest.raises(ValueError, match=match):
        jc.Tabulated(r, f)


def test_spline_is_scipy_not_a_knot():
    from scipy.interpolate import CubicSpline

    r = np.sort(np.concatenate([[0.0], np.random.default_rng(3).uniform(0.0, 1.0, 39)]))
    f = np.sin(2 * r) * r + r**2
    x = np.linspace(0.0, 1.0, 7)
    np.testing.assert_allclose(jc.Tabulated(r, f).shape(x), CubicSpline(r, f)(x) - f[0], rtol=1e-10, atol=1e-14)
