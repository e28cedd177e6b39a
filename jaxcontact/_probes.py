r"""The probes of AFM practice: the exact sphere, pyramidal tips, and the validity of a contact.

- `Sphere(R)`: the exact spherical cap $f(r) = R - \sqrt{R^2 - r^2}$, whose MDR profile is
  $g(x) = x\,\operatorname{artanh}(x/R) = \frac{x}{2}\ln\frac{R+x}{R-x}$ (the non-adhesive
  solution of Sneddon 1965); `Parabola(R)` is its small-indentation limit.
- `pyramid(half_angle, sides=4, angle="face")`: a regular 3- or 4-sided pyramid as the
  axisymmetric cone that gives the same non-adhesive force (the factors of Bilodeau 1992 and
  nanite's three-sided model; `docs/physics.md` §10).
- `tabor_parameter`: Tabor's parameter of the JKR limit the model assumes.
- `profile_validity`: how far a contact radius lies inside the range where a profile is a
  faithful model of the probe it stands for.

Signs and units as everywhere: SI, indentation positive into the sample.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Float

from ._profiles import (
    AbstractCurvedProfile,
    AbstractProfile,
    Cone,
    FlatPunch,
    Parabola,
    PowerLaw,
    fold_front_radius,
    parabola_stable_radius,
)
from ._root import convex_root
from ._solvers import as_float, float64_scope
from ._validate import Constraint, concrete_float, float_field, guarded, is_concrete

__all__ = [
    "Sphere",
    "SPHERE_LIMIT",
    "PYRAMID_FACTORS",
    "pyramid",
    "pyramid_cone_angle",
    "tabor_parameter",
    "TABOR_SEPARATION",
    "ProfileValidity",
    "profile_validity",
    "PARABOLA_LIMIT",
    "depth_limit",
]

#: The largest contact radius of `Sphere`, as a fraction of $R$: at $a = 0.95R$ the
#: indentation is already $d = 1.74R$ (the contact reaches within 5 % of the equator, where
#: the surface is nearly vertical and no half-space model holds); $g$ diverges as
#: $a \to R$, so any larger radius would be an extrapolation of the geometry.
SPHERE_LIMIT = 0.95

#: Contact radius (fraction of $R$) up to which `Parabola(R)` stands for a sphere: at
#: $a = 0.3R$ the paraboloid's force at the same indentation is 0.9 % above the exact
#: sphere's (Sneddon), at $a = 0.5R$ 2.8 %, at $a = 0.9R$ 15 % (`tests/test_probes.py`).
PARABOLA_LIMIT = 0.3

#: Tabor's equilibrium separation $z_0$ [m] (the default of `tabor_parameter`): 0.3 nm, the
#: order of an interatomic distance (values of 0.2–0.5 nm are used in the literature).
TABOR_SEPARATION = 3e-10


# --------------------------------------------------------------------------------------
# The exact sphere
# --------------------------------------------------------------------------------------

@jax.custom_jvp
def _artanh(s):
    r"""$\operatorname{artanh}s = \tfrac12\log\bigl(1 + \tfrac{2s}{1-s}\bigr)$ for
    $0 \le s < 1$, within 3 ulp in float64 (XLA's `atanh` on the CPU errs by up to 128
    ulp near $s = 0.414$, 20,000 points against mpmath, as does its `log1p` of negative
    arguments; of positive ones, as here, within 2 ulp; this form is also 1.3× faster),
    with the derivative $1/((1-s)(1+s))$ (not that of the quotient)."""
    return 0.5 * jnp.log1p(2.0 * s / (1.0 - s))


@_artanh.defjvp
def _artanh_jvp(primals, tangents):
    (s,), (ds,) = primals, tangents
    return _artanh(s), ds / ((1.0 - s) * (1.0 + s))


_SERIES_TERMS = 18  # s < 0.3: s^2k <= 0.09^k, below float64 round-off after 17 terms


def _sphere_integral(s):
    r"""$J(s) = \int_0^s u\,\operatorname{artanh}u\,\mathrm{d}u$ for $0 \le s < 1$.

    Closed form $\frac{s^2-1}{2}\operatorname{artanh}s + \frac s2$, which cancels to
    $s^3/3$ for small $s$; there the series $\sum_k s^{2k+3}/((2k+1)(2k+3))$.
    """
    small = s < 0.3
    ss = jnp.where(small, s, 0.0)
    s2 = ss * ss
    series = jnp.zeros_like(ss)
    for k in reversed(range(_SERIES_TERMS)):
        series = series * s2 + 1.0 / ((2 * k + 1) * (2 * k + 3))
    series = series * s2 * ss
    sl = jnp.where(small, 0.5, s)
    closed = 0.5 * (sl * sl - 1.0) * _artanh(sl) + 0.5 * sl
    return jnp.where(small, series, closed)


#: Newton steps of the exact sphere's stationary radius (`convex_root` from the
#: paraboloid's value; worst start over roots s = x/R in [1e-8, 0.95] and every bracket
#: end: relative error 2.5e-7 after 6 steps, 3e-16 after 8)
_STATIONARY_STEPS = 8


#: Newton steps of the exact sphere's contact radius (`convex_root` from the paraboloid's
#: radius): over roots from 1e-8 R to 0.95 R, on brackets from the whole admitted range to
#: 1 % about the root, 6 steps reach the radius to 1e-15 (`tests/test_probes.py`); 5 leave
#: 8e-14, 4 2e-7
_CONTACT_STEPS = 6

#: Newton steps of the exact sphere's detachment front (`fold_root` from the paraboloid's
#: stable root): over c/sqrt(R) in [1e-7, 20] (folds from 1e-5 R to 0.94 R) and roots from
#: 1e-12 of the fold to 0.95 R, 5 steps agree with Brent's method to the root's
#: conditioning (`tests/test_probes.py`, within 0.6 of that bound); 4 miss it 1e6-fold
_FRONT_STEPS = 5


def _psi(s):
    r"""$\psi(s) = \sqrt s\,(\operatorname{artanh}s + s/(1-s^2))$ for $0 \le s < 1$: the
    exact sphere's $\sqrt x\,g'(x)/\sqrt R$ at $x = Rs$. A series
    $\sum_{k\ge1} c_k s^{k+1/2}$ with $c_k \ge 0$, $c_1 = 2$: increasing, convex, and
    $\ge 2s^{3/2}$ (the paraboloid's)."""
    return jnp.sqrt(s) * (_artanh(s) + s / ((1.0 - s) * (1.0 + s)))


def _psi_root(Q, lo, hi):
    r"""$s \in [\mathrm{lo}, \mathrm{hi}]$ with $\psi(s) = Q$ (`_psi`; the stationary and
    critical radii of the exact sphere over $R$): `convex_root` from the paraboloid's
    $(Q/2)^{2/3}$, which lies at or right of the root ($\psi \ge 2s^{3/2}$); derivatives
    with respect to $Q$ by implicit differentiation."""
    return convex_root(lambda s: _psi(s) - Q, (0.5 * lax.stop_gradient(Q)) ** (2.0 / 3.0),
                       lo, hi, steps=_STATIONARY_STEPS)


class Sphere(AbstractCurvedProfile):
    r"""Exact sphere of radius $R$: $f(r) = R - \sqrt{R^2 - r^2}$ for $r \le R$.

    **Arguments:**

    - `R`: the sphere's radius [m], > 0.

    MDR profile (Sneddon 1965): $g(x) = x\,\operatorname{artanh}(x/R)
    = \frac x2\ln\frac{R+x}{R-x}$, $g'(x) = \operatorname{artanh}(x/R) + \frac{xR}{R^2-x^2}$,
    $\int_0^a g = \frac{a^2-R^2}{2}\operatorname{artanh}(a/R) + \frac{aR}{2}$, so that the
    non-adhesive force is $F = E^*[(a^2+R^2)\operatorname{artanh}(a/R) - aR]$. For
    $a \ll R$ it is `Parabola(R)` ($g = a^2/R + a^4/(3R^3) + \dots$).

    **Limit.** $g$ diverges as $a \to R$ (the contact cannot reach the equator at a finite
    indentation). Contact radii are admitted up to `max_radius` $= 0.95R$ (`SPHERE_LIMIT`;
    indentation $d \le 1.74R$). Beyond it `g`, `dg`, `integral_g` and `contact_radius` are
    $+\infty$: the entry functions report a non-finite result (`RESULTS.non_finite_result`
    per lane, or an error), never an extrapolated number; `contact_radius` with concrete
    values raises a `ValueError` naming the depth. `shape` is the geometric cap up to $r = R$
    ($+\infty$ beyond: never touched in a BEM height map).

    The radii of the contact models are Newton iterations of a fixed number of steps from
    the paraboloid's closed forms, which lie at or right of the sphere's roots ($g \ge
    a^2/R$): `contact_radius` ($g(a) = d$) and `critical_radius` ($\sqrt a\,g'(a) = kc$)
    on convex increasing functions (`convex_root`), `front_radius` ($g(a) - c\sqrt a = m$)
    on the square root of the rise above the fold (`fold_root`), each step count the
    measured worst case to round-off; no loop under `vmap`, where a loop runs every lane
    to the slowest. All differentiable by implicit differentiation.
    """

    R: Float[Array, ""] = eqx.field(converter=float_field("R", "m"))

    def domain(self):
        return (Constraint("R", self.R, "m", kind="length"),)

    def _inside(self, x):
        """`(|x|/R where admitted else 0, admitted)`."""
        ax = jnp.abs(as_float(x))
        ok = ax <= SPHERE_LIMIT * self.R
        return jnp.where(ok, ax / self.R, 0.0), ok

    @guarded
    def shape(self, r):
        ar = jnp.abs(as_float(r))
        ok = ar <= self.R
        rs = jnp.where(ok, ar, 0.0)
        # R - sqrt(R^2 - r^2) without cancellation
        out = rs * rs / (self.R + jnp.sqrt((self.R - rs) * (self.R + rs)))
        return jnp.where(ok, out, jnp.inf)

    @guarded
    def g(self, x):
        s, ok = self._inside(x)
        return jnp.where(ok, self.R * s * _artanh(s), jnp.inf)

    @guarded
    def dg(self, x):
        s, ok = self._inside(x)
        return jnp.where(ok, _artanh(s) + s / ((1.0 - s) * (1.0 + s)), jnp.inf)

    @guarded
    def integral_g(self, a):
        s, ok = self._inside(a)
        return jnp.where(ok, jnp.sign(as_float(a)) * self.R**2 * _sphere_integral(s), jnp.inf)

    @property
    @guarded
    def max_radius(self):
        return SPHERE_LIMIT * self.R

    def _depth_limit(self):
        s = SPHERE_LIMIT
        return self.R * s * math.atanh(s)

    def contact_radius(self, depth, *, lo=None, hi=None):
        # g is increasing and convex on [0, max_radius], and the paraboloid's radius
        # sqrt(R d) lies at or right of the root (g >= a^2/R): `convex_root`, a fixed number
        # of Newton steps (no loop under `vmap`, where one runs every lane to the slowest)
        depth = as_float(depth)
        top = self.max_radius
        bracketed = lo is not None or hi is not None
        if not bracketed:
            check_depth_limit("depth", self, depth)
        lo = jnp.zeros_like(depth) if lo is None else jnp.clip(lo, 0.0, top)
        hi = top if hi is None else jnp.clip(hi, 0.0, top)
        pos = depth > 0
        d = jnp.where(pos, depth, 1.0)  # (no tangent from the root where the depth is not)
        start = jnp.sqrt(lax.stop_gradient(self.R) * lax.stop_gradient(d))
        a = convex_root(lambda a: self.g(a) - d, start, lo, hi, steps=_CONTACT_STEPS)
        a = jnp.where(pos, a, lo)
        # beyond the admitted depth: +inf (the bracket's end inside the foundation's cells)
        return a if bracketed else jnp.where(depth <= self._depth_limit(), a, jnp.inf)

    def critical_radius(self, c, k):
        # a g'(a) = k c sqrt(a)  <=>  psi(s) = k c / sqrt(R) at s = a/R (`_psi`)
        c = as_float(c)
        Q = k * c / jnp.sqrt(self.R)
        pos = Q > 0
        s = _psi_root(jnp.where(pos, Q, 1.0), 0.0, SPHERE_LIMIT)
        return jnp.where(pos, self.R * s, 0.0)

    def front_radius(self, m, c, lo, hi=None):
        # the root right of the fold `lo` by `fold_root` from the paraboloid's stable root
        # (closed form, `parabola_stable_radius`; h >= the paraboloid's, so it lies at or
        # right of the sphere's root, by ~ s^2/3 of the radius, s = a/R)
        top = self.max_radius if hi is None else jnp.minimum(hi, self.max_radius)
        R = lax.stop_gradient(self.R)
        c_start = lax.stop_gradient(as_float(c))
        return fold_front_radius(self, m, c, lo, top,
                                 lambda mm: parabola_stable_radius(mm, c_start, R),
                                 steps=_FRONT_STEPS)

    def stationary_radius(self, q, lo, hi):
        # sqrt(x) g'(x) = q  <=>  psi(s) = q / sqrt(R) at s = x / R (`_psi`); psi >= 2 s^1.5,
        # so the paraboloid's root (q / (2 sqrt R))^(2/3) lies at or right of the sphere's
        R = lax.stop_gradient(self.R)
        Q = jnp.maximum(lax.stop_gradient(as_float(q)), 0.0) / jnp.sqrt(R)
        s_lo = jnp.clip(lax.stop_gradient(lo), 0.0, SPHERE_LIMIT * R) / R
        s_hi = jnp.clip(lax.stop_gradient(hi), 0.0, SPHERE_LIMIT * R) / R
        return R * _psi_root(Q, s_lo, s_hi)


# --------------------------------------------------------------------------------------
# Pyramids as equivalent cones
# --------------------------------------------------------------------------------------

#: Non-adhesive force of a regular pyramid, $F = k\,E^*\tan\alpha\,d^2$ with $\alpha$ the
#: half-angle to the face: 4 sides, Bilodeau (1992), $k = 1.4906/2$; 3 sides, nanite's
#: three-sided model (`hertz_pyr3s`, also citing Bilodeau 1992), $k = 0.8887$.
PYRAMID_FACTORS = {4: 0.7453, 3: 0.8887}


@float64_scope
def pyramid_cone_angle(half_angle, sides: int = 4, angle: str = "face") -> float:
    r"""The half-opening angle [rad] of the cone equivalent to a regular pyramid.

    **Arguments:**

    - `half_angle`: the pyramid's half-angle [rad] in (0, π/2), between the axis and a face
      (`angle="face"`, the angle $\alpha$ of Bilodeau and nanite) or an edge
      (`angle="edge"`); for a regular $n$-sided pyramid
      $\tan\alpha_\mathrm{face} = \cos(\pi/n)\tan\alpha_\mathrm{edge}$.
    - `sides`: 3 or 4.

    **Returns:** $\psi$ with $\tan\psi = \frac\pi2\,k_n\tan\alpha_\mathrm{face}$, so that the
    cone's force $\frac2\pi E^*\tan\psi\,d^2$ is the pyramid's $k_n E^*\tan\alpha\,d^2$
    (`PYRAMID_FACTORS`).
    """
    if sides not in PYRAMID_FACTORS:
        raise ValueError(f"`sides` must be 3 or 4; got {sides!r}.")
    if angle not in ("face", "edge"):
        raise ValueError(f"`angle` must be 'face' or 'edge'; got {angle!r}.")
    alpha = float(half_angle)
    if not (math.isfinite(alpha) and 0.0 < alpha < math.pi / 2):
        raise ValueError(f"`half_angle` must lie in (0, pi/2) [rad]; got {half_angle!r}.")
    tan_face = math.tan(alpha) * (math.cos(math.pi / sides) if angle == "edge" else 1.0)
    return math.atan(0.5 * math.pi * PYRAMID_FACTORS[sides] * tan_face)


@float64_scope
def pyramid(half_angle, sides: int = 4, angle: str = "face") -> Cone:
    r"""A regular 3- or 4-sided pyramidal tip as its axisymmetric equivalent `Cone`.

    The MDR (and every model here) needs an axisymmetric profile; a pyramid is replaced by
    the cone with the same non-adhesive force–indentation relation (`pyramid_cone_angle`:
    Bilodeau 1992 for four sides, nanite's three-sided model). Adhesion and viscoelasticity
    then act on that cone. Arguments as `pyramid_cone_angle` (`half_angle` [rad]).
    """
    return Cone(half_angle=pyramid_cone_angle(half_angle, sides, angle))


# --------------------------------------------------------------------------------------
# Validity: the JKR limit and the profile's range
# --------------------------------------------------------------------------------------


@float64_scope
def tabor_parameter(
    radius: Float[ArrayLike, "..."],
    work_of_adhesion: Float[ArrayLike, "..."],
    effective_modulus: Float[ArrayLike, "..."],
    equilibrium_separation: Float[ArrayLike, "..."] = TABOR_SEPARATION,
) -> Array:
    r"""Tabor's parameter $\mu = \left(R\,\Delta\gamma^2/(E^{*2} z_0^3)\right)^{1/3}$ [1].

    The ratio of the elastic neck at the edge of an adhesive contact to the range of the
    surface forces. The models here are in the JKR limit (forces of vanishing range), which
    holds for large $\mu$ (≳ 3–5); for $\mu \lesssim 1$ the contact is DMT-like and the
    energetic criterion overestimates the adhesive neck (Maugis–Dugdale in between).

    **Arguments** (broadcast together):

    - `radius`: the probe's radius of curvature $R$ [m], > 0 (a sphere's or paraboloid's $R$;
      for a cone or pyramid the radius of its rounded apex).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], >= 0.
    - `effective_modulus`: $E^*$ [Pa], > 0. For this model's incompressible half-space
      $E^* = 4G$; use the **glass** modulus, $E^* = 4G_g$ (`G0` of the standard model,
      $G_\infty + \sum G_k$ of a Prony series): the detachment criterion acts with the glass
      modulus (`docs/physics.md` §3), the neck at the moving front responds instantly. (With
      the relaxed modulus $\mu$ is larger by $(G_g/G_\infty)^{2/3}$: a glass-modulus $\mu$ is
      the conservative one.)
    - `equilibrium_separation`: $z_0$ [m], > 0; default 0.3 nm (`TABOR_SEPARATION`).

    **Returns:** $\mu$, the broadcast shape of the inputs. Concrete invalid inputs raise
    `ValueError`; traced ones give NaN.
    """
    names = (("radius", radius, "m", False), ("work_of_adhesion", work_of_adhesion, "J/m^2", True),
             ("effective_modulus", effective_modulus, "Pa", False),
             ("equilibrium_separation", equilibrium_separation, "m", False))
    ok = jnp.asarray(True)
    for name, value, unit, zero_ok in names:
        c = Constraint(name, value, unit, lo_open=not zero_ok)
        c.check()
        ok = ok & c.ok()
    R, w, E, z0 = (as_float(v) for _, v, _, _ in names)
    mu = jnp.cbrt(R * w * w / (E * E * z0**3))
    return jnp.where(ok, mu, jnp.nan)


@float64_scope
def depth_limit(profile: AbstractProfile) -> Array:
    r"""The largest indentation [m] that `profile` admits: for `Sphere(R)`
    $g(0.95R) = 0.95R\operatorname{artanh}(0.95) = 1.74R$ (`SPHERE_LIMIT`), `inf` for every
    other profile. `retract` and `simulate` (displacement control) reject a deeper
    indentation: `ValueError` for concrete inputs, `RESULTS.invalid_depth` /
    `RESULTS.invalid_displacement` per lane."""
    if isinstance(profile, Sphere):
        return profile._depth_limit()
    return jnp.asarray(jnp.inf)


def check_depth_limit(name: str, profile: AbstractProfile, depth) -> None:
    """Eager: `ValueError` if a concrete `depth` [m] (any shape) exceeds `depth_limit`."""
    if not isinstance(profile, Sphere) or not is_concrete((profile, depth)):
        return
    d = float(np.max(np.asarray(depth, dtype=float)))
    limit = concrete_float(lambda: depth_limit(profile))
    if d > limit:
        raise ValueError(
            f"`{name}` reaches {d:g} m, beyond the limit of the exact sphere "
            f"(R = {float(profile.R):g} m): {limit:g} m, where the contact radius reaches "
            f"{SPHERE_LIMIT} R (`SPHERE_LIMIT`); nearer the equator no half-space model holds."
        )


class ProfileValidity(eqx.Module):
    r"""Where a contact radius lies in the range of a profile.

    **Fields:**

    - `limit`: the largest contact radius [m] at which the profile is a faithful model of
      the probe it stands for (`inf` where there is none); see `profile_validity`.
    - `fraction`: `contact_radius / limit` [1] (0 where the limit is infinite); above 1 the
      contact is outside the profile's validity.
    - `valid`: `fraction <= 1` (boolean array).
    - `reason`: what the limit is (a string, the same for every entry).
    """

    limit: Array
    fraction: Array
    valid: Array
    reason: str = eqx.field(static=True)


@float64_scope
def profile_validity(profile: AbstractProfile, contact_radius) -> ProfileValidity:
    r"""How far `contact_radius` [m] (any shape) lies inside the profile's validity.

    The limits:

    - `Parabola(R)`: $0.3R$ (`PARABOLA_LIMIT`): the paraboloid stands for a sphere; beyond,
      use `Sphere(R)`.
    - `Sphere(R)`: its `max_radius`, $0.95R$ (`SPHERE_LIMIT`).
    - `FlatPunch`, `Tabulated`: `max_radius` (the punch, the end of the table: a larger
      contact is an extrapolation).
    - `Cone`, `PowerLaw` (and cones standing for pyramids): no limit of the shape (`inf`).
      A real tip is rounded at the apex and ends at its height; check those separately.

    **Returns:** a `ProfileValidity`.
    """
    if not isinstance(profile, AbstractProfile):
        raise TypeError(f"`profile` must be an AbstractProfile; got {type(profile).__name__}.")
    a = as_float(contact_radius)
    if isinstance(profile, Parabola):
        limit = PARABOLA_LIMIT * profile.R
        reason = (f"beyond {PARABOLA_LIMIT} R the paraboloid departs from a sphere "
                  "(use the exact Sphere)")
    elif isinstance(profile, Sphere):
        limit = profile.max_radius
        reason = (f"the exact sphere is admitted up to {SPHERE_LIMIT} R (near the equator no "
                  "half-space model holds)")
    elif isinstance(profile, Cone | PowerLaw):
        limit = jnp.asarray(jnp.inf, a.dtype)
        reason = "no limit of the shape"
    elif isinstance(profile, FlatPunch):
        limit = profile.max_radius
        reason = "the punch's radius"
    else:
        limit = profile.max_radius
        reason = "the profile's max_radius (beyond it: extrapolated)"
    limit = as_float(limit)
    fraction = jnp.where(jnp.isfinite(limit), a / jnp.where(jnp.isfinite(limit), limit, 1.0),
                         0.0)
    return ProfileValidity(limit=limit, fraction=fraction, valid=fraction <= 1.0,
                           reason=reason)
