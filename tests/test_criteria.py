"""Detachment criteria: Heß rule, energetic (glass-modulus) criterion, BEM cell criterion."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy import integrate, optimize

import jaxcontact as jc


def _square_pair_integral(kernel):
    r"""$\iint\iint_{[0,1]^2\times[0,1]^2} k(|\mathbf r - \mathbf r'|)$, reduced to 2D.

    The difference $\mathbf w = \mathbf r - \mathbf r'$ of two uniform points of the unit
    square has density (autocorrelation) $(1-|w_x|)(1-|w_y|)$ on $[-1,1]^2$. By the four
    quadrants and the $w_x \leftrightarrow w_y$ symmetry, in polar coordinates
    $= 8\int_0^{\pi/4}\int_0^{1/\cos\theta}(1-\rho\cos\theta)(1-\rho\sin\theta)
    k(\rho)\,\rho\,d\rho\,d\theta$.
    """

    def inner(theta):
        c, s = math.cos(theta), math.sin(theta)
        val, _ = integrate.quad(
            lambda rho: (1 - rho * c) * (1 - rho * s) * kernel(rho) * rho,
            0.0,
            1.0 / c,
            epsabs=0,
            epsrel=1e-13,
        )
        return val

    val, _ = integrate.quad(inner, 0.0, math.pi / 4, epsabs=0, epsrel=1e-13)
    return 8 * val


def test_square_reduction_on_smooth_kernel():
    # E|r - r'|^2 for two uniform points of the unit square = 2 * 2 * Var(U) = 1/3.
    assert _square_pair_integral(lambda rho: rho**2) == pytest.approx(1 / 3, rel=1e-12)
    # total mass of the autocorrelation = 1
    assert _square_pair_integral(lambda rho: 1.0) == pytest.approx(1.0, rel=1e-12)


def test_bem_chi_against_fourfold_integral():
    numeric = _square_pair_integral(lambda rho: 1.0 / rho) / (2 * math.pi)  # eq. (12)
    assert jc.BEM_CHI == pytest.approx(numeric, rel=1e-11)
    assert jc.BEM_CHI == pytest.approx(0.473201, abs=5e-7)
    # ln((√2+1)/(√2−1)) = 2 asinh(1): the classic closed form (4/3)(1-√2) + 4 asinh 1
    assert 2 * math.pi * jc.BEM_CHI == pytest.approx(
        4 / 3 * (1 - math.sqrt(2)) + 4 * math.asinh(1.0), rel=1e-14
    )


def test_bem_energy_balance():
    delta = np.array([1e-8, 5e-8, 2e-7])  # cell sizes [m]
    w, estar = 0.05, 4 * 2e6  # J/m^2, Pa (incompressible glass: E* = 4 G0)
    sigma_c = jc.bem_critical_stress(delta, w, estar)
    assert np.all(sigma_c < 0)
    u_el = jc.bem_release_energy(sigma_c, delta, estar)
    np.testing.assert_allclose(u_el, w * delta**2, rtol=1e-13)  # eq. (14)
    np.testing.assert_allclose(sigma_c, -np.sqrt(estar * w / (0.473201 * delta)), rtol=1e-6)
    # U_el = sigma^2 chi Delta^3 / E*
    assert float(jc.bem_release_energy(-3e5, 1e-7, estar)) == pytest.approx(
        9e10 * jc.BEM_CHI * 1e-21 / estar, rel=1e-14
    )


def test_energetic_criterion_energy_balance():
    a = np.array([0.0, 1e-7, 1e-6, 3e-5])
    w, g0 = 0.03, 5e6
    dl0 = jc.critical_elongation(a, w, g0)
    np.testing.assert_allclose(4 * g0 * dl0**2, 2 * np.pi * a * w, rtol=1e-14, atol=0)  # (10)
    assert np.all(np.asarray(dl0) >= 0)


def _jkr_energy(a, d, R, estar):
    r"""Stored elastic energy [J] of a paraboloid contact of radius $a$ at indentation $d$
    (3D, Johnson's JKR construction, not the MDR): the Hertz state $U_H = \frac{8}{15}E^*a^5/R^2$
    at $d_H = a^2/R$, $F_H = \frac43 E^*a^3/R$, then a flat-punch unloading of stiffness
    $2E^*a$ at fixed $a$: $U = U_H + F_H(d - d_H) + E^*a(d - d_H)^2$."""
    dH = a**2 / R
    return 8 / 15 * estar * a**5 / R**2 + 4 / 3 * estar * a**3 / R * (d - dH) + estar * a * (d - dH) ** 2


def _release_rate(energy, a, d):
    r"""$G = (\partial U/\partial a)_d / (2\pi a)$ by central finite differences."""
    h = 1e-5 * a
    return (energy(a + h, d) - energy(a - h, d)) / (2 * h) / (2 * np.pi * a)


def test_criteria_balance_the_energy_release_rate():
    # the elastic energy released per new contact area equals the work of adhesion at the
    # edge the criteria predict: G = dgamma (Griffith), from the 3D energy by finite differences
    R, w, g0 = 1e-5, 0.05, 2.5e6
    estar = 4 * g0  # the energetic criterion is the elastic balance with the glass modulus
    energy = lambda a, d: _jkr_energy(a, d, R, estar)  # noqa: E731
    for a in (3e-7, 1e-6, 4e-6):
        d_c = a**2 / R - float(jc.hess_elongation(a, w, estar))
        assert _release_rate(energy, a, d_c) == pytest.approx(w, rel=1e-7)
        # the MDR edge line load q = E*(d - g(a)) at that indentation is the critical one
        q_c = float(jc.critical_line_load(a, w, g0))
        assert q_c == pytest.approx(estar * (d_c - a**2 / R), rel=1e-12)
        d_q = a**2 / R + q_c / estar
        assert _release_rate(energy, a, d_q) == pytest.approx(w, rel=1e-7)
        # the glass spring's elongation (eq. 11) is the same edge
        assert float(jc.critical_elongation(a, w, g0)) == pytest.approx(a**2 / R - d_c, rel=1e-12)


def test_flat_punch_kendall():
    # Kendall (1971): a flat punch of radius a detaches at F = -sqrt(8 pi a^3 dgamma E*). Its
    # energy at fixed a, U = E* a d^2 (stiffness 2E*a), gives G = dgamma at d_c; the MDR force
    # of the uniformly stretched springs is F = 2a q with the edge line load q = E* d.
    a, w, g0 = 2e-6, 0.03, 1.5e6
    estar = 4 * g0
    g_unit = _release_rate(lambda a_, d: estar * a_ * d**2, a, 1.0)  # G at d = 1 m
    d_c = -np.sqrt(w / g_unit)
    kendall = -np.sqrt(8 * np.pi * a**3 * w * estar)
    assert 2 * estar * a * d_c == pytest.approx(kendall, rel=1e-8)
    assert float(2 * a * jc.critical_line_load(a, w, g0)) == pytest.approx(kendall, rel=1e-8)
    assert float(2 * estar * a * -jc.hess_elongation(a, w, estar)) == pytest.approx(kendall,
                                                                                   rel=1e-8)


def test_energetic_criterion_is_hess_rule_with_glass_modulus():
    a = np.geomspace(1e-8, 1e-4, 7)
    w, g0 = 0.07, 3e7
    dl0 = jc.critical_elongation(a, w, g0)
    np.testing.assert_allclose(dl0, jc.hess_elongation(a, w, 4 * g0), rtol=1e-14)
    q = jc.critical_line_load(a, w, g0)
    assert np.all(np.asarray(q) < 0)
    np.testing.assert_allclose(q, -4 * g0 * dl0, rtol=1e-14)


@pytest.mark.parametrize("which", ["hess", "line_load"])
def test_pulloff_of_paraboloid_is_jkr(which):
    # force control: the least force over the front d(a) = g(a) - dl(a) of the elastic MDR
    # (F = 2E*(a d - a^3/(3R)), g = a^2/R) is JKR's -(3/2) pi dgamma R, found by a minimiser
    R, w, g0 = 1e-5, 0.05, 2.5e6
    estar = 4 * g0

    def force(a):
        if which == "hess":
            d = a**2 / R - float(jc.hess_elongation(a, w, estar))
        else:
            d = a**2 / R + float(jc.critical_line_load(a, w, g0)) / estar
        return 2 * estar * (a * d - a**3 / (3 * R))

    res = optimize.minimize_scalar(force, bounds=(1e-9, 1e-5), method="bounded",
                                   options={"xatol": 1e-15})
    assert res.fun == pytest.approx(-1.5 * np.pi * w * R, rel=1e-9)


def test_hess_rule_reproduces_jkr():
    # parabola: F(a) = 4E*a^3/(3R) - sqrt(8 pi E* w a^3); force-controlled minimum -3/2 pi w R
    R, w, estar = 1e-5, 0.05, 1e7
    a_c = (9 * np.pi * w * R**2 / (8 * estar)) ** (1 / 3)
    d = a_c**2 / R - jc.hess_elongation(a_c, w, estar)
    force = 2 * estar * (d * a_c - a_c**3 / (3 * R))
    assert float(force) == pytest.approx(-1.5 * np.pi * w * R, rel=1e-12)


def test_broadcasting_and_jit():
    a = jnp.linspace(1e-7, 1e-6, 5)[:, None]
    g0 = jnp.array([1e6, 2e6, 4e6])
    out = jax.jit(jc.critical_line_load)(a, 0.1, g0)
    assert out.shape == (5, 3)
    # each element is the unbatched call
    ref = [[float(jc.critical_line_load(float(ai), 0.1, float(gj))) for gj in g0] for ai in a[:, 0]]
    np.testing.assert_allclose(out, ref, rtol=1e-14)
    vm = jax.vmap(jc.bem_critical_stress, in_axes=(0, None, None))(jnp.array([1e-8, 1e-7]), 0.1, 1e7)
    assert vm.shape == (2,)


@pytest.mark.parametrize(
    "fn",
    [jc.critical_elongation, jc.critical_line_load, jc.hess_elongation, jc.bem_critical_stress],
)
def test_grads(fn):
    # dimensionless magnitudes for the finite differences; the formulas are scale-free
    check_grads(fn, (0.7, 1.3, 2.1), order=2, modes=["fwd", "rev"])


def test_grads_release_energy():
    check_grads(jc.bem_release_energy, (-0.8, 1.3, 2.1), order=2, modes=["fwd", "rev"])


def test_grad_values():
    a, w, g0 = 2e-6, 0.04, 1e6
    dda = jax.grad(jc.critical_elongation)(a, w, g0)
    assert float(dda) == pytest.approx(0.5 * float(jc.critical_elongation(a, w, g0)) / a)
    ddg = jax.grad(jc.critical_line_load, argnums=2)(a, w, g0)
    assert float(ddg) == pytest.approx(0.5 * float(jc.critical_line_load(a, w, g0)) / g0)


@pytest.mark.parametrize(
    ("fn", "args", "name"),
    [
        (jc.critical_elongation, (-1e-6, 0.1, 1e6), "radius"),
        (jc.critical_elongation, (1e-6, 0.0, 1e6), "work_of_adhesion"),
        (jc.critical_elongation, (1e-6, 0.1, -1e6), "glass_modulus"),
        (jc.critical_elongation, (np.nan, 0.1, 1e6), "radius"),
        (jc.critical_line_load, (1e-6, 0.1, 0.0), "glass_modulus"),
        (jc.critical_line_load, (1e-6, np.inf, 1e6), "work_of_adhesion"),
        (jc.hess_elongation, (1e-6, 0.1, 0.0), "effective_modulus"),
        (jc.hess_elongation, (np.array([1e-6, -1.0]), 0.1, 1e6), "radius"),
        (jc.bem_critical_stress, (0.0, 0.1, 1e6), "cell_size"),
        (jc.bem_critical_stress, (1e-8, -0.1, 1e6), "work_of_adhesion"),
        (jc.bem_critical_stress, (1e-8, 0.1, np.nan), "effective_modulus"),
        (jc.bem_release_energy, (np.nan, 1e-8, 1e6), "stress"),
        (jc.bem_release_energy, (1.0, -1e-8, 1e6), "cell_size"),
    ],
)
def test_bad_inputs(fn, args, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        fn(*args)


def test_zero_radius_allowed():
    assert float(jc.critical_elongation(0.0, 0.1, 1e6)) == 0.0
    assert float(jc.critical_line_load(0.0, 0.1, 1e6)) == 0.0
