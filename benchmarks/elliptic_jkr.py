r"""Approximate JKR theories of an elliptical contact: the reference for the BEM ellipsoid.

An ellipsoid $h = x^2/(2R_x) + y^2/(2R_y)$ pressed into an elastic half-space ($E^*$) with
work of adhesion $\Delta\gamma$, in the JKR limit. Both theories assume an elliptical
contact, semi-axes $a$ (along $x$) and $b$ (along $y$), with the pressure

$$p = E^*\,\frac{\alpha + \beta x^2 + \gamma y^2}{\sqrt{1 - x^2/a^2 - y^2/b^2}},$$

the most general pressure of this form whose surface displacement inside the ellipse is a
quadratic (Galin's theorem), so that it fits the indenter exactly:
$u = d - x^2/(2R_x) - y^2/(2R_y)$ fixes $\alpha, \beta, \gamma$ for given $a, b, d$.

Displacements of the basis pressures (all inside the ellipse, $E^* = 1$), with
$e^2 = 1 - b^2/a^2$ ($a \ge b$; swap the axes otherwise) and $K$, $E$ the complete elliptic
integrals of modulus $e$ (Johnson, *Contact Mechanics*, 1985, ch. 3):

- $(1-\rho^2)^{1/2}$: $u = (L - Mx^2 - Ny^2)/\pi$ with $L = \pi bK$,
  $M = \pi b(K - E)/(e^2a^2)$, $N = \pi b\,(a^2E/b^2 - K)/(e^2a^2)$;
- $(1-\rho^2)^{-1/2}$: $u = 2bK$ (the flat elliptical punch);
- $x^2(1-\rho^2)^{-1/2} = a^3\,\partial_a(1-\rho^2)^{1/2}$ and
  $y^2(1-\rho^2)^{-1/2} = b^3\,\partial_b(1-\rho^2)^{1/2}$: the derivatives of the first
  line with respect to $a$ and $b$ (the pressure vanishes on the moving edge, so the
  derivative of the integral is the integral of the derivative), taken here by
  fourth-order central differences.

Force $F = E^*[2\pi ab\,\alpha + \tfrac{2\pi}{3}ab\,(a^2\beta + b^2\gamma)]$; stored elastic
energy $U = \tfrac12\int p\,u\,\mathrm dA$ with the moments
$\int x^2 (1-\rho^2)^{-1/2} = \tfrac{2\pi}{3}a^3b$, $\int x^4(\ldots) = \tfrac{2\pi}{5}a^5b$,
$\int x^2y^2(\ldots) = \tfrac{2\pi}{15}a^3b^3$. The stress intensity factor at the end of
the $x$ axis is $K_I = -E^*(\alpha + \beta a^2)\sqrt{\pi a}$ (and $y$ likewise), and the
energy release rate $G = K_I^2/(2E^*)$.

- **JG** (Johnson & Greenwood 2005, J. Phys. D 38, 1042): Griffith's criterion
  $K_I^2/(2E^*) = \Delta\gamma$ at the ends of both axes.
- **energy** (the approach of Giudici, Vella & Griffiths 2025): $a$ and $b$ make the total
  energy $U - \pi ab\,\Delta\gamma$ stationary at fixed $d$. By Irwin's relation
  $\partial U/\partial a = b\oint G\cos^2\theta\,\mathrm d\theta$ and
  $\partial U/\partial b = a\oint G\sin^2\theta\,\mathrm d\theta$ on the edge
  $(a\cos\theta, b\sin\theta)$, where $G = \pi E^* P^2/(2w)$,
  $P = \alpha + \beta x^2 + \gamma y^2$, $w = \sqrt{\cos^2\theta/a^2 + \sin^2\theta/b^2}$:
  the two weighted means of $G$ equal $\Delta\gamma$ (evaluated by the trapezoid rule).

Along each equilibrium branch (parametrised by $a$) the force-control pull-off is the
minimum of $F$ and the displacement-control jump-off the force at the minimum of $d$. Both
are computed here from the formulas above (no tabulated values of either paper are used);
for $R_x = R_y$ both reduce to JKR ($-\tfrac32\pi\Delta\gamma R$, $-\tfrac56\pi\Delta\gamma R$),
which `_check` verifies.

Run: ``python benchmarks/elliptic_jkr.py`` prints both theories for a few $R_x/R_y$.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.optimize import fsolve, minimize_scalar
from scipy.special import ellipe, ellipk

__all__ = ["pull_off", "pull_off_table"]


def _u_half(a, b):
    """(L, M, N)/pi: u = L' - M' x^2 - N' y^2 of the pressure (1 - rho^2)^(1/2), E* = 1."""
    if a < b:
        lo, m, n = _u_half(b, a)
        return lo, n, m
    if a == b:
        return np.pi * a / 2, np.pi / (4 * a), np.pi / (4 * a)
    m2 = 1.0 - (b / a) ** 2
    k, e = ellipk(m2), ellipe(m2)
    return b * k, b * (k - e) / (m2 * a * a), b * (a * a * e / (b * b) - k) / (m2 * a * a)


def _u_punch(a, b):
    """Displacement of the pressure (1 - rho^2)^(-1/2), E* = 1 (a constant inside)."""
    big, small = max(a, b), min(a, b)
    return 2.0 * small * ellipk(1.0 - (small / big) ** 2)


def _basis(a, b, rel=1e-3):
    """Rows: the displacement coefficients (constant, x^2, y^2) with u = c0 - cx x^2 - cy y^2
    of the pressures (1, x^2, y^2) / sqrt(1 - rho^2) (fourth-order central differences)."""

    def diff(f, h):
        return (-f(2 * h) + 8 * f(h) - 8 * f(-h) + f(-2 * h)) / (12 * h)

    da = diff(lambda h: np.array(_u_half(a + h, b)), rel * a)
    db = diff(lambda h: np.array(_u_half(a, b + h)), rel * b)
    return np.array([[_u_punch(a, b), 0.0, 0.0], a**3 * da, b**3 * db])


def _state(a, b, d, rx, ry):
    """(alpha, beta, gamma), force and elastic energy at semi-axes a, b and depth d (E* = 1)."""
    B = _basis(a, b)
    # x^2, y^2 coefficients: beta B[1] + gamma B[2] = (1/(2Rx), 1/(2Ry))
    beta, gamma = np.linalg.solve(np.array([[B[1, 1], B[2, 1]], [B[1, 2], B[2, 2]]]),
                                  [0.5 / rx, 0.5 / ry])
    alpha = (d - beta * B[1, 0] - gamma * B[2, 0]) / B[0, 0]
    c = 2 * np.pi * a * b
    force = c * (alpha + (a * a * beta + b * b * gamma) / 3)
    mx2 = c * (alpha * a * a / 3 + beta * 3 * a**4 / 15 + gamma * a * a * b * b / 15)
    my2 = c * (alpha * b * b / 3 + beta * a * a * b * b / 15 + gamma * 3 * b**4 / 15)
    energy = 0.5 * (d * force - mx2 / (2 * rx) - my2 / (2 * ry))
    return (alpha, beta, gamma), force, energy


def _release_rate(coef, a, b, theta):
    """Energy release rate G / E* around the edge, at x = a cos(theta), y = b sin(theta)."""
    alpha, beta, gamma = coef
    c, s = np.cos(theta), np.sin(theta)
    P = alpha + beta * (a * c) ** 2 + gamma * (b * s) ** 2
    w = np.sqrt(c * c / (a * a) + s * s / (b * b))
    return np.pi * P * P / (2 * w)


_THETA = np.linspace(0.0, 2 * np.pi, 128, endpoint=False)  # trapezoid rule (periodic)


def _equations(theory, a, b, d, rx, ry, dgamma):
    coef, _, _ = _state(a, b, d, rx, ry)
    if theory == "jg":  # Griffith at the ends of the two axes (E* = 1)
        return [_release_rate(coef, a, b, 0.0) / dgamma - 1,
                _release_rate(coef, a, b, np.pi / 2) / dgamma - 1]
    # energy: dU/da = b \oint G cos^2, dU/db = a \oint G sin^2 (Irwin) equal pi b, pi a dgamma
    g = _release_rate(coef, a, b, _THETA)
    dth = 2 * np.pi / _THETA.size
    return [np.sum(g * np.cos(_THETA) ** 2) * dth / (np.pi * dgamma) - 1,
            np.sum(g * np.sin(_THETA) ** 2) * dth / (np.pi * dgamma) - 1]


def _branch(theory, rx, ry, dgamma, a_values):
    """(a, b, d, F) along the equilibrium branch, one row per a (continuation in a)."""
    rows = []
    b, d = a_values[0] * (ry / rx) ** (1 / 3), 0.0
    for a in a_values:
        sol, info, ok, _ = fsolve(
            lambda z, a=a: _equations(theory, a, z[0], z[1], rx, ry, dgamma), [b, d],
            full_output=True, xtol=1e-13,
        )
        if ok != 1:
            continue
        b, d = sol
        rows.append((a, b, d, _state(a, b, d, rx, ry)[1]))
    return np.array(rows)


def pull_off(theory: str, ratio: float, *, dgamma: float = 1.0) -> dict:
    """Pull-off of the ellipsoid $R_x = $ `ratio` $\\cdot R_y$, $\\sqrt{R_xR_y} = 1$, $E^* = 1$.

    **Returns:** `force_control` and `displacement_control` pull-off forces over
    $\\tfrac32\\pi\\Delta\\gamma\\sqrt{R_xR_y}$ (negative), and the semi-axes `(a, b)` at the
    force-control pull-off.
    """
    rx, ry = np.sqrt(ratio), 1 / np.sqrt(ratio)
    a_jkr = (9 * np.pi * dgamma / 8) ** (1 / 3)  # force-control radius of the sphere R = 1
    a_values = a_jkr * np.geomspace(3.0, 0.15, 400) * ratio ** (1 / 3)
    br = _branch(theory, rx, ry, dgamma, a_values)
    scale = 1.5 * np.pi * dgamma

    def solve_at(a):
        j = int(np.argmin(np.abs(br[:, 0] - a)))
        with warnings.catch_warnings():  # at round-off fsolve says it cannot improve
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = fsolve(lambda z: _equations(theory, a, z[0], z[1], rx, ry, dgamma),
                         br[j, 1:3], xtol=1e-14)
        return sol, _state(a, sol[0], sol[1], rx, ry)[1]

    def extremum(col):
        # the minimum of F (col 3) or d (col 2) over the branch, polished between the
        # neighbours of the smallest sample
        i = int(np.argmin(br[:, col]))
        i = min(max(i, 1), len(br) - 2)
        lo, hi = sorted((br[i - 1, 0], br[i + 1, 0]))
        key = (lambda a: solve_at(a)[1]) if col == 3 else (lambda a: solve_at(a)[0][1])
        return minimize_scalar(key, bounds=(lo, hi), method="bounded",
                               options=dict(xatol=1e-12 * hi)).x

    a_fc, a_dc = extremum(3), extremum(2)
    (b_fc, _), f_fc = solve_at(a_fc)
    _, f_dc = solve_at(a_dc)
    return dict(force_control=f_fc / scale, displacement_control=f_dc / scale,
                axes=(a_fc, b_fc))


def pull_off_table(ratios=(1.0, 2.0, 4.0, 10.0)) -> list[dict]:
    """Both theories at each $R_x/R_y$ in `ratios`."""
    return [dict(ratio=r, jg=pull_off("jg", r), energy=pull_off("energy", r)) for r in ratios]


def _check():
    # circular limit: JKR
    for theory in ("jg", "energy"):
        out = pull_off(theory, 1.0)
        assert abs(out["force_control"] + 1) < 1e-5, out
        assert abs(out["displacement_control"] + 5 / 9) < 1e-5, out
    # the basis: (1 - rho^2)^(1/2) = (1 - x^2/a^2 - y^2/b^2) (1 - rho^2)^(-1/2)
    a, b = 1.7, 0.6
    B = _basis(a, b)
    half = np.array(_u_half(a, b))
    assert np.allclose(B[0] - B[1] / a**2 - B[2] / b**2, half, rtol=1e-8)


if __name__ == "__main__":
    _check()
    print("ratio  JG: F_fc/(1.5 pi dg R)  F_dc   energy: F_fc  F_dc   (R = sqrt(Rx Ry))")
    for row in pull_off_table((1.0, 2.0, 4.0, 10.0)):
        a, b = row["energy"]["axes"]
        print(f"{row['ratio']:5.1f}  {row['jg']['force_control']:+.4f}  "
              f"{row['jg']['displacement_control']:+.4f}   "
              f"{row['energy']['force_control']:+.4f}  {row['energy']['displacement_control']:+.4f}"
              f"   axes at pull-off (energy) {a:.4f} {b:.4f}")
