r"""Detachment criteria: the elastic rule of Heß and the energetic (glass-modulus) criterion.

Sign convention: elongations are magnitudes (> 0); line loads and stresses are negative in
tension (the edge of a detaching contact is under tension). All quantities in SI units.

- Elastic MDR (rule of Heß, paper eq. 4): the edge spring of a contact of radius $a$ detaches
  at the elongation $\Delta l = \sqrt{2\pi a\Delta\gamma/E^*}$ (`hess_elongation`).
- Viscoelastic MDR (energetic criterion, eqs. 10-11): only the energy stored in the instant
  (glass) spring $G_0$ of the edge element is released at detachment, so its elongation must
  reach $\Delta l_0 = \sqrt{\pi a\Delta\gamma/(2G_0)}$ (`critical_elongation`), from
  $2\pi a\,\Delta x\,\Delta\gamma = (4G_0)\,\Delta x\,\Delta l_0^2$. In the
  representation-free form the edge line load reaches
  $q_c = -4G_0\Delta l_0 = -\sqrt{8\pi a\Delta\gamma G_0}$ (`critical_line_load`), which is
  the rule of Heß with the glass value $E^* = 4G_0$.
- Boundary elements (eqs. 12-16): a square cell of side $\Delta$ carrying the stress
  $\sigma$ releases $U_{el} = \chi\,\sigma^2\Delta^3/E^*$ when it is unloaded
  (`bem_release_energy`, $\chi$ = `BEM_CHI`); equating this to $\Delta\gamma\,\Delta^2$ gives
  the critical stress $\sigma_c = -\sqrt{E^*\Delta\gamma/(\chi\Delta)}$
  (`bem_critical_stress`), with the glass value of $E^*$.

Inputs are validated with a `ValueError` when they are concrete (not under `jit`); every
function broadcasts over its arguments and is differentiable.

**The one home of the rule.** Every model evaluates the criterion through the unchecked,
trace-safe coefficients below (the public functions call them too): `hess_coefficient`
(elastic MDR, `_elastic.py`, and the profiles' front), `line_load_coefficient` (the foundation,
`_foundation/_model.py`), `relaxed_front_coefficient` (the relaxed front of `retract`,
`_pulloff.py`, and of the sweep, `_sweep/_models.py`) and `cell_critical_stress` (the BEM,
`_bem/_history.py`). Changing the criterion (attachment different from detachment, a finite range)
means changing these.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from ._solvers import float64_scope
from ._validate import check_finite, check_positive

__all__ = [
    "BEM_CHI",
    "cell_critical_stress",
    "hess_coefficient",
    "line_load_coefficient",
    "relaxed_front_coefficient",
    "bem_critical_stress",
    "bem_release_energy",
    "critical_elongation",
    "critical_line_load",
    "hess_elongation",
]

#: $\chi/\Delta^3 = \frac{2}{3\pi}\left(1 - \sqrt2 + \frac32\ln\frac{\sqrt2+1}{\sqrt2-1}\right)
#: \approx 0.473201$ (paper, eq. 13): the elastic energy released by unloading a uniformly
#: stressed unit square on a half-space, in units of $\sigma^2\Delta^3/E^*$. It equals
#: $\frac{1}{2\pi}\iint\iint_{[0,1]^2\times[0,1]^2} |\mathbf r - \mathbf r'|^{-1}$.
BEM_CHI: float = (2.0 / (3.0 * math.pi)) * (
    1.0 - math.sqrt(2.0) + 1.5 * math.log((math.sqrt(2.0) + 1.0) / (math.sqrt(2.0) - 1.0))
)


def hess_coefficient(effective_modulus, work_of_adhesion):
    r"""$c = \sqrt{2\pi\Delta\gamma/E^*}$ [m^(1/2)]: the rule of Heß (eq. 4) as the critical
    edge elongation $\Delta l(a) = c\sqrt a$ (`hess_elongation`). Unchecked, trace-safe."""
    return jnp.sqrt(2 * jnp.pi * work_of_adhesion / effective_modulus)


def line_load_coefficient(work_of_adhesion, glass_modulus):
    r"""$\sqrt{8\pi\Delta\gamma G_0}$ [N m^(-3/2)]: the energetic criterion (eqs. 10-11) as
    the critical edge line load $q_c(a) = -\sqrt{8\pi\Delta\gamma G_0}\,\sqrt a$
    (`critical_line_load`), i.e. the rule of Heß with $E^* = 4G_0$ applied to the line load
    ($q_c = -E^* c\sqrt a$). Unchecked, trace-safe."""
    return jnp.sqrt(8 * jnp.pi * work_of_adhesion * glass_modulus)


def relaxed_front_coefficient(work_of_adhesion, glass_modulus, relaxed_modulus):
    r"""$c = \sqrt{8\pi\Delta\gamma G_0}/(4G_\infty) = \sqrt{\pi\Delta\gamma G_0/2}/G_\infty$
    [m^(1/2)]: the energetic criterion on a front whose springs are relaxed (the relaxed front
    of `retract` and the sweep): the critical line load $q_c$ carried by the relaxed stiffness
    $4G_\infty$ is the elongation $c\sqrt a$, so the front is $h(a) = g(a) - c\sqrt a$
    (`_profiles.front_displacement`). Unchecked, trace-safe."""
    return line_load_coefficient(work_of_adhesion, glass_modulus) / (4 * relaxed_modulus)


def cell_critical_stress(cell_size, work_of_adhesion, effective_modulus):
    r"""$\sigma_c = -\sqrt{E^*\Delta\gamma/(\chi\Delta)}$ [Pa] (eq. 15) without the checks of
    `bem_critical_stress` (trace-safe; the BEM passes the glass $E^* = 4G_0$)."""
    return -jnp.sqrt(effective_modulus * work_of_adhesion / (BEM_CHI * cell_size))


def _check_common(radius, work_of_adhesion):
    check_positive("radius", radius, "m", allow_zero=True)
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2")


@float64_scope
def critical_elongation(
    radius: ArrayLike, work_of_adhesion: ArrayLike, glass_modulus: ArrayLike
) -> Array:
    r"""Critical elongation of the instant spring at the contact edge, eq. (11) [m].

    $$\Delta l_0 = \sqrt{\frac{\pi a \Delta\gamma}{2 G_0}}.$$

    The edge element detaches when the elongation (tension, reported as a positive
    magnitude) of its glass spring $G_0$ reaches $\Delta l_0$: only that spring's energy,
    $(4G_0)\Delta x\,\Delta l_0^2/2$ per side, is released instantly and pays for the new
    surface $2\pi a\,\Delta x\,\Delta\gamma$ (eq. 10).

    **Arguments:**

    - `radius`: contact radius $a$ [m], >= 0 (the derivative is infinite at 0).
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `glass_modulus`: glass (instant) shear modulus $G_0$ [Pa], > 0; the MDR foundation
      stiffness is $4G_0$ per unit length (incompressible).
    """
    _check_common(radius, work_of_adhesion)
    check_positive("glass_modulus", glass_modulus, "Pa")
    a, w, g0 = jnp.broadcast_arrays(radius, work_of_adhesion, glass_modulus)
    return hess_coefficient(4 * g0, w) * jnp.sqrt(a)


@float64_scope
def critical_line_load(
    radius: ArrayLike, work_of_adhesion: ArrayLike, glass_modulus: ArrayLike
) -> Array:
    r"""Critical MDR line load at the contact edge [N/m], negative (tensile).

    $$q_c = -\sqrt{8\pi a\Delta\gamma G_0} = -4G_0\,\Delta l_0.$$

    Representation-free form of the energetic criterion: the edge element detaches when the
    line load it carries reaches $q_c$ (the force in the instant spring is the force in the
    whole element). It is the elastic rule of Heß with $E^* = 4G_0$ applied to the actual
    line load.

    **Arguments:**

    - `radius`: contact radius $a$ [m], >= 0.
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `glass_modulus`: glass shear modulus $G_0$ [Pa], > 0 (for a Prony series,
      $G_\infty + \sum_k G_k$).
    """
    _check_common(radius, work_of_adhesion)
    check_positive("glass_modulus", glass_modulus, "Pa")
    a, w, g0 = jnp.broadcast_arrays(radius, work_of_adhesion, glass_modulus)
    return -line_load_coefficient(w, g0) * jnp.sqrt(a)


@float64_scope
def hess_elongation(
    radius: ArrayLike, work_of_adhesion: ArrayLike, effective_modulus: ArrayLike
) -> Array:
    r"""Rule of Heß for elastic MDR, eq. (4): critical edge elongation [m].

    $$\Delta l(a) = \sqrt{\frac{2\pi a\Delta\gamma}{E^*}},$$

    a positive magnitude; on the detachment front $w_{1D}(a) = -\Delta l(a)$, i.e.
    $d = g(a) - \Delta l(a)$ (eq. 6). For a parabola this reproduces JKR exactly.

    **Arguments:**

    - `radius`: contact radius $a$ [m], >= 0.
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `effective_modulus`: $E^*$ [Pa], > 0 ($4G$ for an incompressible half-space).
    """
    _check_common(radius, work_of_adhesion)
    check_positive("effective_modulus", effective_modulus, "Pa")
    a, w, e = jnp.broadcast_arrays(radius, work_of_adhesion, effective_modulus)
    return hess_coefficient(e, w) * jnp.sqrt(a)


@float64_scope
def bem_release_energy(
    stress: ArrayLike, cell_size: ArrayLike, effective_modulus: ArrayLike
) -> Array:
    r"""Elastic energy released when a square BEM cell is unloaded, eqs. (12)-(13) [J].

    $$U_{el} = \chi\,\frac{\sigma^2\Delta^3}{E^*}, \qquad \chi = 0.473201\ldots$$
    (`BEM_CHI`), for a uniform stress $\sigma$ on a square of side $\Delta$.

    **Arguments:**

    - `stress`: cell stress $\sigma$ [Pa], any sign (tensile negative).
    - `cell_size`: side $\Delta$ [m], > 0.
    - `effective_modulus`: $E^*$ [Pa], > 0; the glass value for the instant release.
    """
    check_finite("stress", stress, "Pa")
    check_positive("cell_size", cell_size, "m")
    check_positive("effective_modulus", effective_modulus, "Pa")
    s, d, e = jnp.broadcast_arrays(stress, cell_size, effective_modulus)
    return BEM_CHI * s**2 * d**3 / e


@float64_scope
def bem_critical_stress(
    cell_size: ArrayLike, work_of_adhesion: ArrayLike, effective_modulus: ArrayLike
) -> Array:
    r"""Critical stress of a square BEM cell at the contact edge, eq. (15) [Pa], negative.

    $$\sigma_c = -\sqrt{\frac{E^*\Delta\gamma}{\chi\,\Delta}},$$

    from $U_{el}(\sigma_c) = \Delta\gamma\,\Delta^2$ (eq. 14). A boundary cell detaches when
    its (tensile) stress reaches $\sigma_c$.

    **Arguments:**

    - `cell_size`: side $\Delta$ [m] of the square cell, > 0.
    - `work_of_adhesion`: $\Delta\gamma$ [J/m²], > 0.
    - `effective_modulus`: $E^*$ [Pa], > 0, the *glass* value (the instant release is
      elastic). For an incompressible medium $E^* = 4G_0$ with the glass shear modulus $G_0$.
    """
    check_positive("cell_size", cell_size, "m")
    check_positive("work_of_adhesion", work_of_adhesion, "J/m^2")
    check_positive("effective_modulus", effective_modulus, "Pa")
    d, w, e = jnp.broadcast_arrays(cell_size, work_of_adhesion, effective_modulus)
    return cell_critical_stress(d, w, e)
