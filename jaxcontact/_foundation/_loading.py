"""Loading systems: how the sampled input drives the indenter (`docs/physics.md` §6)."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._root import bracketed_root, newton_root
from .._sharding import pick
from .._solvers import as_float, quadratic_at, quadratic_newton_form, quadratic_vertex, safe_div
from .._validate import Constraint
from ._events import refine_instability
from ._state import JumpOff


class SpringEquation(eqx.Module):
    r"""The equation that fixes the indentation under a loading system with a spring.

    At a sample with input $x$ the indentation $d$ solves
    $$r(d) = F(d) + k\,d - c\,x = 0,$$
    with $F(d)$ the contact force [N] (compressive positive): a spring of stiffness $k$
    between the drive $z = x$ and the indenter has $c = k$ ($k(d - z) + F = 0$,
    `CompliantLoading`); a dead load $F = x$ has $k = 0$, $c = 1$ (`ForceControl`). The one
    home of this equation: `simulate` (`CompliantLoading.step`) and `bem_simulate` solve it
    with `_root.newton_iterate`.

    **Fields:**

    - `spring`: $k$ [N/m] (or [N/m] over a force unit, see `scaled`), >= 0.
    - `gain`: $c$, the factor of the input ($k$ for a drive position [m], 1 for a force [N]).
    """

    spring: Float[Array, ""]
    gain: Float[Array, ""]

    def residual(self, force, depth, x):
        """$r = F + k d - c x$ [N] of the force `force` [N] at the indentation `depth` [m]
        for the input `x`; increasing in `depth` wherever the contact's $dF/dd > -k$.
        Evaluated as $k(d - x) + F - (c - k)x$: a spring's extension without cancellation
        (the last term vanishes for a spring, $c = k$)."""
        return self.spring * (depth - x) + force - (self.gain - self.spring) * x

    def slope(self, contact_stiffness):
        """$dr/dd = dF/dd + k$ [N/m] for the contact's stiffness $dF/dd$ [N/m]."""
        return contact_stiffness + self.spring

    def target(self, x):
        r"""$c\,x$ [N]: the force the contact carries where the indenter does not move."""
        return self.gain * x

    def scaled(self, unit):
        """The same equation with forces in units of `unit` [N] (both sides divided)."""
        return SpringEquation(self.spring / unit, self.gain / unit)


class AbstractLoading(eqx.Module):
    """How the input history drives the indenter (`docs/physics.md` §6).

    A loading system turns the sampled input into the indentation at every sample
    (`step`), bounds the indentation the grid must cover (`grid_depth`), refines the
    jump-off inside its step (`refine_jumpoff`), states the domain of its parameters
    (`domain`) and the equation that fixes the indentation (`spring_equation`, the one that
    `bem_simulate` solves). Subclasses implement all of them; `simulate` and `bem_simulate`
    call them and never ask for the type. `input_name`, `input_unit` and `input_kind` (the
    `PLAUSIBLE` kind, None: unchecked) describe the input history in messages.
    """

    input_name: ClassVar[str] = "displacement"
    input_unit: ClassVar[str] = "m"
    input_kind: ClassVar[str | None] = "length"

    @abc.abstractmethod
    def domain(self) -> tuple[Constraint, ...]:
        """The parameters and their allowed ranges (checked eagerly and per lane)."""

    @abc.abstractmethod
    def spring_equation(self) -> SpringEquation | None:
        """The `SpringEquation` that fixes the indentation at a sample, or None where the
        input is the indentation itself (displacement control)."""

    @abc.abstractmethod
    def grid_depth(self, rheology, profile, drive_max):
        """Largest indentation [m] reached for inputs up to `drive_max` [m] (before the
        grid's margin of one cell)."""

    @abc.abstractmethod
    def step(self, model, state, t0, t1, z0, z1, P, stiffness, depth):
        """Advance `state` (a `FoundationState` at `t0`) to `t1` for the input moving
        linearly from `z0` to `z1` [m]. `P`: the free-relaxation propagator of the step;
        `stiffness`: $dF/dd$ [N/m] carried from the previous sample; `depth`: the grid depth
        [m]. Returns `(new_state, out, stiffness)` with `out` a `StepOutput`."""

    @abc.abstractmethod
    def refine_jumpoff(self, model, jumpoff, pre, safe, i_j, ts, u, d, radius, force) -> JumpOff:
        """The first jump-off refined for this loading system. `jumpoff`: the `JumpOff`
        from `refine_jumpoff(model, pre)` (`valid`: the root under displacement control
        bracketed the fold); `pre`: the `StepStart` of the jump-off step (a stand-in where
        `safe` is False); `i_j`: its sample index; `ts`, `u`, `d`, `radius`, `force`: the
        sampled history."""


class DisplacementControl(AbstractLoading):
    r"""Rigid loading (default): the input is the indentation $d(t)$ [m] itself."""

    def domain(self):
        return ()

    def spring_equation(self):
        return None

    def grid_depth(self, rheology, profile, drive_max):
        return drive_max

    def step(self, model, state, t0, t1, z0, z1, P, stiffness, depth):
        new_state, out = model.step(state, t0, t1, z1, P)
        return new_state, out, stiffness

    def refine_jumpoff(self, model, jumpoff, pre, safe, i_j, ts, u, d, radius, force):
        return jumpoff


class CompliantLoading(AbstractLoading):
    r"""A spring of stiffness $k$ between the drive and the indenter (AFM cantilever).

    The input is the drive position $z(t)$ [m] (positive towards the sample, zero where the
    undeflected indenter touches the surface); the indentation follows from
    $k\,(z - d) = F$ (compressive $F$ positive), i.e. $d = z - F/k$. At every sample this
    scalar equation is solved by Newton's method on the full step (differentiated
    implicitly). The contact jumps off where its stiffness $\mathrm{d}F/\mathrm{d}d$ meets
    $-k$ (no equilibrium connected to the current one remains); the indenter then jumps to
    the free branch $d = z$. For $k \to \infty$ this is displacement control, for $k \to 0$
    force control (pull-off at the minimum of $F$; for an elastic parabola the jump-off
    force tends to $-\tfrac32\pi\Delta\gamma R$). A dead load $F(t)$ itself is not an
    input: drive a soft spring ($k$ well below the contact stiffness $8 G a$) with
    $z = F/k$; the applied force is then $F - k\,d$.

    **Arguments:**

    - `stiffness`: $k$ [N/m], > 0.
    - `newton_steps`: Newton iterations per sample (static, default 12).
    """

    stiffness: Float[Array, ""] = eqx.field(converter=as_float)
    newton_steps: int = eqx.field(static=True, default=12)

    def __check_init__(self):
        for constraint in self.domain():
            constraint.check()

    def domain(self):
        return (Constraint("stiffness", self.stiffness, "N/m", kind="stiffness"),)

    def spring_equation(self):
        return SpringEquation(self.stiffness, self.stiffness)

    def grid_depth(self, rheology, profile, drive_max):
        if profile.touch_coordinate().covers_contact:
            return drive_max
        # rounded up to 1/8 of an octave, so that the grid does not move with small
        # changes of the parameters (pass `depth` to fix it for a fit)
        bound = _compliant_depth(rheology, profile, self.stiffness, drive_max)
        tiny = jnp.finfo(jnp.result_type(bound)).tiny
        bound = jnp.exp2(jnp.ceil(8.0 * jnp.log2(jnp.maximum(bound, tiny))) / 8.0)
        return jnp.where(drive_max > 0, jnp.minimum(bound, drive_max), drive_max)

    def step(self, model, state, t0, t1, z0, z1, P, stiffness, depth):
        # k (d1 - z1) + F(d1) = 0 by Newton's method (derivatives by the implicit function
        # theorem); where it does not converge in contact the contact is taken as lost
        k = self.stiffness
        d0 = state.depth
        equation = self.spring_equation()

        def f(d1):
            return equation.residual(model.step(state, t0, t1, d1, P)[1].force, d1, z1)

        guess = d0 + (z1 - z0) * k / (k + jnp.maximum(stiffness, 0.0))
        d1 = newton_root(f, guess, steps=self.newton_steps, slope_floor=0.05 * k,
                         fallback_slope=k, tangent_floor=1e-3 * k)
        f1, df1 = jax.jvp(f, (d1,), (jnp.ones_like(d1),))
        scale = k * (jnp.abs(z1) + depth) + jnp.abs(f1 - k * (d1 - z1))
        # converged to the round-off of the residual (1e-8 in float64, 64 eps in float32)
        rtol = max(1e-8, 64 * float(jnp.finfo(scale.dtype).eps))
        converged = (jnp.abs(f1) <= rtol * scale) & (df1 > 0)
        lost = jnp.logical_not(converged) & (state.radius > 0)
        d1 = jnp.where(lost, z1, d1)
        new_state, out = model.step(state, t0, t1, d1, P, force_detach=lost)
        out = dataclasses.replace(
            out, newton_failed=jnp.logical_not(converged) & jnp.logical_not(lost)
        )
        return new_state, out, jnp.where(converged, df1 - k, 0.0)

    def refine_jumpoff(self, model, jumpoff, pre, safe, i_j, ts, u, d, radius, force):
        # The instability is the fold of the drive position along the receding front: z(a)
        # has a minimum at the critical radius (dF/dd = -k there), solved inside the step
        # (`refine_instability`). Where the step does not bracket it (the contact was lost
        # by a failure of Newton's method elsewhere), fit parabolas z(a), F(a) through the
        # last three samples in contact and take the vertex.
        j_time, j_disp, j_rad, j_force = (
            jumpoff.time, jumpoff.displacement, jumpoff.radius, jumpoff.force
        )
        refined = jumpoff.valid
        k = self.stiffness
        i_prev = jnp.maximum(i_j - 1, 0)
        inst = refine_instability(model, pre, pick(u, i_prev), pick(u, i_j), k)
        idx = jnp.maximum(i_j - jnp.arange(3, 0, -1), 0)  # i_j-3, i_j-2, i_j-1
        a3, z3, f3 = pick(radius, idx), pick(u, idx), pick(force, idx)
        usable = (i_j >= 3) & jnp.all(a3 > 0) & (a3[0] > a3[1]) & (a3[1] > a3[2])

        def parabola(y):
            # y(a) = y2 + b (a - a2) + c (a - a2)(a - a1), Newton form (nodes a2 < a1 < a0)
            return quadratic_newton_form(a3[2], a3[1], a3[0], y[2], y[1], y[0], usable)

        bz, cz = parabola(z3)
        ok_c = usable & (cz > 0)
        # vertex of z(a): dz/da = b + c (2a - a2 - a1) = 0
        a_v = quadratic_vertex(a3[2], a3[1], bz, jnp.where(ok_c, cz, 1.0))
        ok_c = ok_c & (a_v <= a3[2]) & (a_v >= a3[2] - 3 * (a3[0] - a3[2]))
        a_v = jnp.where(ok_c, a_v, a3[2])

        def at_vertex(y):
            b, c = parabola(y)
            return quadratic_at(a_v, a3[2], a3[1], y[2], b, c)

        z_v, f_v = at_vertex(z3), at_vertex(f3)
        dz = pick(u, i_j) - z3[2]
        frac = jnp.clip(safe_div(z_v - z3[2], dz), 0.0, 1.0)
        # an instability (no equilibrium left, the vertex) or the criterion itself (stiff
        # spring: the refined root as under displacement control), whichever the receding
        # front reaches first
        use_v = ok_c & (jnp.logical_not(refined) | (a_v > j_rad))
        j_time = jnp.where(
            use_v,
            jnp.where(ok_c, pick(ts, idx[2]) + frac * (pick(ts, i_j) - pick(ts, idx[2])),
                      pick(ts, i_j)),
            j_time,
        )
        j_rad = jnp.where(use_v, a_v, j_rad)
        j_force = jnp.where(use_v, jnp.where(ok_c, f_v, pick(force, idx[2])), j_force)
        j_disp = jnp.where(use_v, jnp.where(ok_c, z_v - f_v / k, pick(d, idx[2])), j_disp)
        use_i = inst.valid & safe & (i_j >= 1)
        return JumpOff(
            time=jnp.where(use_i, inst.time, j_time),
            displacement=jnp.where(use_i, inst.displacement, j_disp),
            radius=jnp.where(use_i, inst.radius, j_rad),
            force=jnp.where(use_i, inst.force, j_force),
            valid=refined | use_v | use_i,
        )


class ForceControl(AbstractLoading):
    r"""A dead load: the input is the applied force $F(t)$ [N] (compressive positive).

    The indentation is the one at which the contact carries the load. Under a tensile load
    the contact jumps off where no equilibrium connected to the current one carries it (for
    an elastic sphere at $-\tfrac32\pi\Delta\gamma R$). An input of `bem_simulate` only:
    the foundation model (`simulate`) takes a dead load as a soft spring,
    `CompliantLoading(k)` driven to $z = F/k$ with $k$ well below the contact stiffness.
    """

    input_name: ClassVar[str] = "force"
    input_unit: ClassVar[str] = "N"
    input_kind: ClassVar[str | None] = None  # a force has no plausible range of its own

    def domain(self):
        return ()

    def spring_equation(self):
        return SpringEquation(jnp.zeros(()), jnp.ones(()))

    def _foundation(self):
        raise ValueError(
            "`loading=ForceControl()` (a dead load) is an input of `bem_simulate` only; "
            "`simulate` takes a dead load F(t) as a soft spring: `CompliantLoading(k)` with "
            "the drive z = F/k and k well below the contact stiffness."
        )

    def grid_depth(self, rheology, profile, drive_max):
        self._foundation()

    def step(self, model, state, t0, t1, z0, z1, P, stiffness, depth):
        self._foundation()

    def refine_jumpoff(self, model, jumpoff, pre, safe, i_j, ts, u, d, radius, force):
        self._foundation()


def _compliant_depth(rheology, profile, stiffness, z_max):
    r"""Largest indentation reachable through a spring $k$ driven to `z_max` [m].

    On a touch-rule loading branch the viscoelastic force is at least the relaxed one,
    $F \ge F_\infty(d) = 8G_\infty(a d - \int_0^a g)$ with $g(a) = d$, so the indentation
    never exceeds the root of $d + F_\infty(d)/k = z_\max$.
    """
    G_inf = rheology.to_prony().G_inf
    k = stiffness

    def resid(d):
        a = profile.contact_radius(d)
        return d + 8.0 * G_inf * (a * d - profile.integral_g(a)) / k - z_max

    root = bracketed_root(resid, 0.0 * z_max, z_max, steps=80)
    return jnp.where(z_max > 0, root, z_max)
