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
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._checks import (
    check_eagerly,
    constraint,
    domain,
    domain_plausibility,
    plausibility,
    traced_checks,
)
from ._criteria import hess_coefficient
from ._probes import check_depth_limit
from ._profiles import AbstractProfile, compiled_contact_radius, front_displacement
from ._solution import RESULTS, fold_results, is_error, raise_if_error
from ._solvers import as_float, cast_floats, float64_scope, float_dtype, gauss_legendre_unit
from ._validate import (
    Constraint,
    check_contact_radius,
    check_plausible,
    concrete_float,
    contact_radius_plausible,
    contact_radius_valid,
    is_concrete,
    plausibility_enabled,
    plausible,
    unchecked,
)

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
# Validation shared by the public functions
# --------------------------------------------------------------------------------------


def _modulus(value):
    return Constraint("effective_modulus", value, "Pa", kind="modulus")


def _adhesion(value, zero_ok):
    return Constraint("work_of_adhesion", value, "J/m^2", lo_open=not zero_ok,
                      kind="work_of_adhesion")


def _requirements(profile, constraints, lengths=()):
    """The `Requirement` of the profile, the scalar `constraints` and the plausibility of
    the lengths `(name, value)`, in order of precedence."""
    out = [domain(profile, RESULTS.invalid_profile)]
    out += [constraint(c, _ITEMS[c.name]) for c in constraints]
    if plausibility_enabled():
        implausible = RESULTS.implausible_input
        out.append(domain_plausibility(profile, implausible))
        out += [plausibility(c.name, c.value, c.kind, implausible)
                for c in constraints if c.kind is not None]
        out += [plausibility(name, value, "length", implausible, magnitude=True)
                for name, value in lengths]
    return out


def _eager_checks(profile, constraints, lengths=()):
    """ValueErrors for concrete inputs (domain, then plausibility of units)."""
    check_eagerly(_requirements(profile, constraints, lengths))


_ITEMS = {
    "effective_modulus": RESULTS.invalid_modulus,
    "work_of_adhesion": RESULTS.invalid_work_of_adhesion,
}


def _traced_checks(profile, constraints, lengths=()):
    """`(ok, RESULTS item)` pairs of the scalar inputs, in order of precedence."""
    return traced_checks(_requirements(profile, constraints, lengths))


def _finish(out, checks, entry_ok, entry_item, *, throw, radius=None, profile=None):
    """The status of an elementwise relation: `checks` of the scalar inputs, `entry_ok`
    (broadcastable to `out`) the check of the per-entry input (`entry_item` when it fails);
    `radius` (with its `profile`), the contact radius computed per entry, checked per entry
    against the profile's `valid_radius` (`RESULTS.beyond_profile`). `throw=True` raises on
    any failure; otherwise the failing entries (all of them for a failing scalar input) are
    NaN."""
    finite = jnp.isfinite(out)
    scalar = fold_results(RESULTS.successful, checks)
    inside = True
    if radius is not None and plausibility_enabled():  # part of the plausibility checks
        inside = jnp.logical_not(jnp.asarray(radius) > profile.valid_radius)
        entry_ok = entry_ok & inside
    result = fold_results(scalar, [
        (jnp.all(inside), RESULTS.beyond_profile),
        (jnp.all(entry_ok | jnp.logical_not(inside)), entry_item),
        (jnp.all(finite | jnp.logical_not(entry_ok)), RESULTS.non_finite_result),
    ])
    if throw:
        return raise_if_error(out, result)
    return jnp.where(jnp.logical_not(is_error(scalar)) & entry_ok & finite, out, jnp.nan)


def _check_finite_result(name, out):
    """Eager: a non-finite result from valid, concrete inputs is an overflow."""
    if not np.all(np.isfinite(np.asarray(out))):
        item = RESULTS.non_finite_result
        raise ValueError(f"{name}: {item._enumeration[item]}")


def _radius_ok(profile, a):
    return jnp.isfinite(a) & (a >= 0) & (a <= profile.valid_radius)


def _check_radius(profile, a, name="a"):
    if is_concrete(a) and is_concrete(profile):
        arr = np.ravel(np.asarray(a, dtype=float))
        amax = concrete_float(lambda: profile.valid_radius)
        good = np.isfinite(arr) & (arr >= 0) & (arr <= amax)
        if not np.all(good):
            raise ValueError(f"`{name}` (contact radius) must be finite and in [0, {amax:g}] "
                             f"[m] (the profile's `valid_radius`: a Parabola's `R`, a bounded "
                             f"shape's edge); got {arr[np.argmin(good)]}.")


def _computed_radius_checks(profile, a, *, per_entry: bool = False):
    """`(ok, RESULTS item)` of a contact radius computed from the inputs: its plausibility
    (a unit mistake: the whole call) and, unless `per_entry` (then `_finish` checks each
    entry), the profile's `valid_radius`."""
    checks = []
    if plausibility_enabled():
        checks.append((contact_radius_plausible(a), RESULTS.implausible_input))
    if not per_entry:
        checks.append((contact_radius_valid(profile, a), RESULTS.beyond_profile))
    return checks


# --------------------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------------------


@float64_scope
def profile_radius(
    profile: AbstractProfile, depth: Float[ArrayLike, "..."], *, throw: bool = True
) -> Array:
    r"""The non-adhesive MDR contact radius $a_0$ with $g(a_0) = d$ [m].

    **Arguments:** `profile`; `depth` $d$ [m], any shape, finite and >= 0; `throw`: under
    `jit`/`vmap`, raise on invalid input (default); with `False` the invalid entries are
    NaN. Concrete inputs raise `ValueError` at once.

    For the flat punch this is the punch radius (any depth).
    """
    _eager_checks(profile, ())
    Constraint("depth", depth, "m", lo_open=False).check()
    if plausibility_enabled():
        check_plausible("depth", depth, "length")
    dtype = float_dtype(profile, depth)
    profile, depth = cast_floats((profile, as_float(depth)), dtype)
    with unchecked():
        if is_concrete((profile, depth)):
            check_depth_limit("depth", profile, depth)  # (the exact sphere's, by name)
            out = compiled_contact_radius(profile, depth)
            _check_finite_result("profile_radius", out)
            check_contact_radius(profile, out, "`depth`")
            return out
        out = profile.contact_radius(depth)
        checks = _traced_checks(profile, ())
        if plausibility_enabled():
            checks.append((plausible(depth, "length"), RESULTS.implausible_input))
        depth_ok = jnp.isfinite(depth) & (depth >= 0)
        a = jnp.where(depth_ok, out, 0.0)
        checks += _computed_radius_checks(profile, jnp.where(jnp.isfinite(a), a, 0.0),
                                          per_entry=True)
        return _finish(out, checks, depth_ok, RESULTS.invalid_depth, throw=throw, radius=a,
                       profile=profile)


@float64_scope
def jkr_displacement(
    profile: AbstractProfile,
    a: Float[ArrayLike, "..."],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
    throw: bool = True,
) -> Float[Array, "..."]:
    r"""Indentation on the detachment front, $d(a) = g(a) - \sqrt{2\pi a\Delta\gamma/E^*}$ [m].

    **Arguments:**

    - `profile`: the indenter.
    - `a`: contact radius [m], any shape, in `[0, profile.max_radius]`.
    - `effective_modulus`: $E^*$ [Pa] (eq. 3; $4G$ for an incompressible half-space).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], >= 0 (0 gives the non-adhesive relation).
    - `throw`: under `jit`/`vmap`, raise on invalid input (default); with `False` the
      entries that cannot be computed are NaN. Concrete inputs raise `ValueError` at once.

    **Returns:** $d$ [m], positive into the sample, with the shape of `a`.
    """
    return _front_relation("jkr_displacement", profile, a, effective_modulus,
                           work_of_adhesion, throw, force=False)


@float64_scope
def jkr_force(
    profile: AbstractProfile,
    a: Float[ArrayLike, "..."],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
    throw: bool = True,
) -> Float[Array, "..."]:
    r"""Normal force on the detachment front, $F(a) = 2E^*\,(a\,d(a) - \int_0^a g)$ [N].

    Arguments as `jkr_displacement`. Compressive force positive, adhesive negative.
    For the parabola this is the JKR force $4E^*a^3/(3R) - \sqrt{8\pi E^*\Delta\gamma a^3}$.
    """
    return _front_relation("jkr_force", profile, a, effective_modulus, work_of_adhesion,
                           throw, force=True)


def _front_relation(name, profile, a, effective_modulus, work_of_adhesion, throw, force):
    constraints = (_modulus(effective_modulus), _adhesion(work_of_adhesion, zero_ok=True))
    _eager_checks(profile, constraints, (("a", a),))
    _check_radius(profile, a)
    dtype = float_dtype(profile, a, effective_modulus, work_of_adhesion)
    profile, a, E, w = cast_floats(
        (profile, as_float(a), as_float(effective_modulus), as_float(work_of_adhesion)), dtype
    )
    with unchecked():
        a_ok = _radius_ok(profile, a)
        a_safe = jnp.where(a_ok, a, 0.0)
        c = hess_coefficient(E, w)
        d = front_displacement(profile, a_safe, c)
        out = 2 * E * (a_safe * d - profile.integral_g(a_safe)) if force else d
        if is_concrete((profile, a, E, w)):
            _check_finite_result(name, out)
            return out
        checks = _traced_checks(profile, (_modulus(E), _adhesion(w, True)), (("a", a),))
        return _finish(out, checks, a_ok, RESULTS.invalid_radius, throw=throw)


@float64_scope
def jkr_contact_radius(
    profile: AbstractProfile,
    displacement: Float[ArrayLike, "..."],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
    throw: bool = True,
) -> Float[Array, "..."]:
    r"""Contact radius on the stable branch of $d(a)$ for a given indentation [m].

    Solves $g(a) - \sqrt{2\pi a\Delta\gamma/E^*} = d$ for the larger root (the stable
    equilibrium under displacement control); differentiable by implicit differentiation.
    Where `displacement` lies below the jump-off displacement there is no equilibrium and
    the result is 0 (the contact is gone). For the flat punch the radius is the punch radius
    while attached.

    **Arguments:** `profile`; `displacement` $d$ [m], any shape, finite; `effective_modulus`
    $E^*$ [Pa] > 0; `work_of_adhesion` $\Delta\gamma$ [J/m²] > 0; `throw` as
    `jkr_displacement` (with `False` a non-finite `displacement` gives NaN, not 0).
    """
    constraints = (_modulus(effective_modulus), _adhesion(work_of_adhesion, zero_ok=False))
    _eager_checks(profile, constraints, (("displacement", displacement),))
    Constraint("displacement", displacement, "m", lo=-np.inf).check()
    dtype = float_dtype(profile, displacement, effective_modulus, work_of_adhesion)
    profile, d, E, w = cast_floats(
        (profile, as_float(displacement), as_float(effective_modulus),
         as_float(work_of_adhesion)), dtype
    )
    with unchecked():
        c = hess_coefficient(E, w)
        a_fold = profile.critical_radius(c, 0.5)
        d_fold = front_displacement(profile, a_fold, c)
        attached = d >= d_fold
        # safe input for detached lanes: the root at twice the fold radius
        d_safe = jnp.where(attached, d, front_displacement(profile, 2 * a_fold, c))
        radius = jnp.where(attached, profile.front_radius(d_safe, c, a_fold), 0.0)
        if is_concrete((profile, d, E, w)):
            _check_finite_result("jkr_contact_radius", radius)
            check_contact_radius(profile, radius, "`displacement`")
            return radius
        checks = _traced_checks(profile, (_modulus(E), _adhesion(w, False)),
                                (("displacement", d),))
        a = jnp.where(jnp.isfinite(d), radius, 0.0)
        checks += _computed_radius_checks(profile, jnp.where(jnp.isfinite(a), a, 0.0),
                                          per_entry=True)
        return _finish(radius, checks, jnp.isfinite(d), RESULTS.invalid_displacement,
                       throw=throw, radius=a, profile=profile)


class PullOff(eqx.Module):
    """Critical state at pull-off.

    **Fields:** `radius` [m], `displacement` [m] (positive into the sample), `force` [N]
    (negative: tensile); `result`: `RESULTS.successful`, or the error (with `throw=False`;
    the other fields are then NaN).
    """

    radius: Float[Array, ""]
    displacement: Float[Array, ""]
    force: Float[Array, ""]
    result: RESULTS = eqx.field(default_factory=lambda: RESULTS.successful)


@float64_scope
def pull_off(
    profile: AbstractProfile,
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""],
    control: str = "displacement",
    throw: bool = True,
) -> PullOff:
    r"""Pull-off of an elastic adhesive contact (JKR limit, any profile).

    **Arguments:**

    - `profile`: the indenter.
    - `effective_modulus`: $E^*$ [Pa], > 0.
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `control`: `"displacement"` (rigid loading: the contact jumps off at the minimum of
      $d(a)$, $a\,g' = \Delta l/2$) or `"force"` (dead load: at the minimum of $F(a)$,
      $a\,g' = 3\Delta l/2$, the largest tensile force).
    - `throw`: under `jit`/`vmap`, raise on invalid input (default); with `False` the status
      is in `.result` (per lane) and the fields of a failed lane are NaN.

    **Returns:** a `PullOff` with radius, displacement and force at the critical point.
    For the parabola: force control $F = -\tfrac32\pi\Delta\gamma R$ at
    $a = (9\pi\Delta\gamma R^2/(8E^*))^{1/3}$; displacement control $F = -\tfrac56\pi\Delta\gamma R$
    at $a = (\pi\Delta\gamma R^2/(8E^*))^{1/3}$. For the flat punch (Kendall) both give
    $F = -\sqrt{8\pi E^*\Delta\gamma a_0^3}$. For a profile whose critical point lies
    beyond its `max_radius` the pull-off happens at `max_radius`.
    """
    k = {"displacement": 0.5, "force": 1.5}.get(control)
    if k is None:
        raise ValueError(f"`control` must be 'displacement' or 'force'; got {control!r}.")
    constraints = (_modulus(effective_modulus), _adhesion(work_of_adhesion, zero_ok=False))
    _eager_checks(profile, constraints)
    dtype = float_dtype(profile, effective_modulus, work_of_adhesion)
    profile, E, w = cast_floats(
        (profile, as_float(effective_modulus), as_float(work_of_adhesion)), dtype
    )
    with unchecked():
        c = hess_coefficient(E, w)
        a = profile.critical_radius(c, k)
        d = front_displacement(profile, a, c)
        F = 2 * E * (a * d - profile.integral_g(a))
        if is_concrete((profile, E, w)):
            _check_finite_result("pull_off", jnp.stack([a, d, F]))
            check_contact_radius(profile, a, "The pull-off (`effective_modulus`, "
                                 "`work_of_adhesion`)")
            return PullOff(radius=a, displacement=d, force=F)
        checks = _traced_checks(profile, (_modulus(E), _adhesion(w, False)))
        checks += _computed_radius_checks(profile, a)
        finite = jnp.isfinite(a) & jnp.isfinite(d) & jnp.isfinite(F)
        checks.append((finite, RESULTS.non_finite_result))
        result = fold_results(RESULTS.successful, checks)
        if throw:
            out = PullOff(radius=a, displacement=d, force=F, result=result)
            return raise_if_error(out, result)
        bad = is_error(result)
        nan = jnp.asarray(jnp.nan, dtype)
        return PullOff(radius=jnp.where(bad, nan, a), displacement=jnp.where(bad, nan, d),
                       force=jnp.where(bad, nan, F), result=result)


_GL_NODES, _GL_WEIGHTS = gauss_legendre_unit(64)  # on [0, 1]


@float64_scope
def contact_pressure(
    profile: AbstractProfile,
    r: Float[ArrayLike, "..."],
    a: Float[ArrayLike, ""],
    *,
    effective_modulus: Float[ArrayLike, ""],
    work_of_adhesion: Float[ArrayLike, ""] = 0.0,
    displacement: Float[ArrayLike, ""] | None = None,
    throw: bool = True,
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
    - `r`: radii [m] (any shape, finite).
    - `a`: contact radius [m], in `[0, profile.max_radius]`.
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], >= 0; used to get $d = d(a)$ on the
      detachment front when `displacement` is not given.
    - `displacement`: indentation $d$ [m] for a contact of radius `a` off the front (e.g. a
      pinned contact); overrides `work_of_adhesion`.
    - `throw`: as `jkr_displacement`.
    """
    constraints = (_modulus(effective_modulus), _adhesion(work_of_adhesion, zero_ok=True))
    _eager_checks(profile, constraints, (("a", a), ("r", r)))
    _check_radius(profile, a)
    Constraint("r", r, "m", lo=-np.inf).check()
    if displacement is not None:
        Constraint("displacement", displacement, "m", lo=-np.inf).check()
    dtype = float_dtype(profile, r, a, effective_modulus, work_of_adhesion, displacement)
    profile, r, a, E, w, disp = cast_floats(
        (profile, as_float(r), as_float(a), as_float(effective_modulus),
         as_float(work_of_adhesion), None if displacement is None else as_float(displacement)),
        dtype,
    )
    with unchecked():
        a_ok = _radius_ok(profile, a)
        a_safe = jnp.where(a_ok, a, 0.0)
        d = disp
        if d is None:
            d = front_displacement(profile, a_safe, hess_coefficient(E, w))
        out = _pressure(profile, jnp.abs(r), a_safe, E, d)
        if is_concrete((profile, r, a, E, w, d)):
            _check_finite_result("contact_pressure", out)
            return out
        checks = _traced_checks(profile, (_modulus(E), _adhesion(w, True)), (("a", a),))
        checks.append((jnp.all(jnp.isfinite(d)), RESULTS.invalid_displacement))
        return _finish(out, checks, a_ok & jnp.isfinite(r), RESULTS.invalid_radius,
                       throw=throw)


def _pressure(profile, r, a, effective_modulus, displacement):
    inside = r < a
    r_in = jnp.where(inside, r, 0.5 * a)
    umax = jnp.sqrt(a**2 - r_in**2)
    # quadrature nodes and weights on a trailing axis, of the rank of `r[..., None]`
    lead = (1,) * jnp.ndim(umax)
    nodes = jnp.reshape(jnp.asarray(_GL_NODES, r.dtype), lead + (-1,))
    weights = jnp.reshape(jnp.asarray(_GL_WEIGHTS, r.dtype), lead + (-1,))
    u = umax[..., None] * nodes
    x = jnp.sqrt(r_in[..., None] ** 2 + u**2)
    x = jnp.maximum(x, jnp.finfo(x.dtype).tiny)
    integrand = profile.dg(x) / x
    integral = umax * jnp.sum(weights * integrand, axis=-1)
    edge = (displacement - profile.g(a)) / umax
    p = effective_modulus / jnp.pi * (integral + edge)
    return jnp.where(inside, p, 0.0)
