"""Solution objects and result codes shared by the forward models."""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._validate import branched_error_if

__all__ = [
    "RESULTS",
    "BEMDetails",
    "BEMSolution",
    "ContactSolution",
    "ErrorEstimate",
    "FoundationDetails",
    "RetractDetails",
    "fold_results",
    "is_error",
    "nan_where",
    "raise_if_error",
]


class RESULTS(eqx.Enumeration):
    """Status of a forward computation (one value per batch lane under `vmap`).

    `detached`, `in_contact` and `successful` are successful outcomes; the others are
    errors, raised when `throw=True` and returned in `.result` when `throw=False` (the other
    fields of an erroneous lane are meaningless: NaN where an input is invalid). The input
    checks come first, in the order of the arguments; `implausible_input` (a value far
    outside the range of its unit, also a contact radius computed from the inputs: a
    profile so flat that the contact would be kilometres wide) can be switched off with
    `jaxcontact.plausibility_checks(False)`; `beyond_profile` (a contact radius beyond the
    profile's `valid_radius`) cannot.
    """

    detached = "The contact detached (jump-off found within the simulated times)."
    in_contact = "The simulated history ends with the indenter still in contact."
    advancing_contact = (
        "The displacement history pushes the indenter beyond the initial contact radius; the "
        "relaxed-start model (`retract`) only describes receding contacts. Use `simulate`."
    )
    solver_failed = (
        "The ODE solver or the root finder failed, or the contact outgrew the foundation "
        "grid (see the solution's `details`)."
    )
    invalid_input = "An input is NaN or inf."
    successful = "Computed successfully."
    invalid_rheology = (
        "A parameter of the rheology is outside its domain: every modulus (G0, G1, G, "
        "G_inf) [Pa] and every viscosity (eta1, eta) [Pa s] or relaxation time (tau) [s] "
        "must be finite and > 0."
    )
    invalid_profile = (
        "A parameter of the profile is outside its domain: Parabola `R` finite and > 0 [m]; "
        "Cone `half_angle` in (0, pi/2) [rad]; PowerLaw `c` finite and > 0, `n` finite and "
        "> 1/2; FlatPunch `radius` and Sphere `R` finite and > 0 [m]; Tabulated `r` [m] "
        "finite, from 0, strictly increasing, `f` [m] finite."
    )
    invalid_work_of_adhesion = "`work_of_adhesion` must be finite and > 0 [J/m^2]."
    invalid_depth = (
        "`depth` (the relaxed indentation) must be finite and > 0 [m], and for the exact "
        "`Sphere` at most `depth_limit` (1.74 R: the contact radius reaches 0.95 R)."
    )
    invalid_velocity = "`velocity` must be finite and > 0 [m/s]."
    invalid_times = (
        "`ts` [s] must be finite and non-decreasing (and >= 0 with `velocity`: t = 0 is the "
        "start of the lift)."
    )
    invalid_displacement = (
        "`displacement` [m] must be finite (and for the exact `Sphere` under displacement "
        "control at most `depth_limit`, 1.74 R)."
    )
    invalid_contact_radius = (
        "`contact_radius` must be finite, > 0 and at most the profile's `max_radius` [m]."
    )
    invalid_loading = "`CompliantLoading.stiffness` must be finite and > 0 [N/m]."
    invalid_modulus = "`effective_modulus` must be finite and > 0 [Pa]."
    invalid_radius = (
        "The contact radius `a` must be finite, >= 0 and at most the profile's `valid_radius` "
        "[m] (a Parabola's `R`, a bounded shape's edge)."
    )
    implausible_input = (
        "An input lies outside the plausible range of its unit (lengths 1e-12-1 m, moduli "
        "1e-3-1e13 Pa, viscosities 1e-6-1e25 Pa s, times 1e-12-1e12 s, work of adhesion "
        "1e-12-10 J/m^2, speeds 1e-15-1e3 m/s, spring stiffness 1e-6-1e12 N/m): probably "
        "a unit mistake (all inputs are SI). If the values are right, switch the check off "
        "with `jaxcontact.plausibility_checks(False)`."
    )
    non_finite_result = (
        "The computation produced NaN or inf although every input is finite and in its "
        "domain: overflow or underflow for inputs far outside the regime the model is built "
        "for (check the units)."
    )
    beyond_profile = (
        "The contact radius exceeds what the profile describes (`valid_radius`): the radius "
        "`R` of a Parabola, which stands for a sphere (no sphere contact reaches a > R), or "
        "the edge of a bounded shape. Indent less, or use a larger indenter."
    )


def is_error(result: RESULTS) -> Array:
    """True where `result` is an error (not `detached`, `in_contact` nor `successful`)."""
    ok = result == RESULTS.detached
    ok = ok | (result == RESULTS.in_contact)
    ok = ok | (result == RESULTS.successful)
    return jnp.logical_not(ok)


def raise_if_error(x, result: RESULTS):
    """`x` with a run-time check that raises the message of `result` where it is an error
    (`throw=True`); the check survives `jax.grad`/`jax.jacfwd` under `jit`
    (`_validate.branched_error_if`)."""
    return branched_error_if(x, is_error(result), result._value,
                             result._enumeration._index_to_message)


def nan_where(bad, sol):
    """`sol` (a `ContactSolution`) with its floating fields but `ts` NaN where `bad` (a
    lane with invalid input: no numbers that look plausible)."""

    def fill(x):
        if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating):
            return jnp.where(bad, jnp.asarray(jnp.nan, x.dtype), x)
        return x

    return eqx.tree_at(lambda s: s.ts, jax.tree_util.tree_map(fill, sol), sol.ts)


def fold_results(result: RESULTS, checks) -> RESULTS:
    """`result`, overridden by the first failing check of `checks`, a sequence of
    `(ok, RESULTS item)` pairs in order of precedence (`ok` a boolean array)."""
    for ok, item in reversed(list(checks)):
        result = RESULTS.where(ok, result, item)
    return result


class RetractDetails(eqx.Module):
    """What `retract` reports besides the curve and the events.

    **Fields:**

    - `initial_radius`: contact radius $a_0$ of the relaxed state [m].
    - `fold_radius`: radius of the fold of the receding front (jump-off under displacement
      control) [m].
    - `force_control_radius`: radius of the minimum of the force along the front [m].
    - `effective_displacement`: $d_\\mathrm{eff}(t)$ at `ts` [m] (`docs/physics.md` §4).
    - `effective_work_of_adhesion`: $\\Delta\\gamma\\,G_g/G_\\infty$ [J/m²].
    - `solver_steps`: steps of the ODE solver (`DiffraxODE`; 0 for `ExactUpdate`).
    """

    initial_radius: Float[Array, ""]
    fold_radius: Float[Array, ""]
    force_control_radius: Float[Array, ""]
    effective_displacement: Float[Array, " n"]
    effective_work_of_adhesion: Float[Array, ""]
    solver_steps: Int[Array, ""]

    def legacy_stats(self, jumpoffs) -> dict:
        """The keys of the former `ContactSolution.stats` dictionary."""
        return dict(
            fold_radius=self.fold_radius, force_control_radius=self.force_control_radius,
            initial_radius=self.initial_radius, effective_displacement=self.effective_displacement,
            effective_work_of_adhesion=self.effective_work_of_adhesion,
            num_steps=self.solver_steps,
        )


class ErrorEstimate(eqx.Module):
    """Richardson estimate of the discretisation error of `simulate` (grid with half the
    cells): `force` [N] (largest over the samples where both grids agree on being in
    contact), `relative_force` (relative to the largest |F|), `jumpoff_time` [s],
    `jumpoff_force` [N]."""

    force: Float[Array, ""]
    relative_force: Float[Array, ""]
    jumpoff_time: Float[Array, ""]
    jumpoff_force: Float[Array, ""]


class FoundationDetails(eqx.Module):
    """What `simulate` reports besides the curve and the events.

    **Fields:**

    - `cells`: number of cells of the foundation grid (static).
    - `nodes`: spring positions $x_j$ [m], shape `(cells + 1,)`; `grid_radius` the last [m].
    - `grid_overflow`: the contact outgrew the grid (then `result` is `solver_failed`).
    - `drive`: the input history at `ts` [m] (the indentation under displacement control,
      the drive position under compliant loading).
    - `final_state`: the `FoundationState` at `ts[-1]` (dashpots, edge springs, radius,
      indentation).
    - `newton_failures`: samples at which the compliant loading's Newton iteration did not
      converge without losing the contact (0 under displacement control).
    - `error_estimate`: an `ErrorEstimate` with `simulate(..., estimate_error=True)`, else
      None.
    """

    cells: int = eqx.field(static=True)
    nodes: Float[Array, " nodes"]
    grid_radius: Float[Array, ""]
    grid_overflow: Bool[Array, ""]
    drive: Float[Array, " n"]
    final_state: eqx.Module
    newton_failures: Int[Array, ""]
    error_estimate: ErrorEstimate | None = None

    def legacy_stats(self, jumpoffs) -> dict:
        """The keys of the former `ContactSolution.stats` dictionary."""
        out = dict(
            cells=jnp.asarray(self.cells), grid_radius=self.grid_radius, nodes=self.nodes,
            jumpoffs=jumpoffs, grid_overflow=self.grid_overflow, drive=self.drive,
            final_state=self.final_state, newton_failures=self.newton_failures,
        )
        e = self.error_estimate
        if e is not None:
            out.update(discretisation_error=e.force, relative_discretisation_error=e.relative_force,
                       jumpoff_time_error=e.jumpoff_time, jumpoff_force_error=e.jumpoff_force)
        return out


class BEMDetails(eqx.Module):
    """What `bem_simulate` reports besides the curve and the events.

    **Fields:**

    - `cg_iterations`: constrained-CG iterations per sample, shape `(m,)`.
    - `rounds`: rounds of the cell rule per sample, shape `(m,)`.
    - `touches_edge`: whether the contact reached the outermost cells of the grid (the grid
      is then too small; an error with `throw=True`).
    - `drive`: the input history at `ts` (the indentation [m] under displacement control,
      the drive position [m] under compliant loading, the force [N] under force control).
    """

    cg_iterations: Int[Array, " m"]
    rounds: Int[Array, " m"]
    touches_edge: Bool[Array, ""]
    drive: Float[Array, " m"]

    def legacy_stats(self, jumpoffs) -> dict:
        """The keys of the former `BEMSolution.stats` dictionary."""
        return dict(cg_iterations=self.cg_iterations, rounds=self.rounds,
                    touches_edge=self.touches_edge, drive=self.drive)


class ContactSolution(eqx.Module):
    """The output of `retract`, `simulate` and (as its subclass `BEMSolution`) `bem_simulate`.

    All per-sample arrays have the shape of `ts` (shape `(n,)`; batch dimensions in front
    under `vmap`). Sign conventions: displacement positive into the sample, force positive
    when compressive and negative when adhesive.

    **Fields:**

    - `ts`: sample times [s].
    - `displacement`: indentation depth $d(t)$ of the indenter at `ts` [m].
    - `force`: normal force $F(t)$ [N]; exactly 0 after jump-off.
    - `contact_radius`: contact radius $a(t)$ [m]; exactly 0 after jump-off.
    - `max_tensile_force`: the most negative force reached [N] (refined between samples
      where the model allows; 0 or positive if no tension was reached).
    - `jumpoff_time`: time of the first jump-off [s], refined between samples; `nan` if the
      contact does not detach within `ts` (then `result == RESULTS.in_contact`).
    - `jumpoff_force`: force just before jump-off [N] (`nan` if no jump-off).
    - `jumpoff_radius`: contact radius just before jump-off [m] (`nan` if no jump-off).
    - `jumpoff_displacement`: indentation at jump-off [m] (`nan` if no jump-off).
    - `jumpoffs`: number of jump-offs in the history (`retract`: 0 or 1).
    - `result`: a `RESULTS` item.
    - `details`: a `RetractDetails` (from `retract`), a `FoundationDetails` (from
      `simulate`) or a `BEMDetails` (from `bem_simulate`).

    With `throw=True` an error result raises whichever field is read (the check is attached
    to every array of the solution).
    """

    ts: Float[Array, " n"]
    displacement: Float[Array, " n"]
    force: Float[Array, " n"]
    contact_radius: Float[Array, " n"]
    max_tensile_force: Float[Array, ""]
    jumpoff_time: Float[Array, ""]
    jumpoff_force: Float[Array, ""]
    jumpoff_radius: Float[Array, ""]
    jumpoff_displacement: Float[Array, ""]
    jumpoffs: Int[Array, ""]
    result: RESULTS
    details: RetractDetails | FoundationDetails | BEMDetails

    @property
    def detached(self) -> Array:
        """Boolean: whether the contact detached within `ts` (and stays so at `ts[-1]`)."""
        return self.result == RESULTS.detached

    @property
    def ok(self) -> Array:
        """Boolean: no error (detached or still in contact)."""
        return jnp.logical_not(is_error(self.result))

    @property
    def stats(self) -> dict:
        """Deprecated: the former dictionary of statistics; use `details` (typed fields)
        and `jumpoffs`."""
        warnings.warn(
            f"`{type(self).__name__}.stats` is deprecated: use the typed fields `details` "
            "and `jumpoffs` (e.g. `sol.details.initial_radius`, `sol.details.cells`, "
            "`sol.details.touches_edge`).",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.details.legacy_stats(self.jumpoffs)


class BEMSolution(ContactSolution):
    """The output of `bem_simulate`: a `ContactSolution` with the BEM's fields.

    Per-sample arrays have the shape of `ts`, `(m,)`. Signs: displacement positive into the
    sample, force compressive positive, adhesive negative. The fields of `ContactSolution`
    mean here:

    - `displacement`: the indentation $d$ [m] at `ts` (the input in displacement control;
      solved in force control and with a compliant loading system). `nan` where a
      prescribed tensile force has no equilibrium (force control after the jump-off).
    - `force`: normal force $F = \\Delta^2\\sum p$ [N] carried by the contact (in force
      control the input while in contact, 0 after the jump-off).
    - `contact_radius`: equivalent radius $\\sqrt{A/\\pi}$ [m] of the contact area.
    - `max_tensile_force`: the most negative force [N] of the samples and of the last
      equilibrium before the jump-off.
    - `jumpoff_time`, `jumpoff_displacement`, `jumpoff_force`, `jumpoff_radius`: time [s],
      indentation [m], force [N] and equivalent radius [m] of the last equilibrium still in
      contact before the first jump-off (the whole contact detaching in one cascade of the
      cell rule), located by bisection of the input within the sample interval
      (`refine_steps`); `nan` if the contact did not jump off.
    - `jumpoffs`: the number of samples at which the contact was lost (it may touch again).
    - `result`: `RESULTS.detached` (a jump-off happened), `RESULTS.in_contact` or
      `RESULTS.solver_failed`.
    - `details`: a `BEMDetails` (CG iterations, cell-rule rounds, `touches_edge`, `drive`).

    **BEM fields:**

    - `contact_area`: $\\Delta^2$ times the number of cells in contact [m²].
    - `pressure`: cell pressures [Pa], shape `(m, n, n)`, if `save_fields=True`, else None.
    - `attached`: cells in contact (bonded cells with adhesion), boolean `(m, n, n)`, if
      `save_fields`, else None.

    `stats` (the former dictionary: `cg_iterations`, `rounds`, `touches_edge`, `drive`) is
    deprecated as for `ContactSolution`: use `details`.
    """

    contact_area: Float[Array, " m"]
    pressure: Float[Array, "m n n"] | None
    attached: Bool[Array, "m n n"] | None

    @property
    def detached(self) -> Array:
        """Boolean: whether the contact jumped off within `ts`."""
        return self.result == RESULTS.detached
