r"""Elastic adhesive contact in the JKR limit by the MDR and the rule of Heß.

For an axisymmetric profile with MDR transform $g$, effective modulus $E^*$ [Pa] and work of
adhesion $\Delta\gamma$ [J/m²], the equilibrium states $(a, d, F)$ on a detachment front are
(paper eq. 4, 6 and the missing eq. 7)

$$d(a) = g(a) - \Delta l(a),\qquad \Delta l(a) = \sqrt{2\pi a\Delta\gamma/E^*},$$
$$F(a) = 2E^*\Big(a\,d(a) - \int_0^a g(x)\,\mathrm{d}x\Big).$$

With $\Delta\gamma = 0$ these are the non-adhesive (Hertz-type) relations. The critical
points solve $a\,g'(a) = k\,\Delta l(a)$ with $k = 1/2$ (minimum of $d(a)$: jump-off under
displacement control) or $k = 3/2$ (minimum of $F(a)$: pull-off under force control).

Signs: $d$ positive into the sample, $F$ positive when compressive (adhesion negative).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._profiles import AbstractProfile, Cone, FlatPunch, Parabola, PowerLaw, power_law_factor
from ._root import bracketed_root
from ._solvers import as_float
from ._validate import check_positive

__all__ = [
    "jkr_displacement",
    "jkr_force",
    "jkr_contact_radius",
    "contact_pressure",
    "pull_off",
    "PullOff",
    "profile_radius",
]


# --------------------------------------------------------------------------------------
# Small building blocks on h(a) = g(a) - c sqrt(a), c = sqrt(2 pi dgamma / E*)
# --------------------------------------------------------------------------------------


def _hess_coefficient(effective_modulus, work_of_adhesion):
    """c such that the critical elongation is c*sqrt(a) [m^(1/2)]."""
    return jnp.sqrt(2 * jnp.pi * work_of_adhesion / effective_modulus)


def _front_displacement(profile, a, c):
    return profile.g(a) - c * jnp.sqrt(a)


def _power_law_params(profile):
    """(K, n) with g(x) = K |x|^n, or None when the profile is not a power law."""
    if isinstance(profile, Parabola):
        return 1.0 / jnp.asarray(profile.R), 2.0
    if isinstance(profile, Cone):
        return 0.5 * jnp.pi / jnp.tan(profile.half_angle), 1.0
    if isinstance(profile, PowerLaw):
        return power_law_factor(profile.n) * profile.c, profile.n
    return None


def _upper_radius(profile):
    """A finite upper end for radius brackets (the profile's own, or 1 m)."""
    amax = as_float(profile.max_radius)
    return jnp.where(jnp.isfinite(amax), amax, 1.0)


def _critical_radius(profile, c, k):
    r"""Root of $a g'(a) = k c \sqrt{a}$ (k = 1/2: fold of $d(a)$; k = 3/2: minimum of $F$)."""
    if isinstance(profile, FlatPunch):
        return jnp.asarray(profile.radius) + 0.0 * c
    pl = _power_law_params(profile)
    if pl is not None:
        K, n = pl
        return (k * c / (n * K)) ** (1.0 / (n - 0.5))
    return _critical_radius_numerical(profile, c, k)


def _critical_radius_numerical(profile, c, k):
    hi = _upper_radius(profile)
    lo = hi * 1e-12

    def resid(log_a):
        a = jnp.exp(log_a)
        return a * profile.dg(a) - k * c * jnp.sqrt(a)

    log_a = bracketed_root(resid, jnp.log(lo), jnp.log(hi), steps=80)
    # no sign change at the top: the minimum sits at the edge of the shape
    return jnp.where(resid(jnp.log(hi)) < 0, hi, jnp.exp(log_a))


def profile_radius(profile: AbstractProfile, depth: Float[ArrayLike, "..."]) -> Array:
    r"""The non-adhesive MDR contact radius $a_0$ with $g(a_0) = d$ [m].

    For the flat punch this is the punch radius (any depth > 0).
    """
    depth = as_float(depth)
    if isinstance(profile, FlatPunch):
        return jnp.asarray(profile.radius) + jnp.zeros_like(depth)
    pl = _power_law_params(profile)
    if pl is not None:
        K, n = pl
        return (jnp.maximum(depth, 0.0) / K) ** (1.0 / n)
    hi = _upper_radius(profile)

    def one(d):
        return bracketed_root(lambda a: profile.g(a) - d, 0.0 * hi, hi, steps=80)

    flat = jnp.ravel(depth)
    return jax.vmap(one)(flat).reshape(depth.shape)


# --------------------------------------------------------------------------------------
# Stable branch of the detachment front: g(a) - c sqrt(a) = m with a >= fold radius
# --------------------------------------------------------------------------------------


def _rcbrt_positive(y):
    r"""$y^{-1/3}$ for positive, normal `y` (float32 or float64), to a few ulp.

    XLA's `cbrt` on the CPU is a scalar library call (~10 ns per element, against ~1 ns for
    `exp`) and dominated `retract`; and divisions or square roots whose results are used
    more than once stop XLA from fusing the element-wise chain, which then makes one pass
    over memory per intermediate. This uses multiplications only: the exponent divided by
    three on the bit pattern (shifts; initial relative error below 3.5 %), then four Newton
    steps $r \leftarrow r\,(4 - y r^3)/3$ (error $\to 2e^2$: 3e-2, 2e-3, 1e-5, 2e-10,
    round-off). Only for arguments whose cube stays in range (here $y \ge 1/16$).
    """
    y = jnp.asarray(y)
    if y.dtype == jnp.float64:
        itype, magic = jnp.int64, 0x553EF00000000000
    elif y.dtype == jnp.float32:
        itype, magic = jnp.int32, 0x54A23400
    else:
        return 1.0 / jnp.cbrt(y)
    bits = jax.lax.bitcast_convert_type(y, itype)
    # bits // 3 by shifts (bits >= 0): 1/3 = 0.010101..., exact to far below the guess error
    third = (bits >> 2) + (bits >> 4)
    for shift in (4, 8, 16, 32)[: 4 if itype == jnp.int64 else 3]:
        third = third + (third >> shift)
    r = jax.lax.bitcast_convert_type(jnp.asarray(magic, itype) - third, y.dtype)
    for _ in range(4):
        r = r * (4.0 - y * (r * r * r)) * (1.0 / 3.0)
    return r


@jax.custom_jvp
def _parabola_stable_radius(m, c, R):
    # Nondimensionalise a = lam^2 s^2 with lam^3 = c R: s^4 - s = mu = R m / lam^4.
    lam = jnp.cbrt(c * R)
    mu = R * m / lam**4
    mu_fold = -0.75 * 4.0 ** (-1.0 / 3.0)
    mu = jnp.maximum(mu, mu_fold)
    # resolvent cubic y^3 + mu y - 1/8 = 0 has one real (positive) root for mu >= mu_fold.
    # Cardano: y = u + v, u = z^(1/3), v = -mu / (3 u), z = 1/16 + sqrt(disc); u + v cancels
    # for large mu, so use y = (u^3 + v^3) / (u^2 - u v + v^2) = 1 / (8 D) with
    # D = u^2 + mu/3 + v^2 > 0. With rs = D^(-1/2): sqrt(2 y) = rs / 2, 2 / sqrt(2 y) = 4 D rs.
    # Multiplications, one cube-root reciprocal and square roots only, so that XLA fuses the
    # whole chain into one pass.
    # sqrt(disc) = sqrt(1/256 + mu^3/27); for mu > 1 as q sqrt(1 + 27/(256 mu^3)) with
    # q = mu^(3/2)/sqrt(27) and t = mu^(-1/2), so that mu^3 cannot overflow (float32: mu is
    # up to (a/a_fold)^2, 1e12 and more for weak adhesion)
    t = jax.lax.rsqrt(jnp.maximum(mu, 1.0))
    q = mu * (mu * t) * float(1.0 / np.sqrt(27.0))
    t3 = t * t * t
    sqrt_disc = jnp.where(
        mu > 1.0,
        q * jnp.sqrt(1.0 + (27.0 / 256.0) * (t3 * t3)),
        jnp.sqrt(jnp.maximum(1.0 / 256.0 + jnp.minimum(mu, 1.0) ** 3 / 27.0, 0.0)),
    )
    z = 1.0 / 16.0 + sqrt_disc
    r = _rcbrt_positive(z)
    u = z * r * r
    v = mu * r * (-1.0 / 3.0)
    D = u * u + mu * (1.0 / 3.0) + v * v
    rs = jax.lax.rsqrt(D)
    s = 0.5 * (0.5 * rs + jnp.sqrt(jnp.maximum(4.0 * D * rs - 0.25 * rs * rs, 0.0)))
    # one Newton polish away from the double root at the fold
    slope = 4.0 * s**3 - 1.0
    s = jnp.where(slope > 1e-3, s - (s**4 - s - mu) / jnp.where(slope > 1e-3, slope, 1.0), s)
    return (lam * s) ** 2


@_parabola_stable_radius.defjvp
def _parabola_stable_radius_jvp(primals, tangents):
    m, c, R = primals
    dm, dc, dR = tangents
    a = _parabola_stable_radius(m, c, R)
    sa = jnp.sqrt(a)
    dh_da = 2 * a / R - 0.5 * c / sa
    # h(a; c, R) = a^2/R - c sqrt(a) = m  =>  h_a da = dm + sqrt(a) dc + a^2/R^2 dR
    da = (dm + sa * dc + a**2 / R**2 * dR) / dh_da
    return a, da


def _stable_radius(profile, m, c, lo, hi):
    r"""Root of $g(a) - c\sqrt a = m$ on the stable branch, bracketed by `[lo, hi]`.

    `lo` is the fold radius (or larger); `hi` a radius with $h(hi) \ge m$.
    """
    if isinstance(profile, Parabola):
        return _parabola_stable_radius(m, c, as_float(profile.R))
    if isinstance(profile, Cone):
        s = 0.5 * jnp.pi / jnp.tan(profile.half_angle)
        # s sigma^2 - c sigma - m = 0, sigma = sqrt(a)
        sigma = (c + jnp.sqrt(jnp.maximum(c**2 + 4 * s * m, 0.0))) / (2 * s)
        return sigma**2
    return bracketed_root(lambda a: _front_displacement(profile, a, c) - m, lo, hi, steps=64)


# --------------------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------------------


def _check(effective_modulus, work_of_adhesion, allow_zero_adhesion=True):
    check_positive("effective_modulus", effective_modulus, "Pa")
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2", allow_zero=allow_zero_adhesion)


def jkr_displacement(
    profile: AbstractProfile,
    a: Float[ArrayLike, "..."],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
) -> Float[Array, "..."]:
    r"""Indentation on the detachment front, $d(a) = g(a) - \sqrt{2\pi a\Delta\gamma/E^*}$ [m].

    **Arguments:**

    - `profile`: the indenter.
    - `a`: contact radius [m], any shape.
    - `effective_modulus`: $E^*$ [Pa] (eq. 3; $4G$ for an incompressible half-space).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²] (0 gives the non-adhesive relation).

    **Returns:** $d$ [m], positive into the sample, with the shape of `a`.
    """
    _check(effective_modulus, work_of_adhesion)
    a = as_float(a)
    c = _hess_coefficient(effective_modulus, work_of_adhesion)
    return _front_displacement(profile, a, c)


def jkr_force(
    profile: AbstractProfile,
    a: Float[ArrayLike, "..."],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
) -> Float[Array, "..."]:
    r"""Normal force on the detachment front, $F(a) = 2E^*\,(a\,d(a) - \int_0^a g)$ [N].

    Arguments as `jkr_displacement`. Compressive force positive, adhesive negative.
    For the parabola this is the JKR force $4E^*a^3/(3R) - \sqrt{8\pi E^*\Delta\gamma a^3}$.
    """
    d = jkr_displacement(
        profile, a, effective_modulus=effective_modulus, work_of_adhesion=work_of_adhesion
    )
    a = as_float(a)
    return 2 * effective_modulus * (a * d - profile.integral_g(a))


def jkr_contact_radius(
    profile: AbstractProfile,
    displacement: Float[ArrayLike, "..."],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
) -> Float[Array, "..."]:
    r"""Contact radius on the stable branch of $d(a)$ for a given indentation [m].

    Solves $g(a) - \sqrt{2\pi a\Delta\gamma/E^*} = d$ for the larger root (the stable
    equilibrium under displacement control); differentiable by implicit differentiation.
    Where `displacement` lies below the jump-off displacement there is no equilibrium and
    the result is 0 (the contact is gone). For the flat punch the radius is the punch radius
    while attached.
    """
    _check(effective_modulus, work_of_adhesion, allow_zero_adhesion=False)
    d = as_float(displacement)
    c = _hess_coefficient(effective_modulus, work_of_adhesion)
    a_fold = _critical_radius(profile, c, 0.5)
    d_fold = _front_displacement(profile, a_fold, c)
    attached = d >= d_fold
    if isinstance(profile, FlatPunch):
        return jnp.where(attached, a_fold, 0.0)
    # safe input for detached lanes: the root at twice the fold radius
    d_safe = jnp.where(attached, d, _front_displacement(profile, 2 * a_fold, c))
    if isinstance(profile, Parabola | Cone):
        radius = _stable_radius(profile, d_safe, c, None, None)
    else:
        top = _upper_radius(profile)

        def one(m):
            # upper bracket: the first of a_fold * 2^k (capped at the profile's size) with h >= m
            cand = jnp.minimum(a_fold * 2.0 ** jnp.arange(1, 64), top)
            ok = _front_displacement(profile, cand, c) >= m
            hi = jnp.where(jnp.any(ok), cand[jnp.argmax(ok)], top)
            return _stable_radius(profile, m, c, a_fold, hi)

        radius = jax.vmap(one)(jnp.ravel(d_safe)).reshape(d.shape)
    return jnp.where(attached, radius, 0.0)


class PullOff(eqx.Module):
    """Critical state at pull-off.

    **Fields:** `radius` [m], `displacement` [m] (positive into the sample), `force` [N]
    (negative: tensile).
    """

    radius: Float[Array, ""]
    displacement: Float[Array, ""]
    force: Float[Array, ""]


def pull_off(
    profile: AbstractProfile,
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
    control: str = "displacement",
) -> PullOff:
    r"""Pull-off of an elastic adhesive contact (JKR limit, any profile).

    **Arguments:**

    - `profile`: the indenter.
    - `effective_modulus`: $E^*$ [Pa].
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `control`: `"displacement"` (rigid loading: the contact jumps off at the minimum of
      $d(a)$, $a\,g' = \Delta l/2$) or `"force"` (dead load: at the minimum of $F(a)$,
      $a\,g' = 3\Delta l/2$, the largest tensile force).

    **Returns:** a `PullOff` with radius, displacement and force at the critical point.
    For the parabola: force control $F = -\tfrac32\pi\Delta\gamma R$ at
    $a = (9\pi\Delta\gamma R^2/(8E^*))^{1/3}$; displacement control $F = -\tfrac56\pi\Delta\gamma R$
    at $a = (\pi\Delta\gamma R^2/(8E^*))^{1/3}$. For the flat punch (Kendall) both give
    $F = -\sqrt{8\pi E^*\Delta\gamma a_0^3}$. For a profile whose critical point lies
    beyond its `max_radius` the pull-off happens at `max_radius`.
    """
    _check(effective_modulus, work_of_adhesion, allow_zero_adhesion=False)
    k = {"displacement": 0.5, "force": 1.5}.get(control)
    if k is None:
        raise ValueError(f"`control` must be 'displacement' or 'force'; got {control!r}.")
    c = _hess_coefficient(effective_modulus, work_of_adhesion)
    a = _critical_radius(profile, c, k)
    d = _front_displacement(profile, a, c)
    F = 2 * effective_modulus * (a * d - profile.integral_g(a))
    return PullOff(radius=a, displacement=d, force=F)


_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(64)


def contact_pressure(
    profile: AbstractProfile,
    r: Float[ArrayLike, "..."],
    a: Float[ArrayLike, ""],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""] = 0.0,
    displacement: Float[ArrayLike, ""] | None = None,
) -> Float[Array, "..."]:
    r"""Contact pressure $p(r)$ [Pa] by the MDR back-transform (compressive positive).

    $$p(r) = \frac{E^*}{\pi}\int_r^a \frac{g'(x)}{\sqrt{x^2-r^2}}\,\mathrm{d}x
       + \frac{E^*\,(d - g(a))}{\pi\sqrt{a^2-r^2}},\qquad r < a,$$

    and 0 for $r \ge a$. The second term is the square-root singular edge term of the jump of
    the line load $q = E^*(d - g)$ at the edge (tensile on a detachment front). The integral is
    evaluated with the substitution $u = \sqrt{x^2-r^2}$ (smooth integrand $g'(x)/x$) by
    64-point Gauss–Legendre quadrature.

    **Arguments:**

    - `profile`, `effective_modulus`: as `jkr_force`.
    - `r`: radii [m] (any shape).
    - `a`: contact radius [m].
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²]; used to get $d = d(a)$ on the detachment front
      when `displacement` is not given.
    - `displacement`: indentation $d$ [m] for a contact of radius `a` off the front (e.g. a
      pinned contact); overrides `work_of_adhesion`.
    """
    r = jnp.abs(as_float(r))
    a = as_float(a)
    if displacement is None:
        displacement = jkr_displacement(
            profile, a, effective_modulus=effective_modulus, work_of_adhesion=work_of_adhesion
        )
    inside = r < a
    r_in = jnp.where(inside, r, 0.5 * a)
    umax = jnp.sqrt(a**2 - r_in**2)
    # quadrature nodes and weights on a trailing axis, of the rank of `r[..., None]`
    lead = (1,) * jnp.ndim(umax)
    nodes = jnp.reshape(jnp.asarray(_GL_NODES), lead + (-1,))
    weights = jnp.reshape(jnp.asarray(_GL_WEIGHTS), lead + (-1,))
    u = 0.5 * umax[..., None] * (nodes + 1.0)
    x = jnp.sqrt(r_in[..., None] ** 2 + u**2)
    x = jnp.maximum(x, 1e-300)
    integrand = profile.dg(x) / x
    integral = 0.5 * umax * jnp.sum(weights * integrand, axis=-1)
    edge = (displacement - profile.g(a)) / umax
    p = effective_modulus / jnp.pi * (integral + edge)
    return jnp.where(inside, p, 0.0)
