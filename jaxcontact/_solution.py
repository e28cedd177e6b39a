"""Solution objects and result codes shared by the forward models."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["RESULTS", "ContactSolution", "is_error"]


class RESULTS(eqx.Enumeration):
    """Status of a forward simulation (one value per batch lane under `vmap`).

    `detached` and `in_contact` are successful outcomes; the others are errors, raised when
    `throw=True` and returned in `.result` when `throw=False`.
    """

    detached = "The contact detached (jump-off found within the simulated times)."
    in_contact = "The simulated history ends with the indenter still in contact."
    advancing_contact = (
        "The displacement history pushes the indenter beyond the initial contact radius; the "
        "relaxed-start model (`retract`) only describes receding contacts. Use `simulate`."
    )
    solver_failed = "The ODE solver or the root finder failed (see the solver's statistics)."
    invalid_input = "Non-finite input (NaN or inf) reached the model."


def is_error(result: RESULTS) -> Array:
    """True where `result` is an error (not `detached` nor `in_contact`)."""
    return (result != RESULTS.detached) & (result != RESULTS.in_contact)


class ContactSolution(eqx.Module):
    """The output of `retract` and `simulate`.

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
    - `jumpoff_time`: time of jump-off [s], refined between samples; `nan` if the contact
      does not detach within `ts` (then `result == RESULTS.in_contact`).
    - `jumpoff_force`: force just before jump-off [N] (`nan` if no jump-off).
    - `jumpoff_radius`: contact radius just before jump-off [m] (`nan` if no jump-off).
    - `jumpoff_displacement`: indentation at jump-off [m] (`nan` if no jump-off).
    - `result`: a `RESULTS` item.
    - `stats`: dictionary of solver statistics.
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
    result: RESULTS
    stats: dict = eqx.field(default_factory=dict)

    @property
    def detached(self) -> Array:
        """Boolean: whether the contact detached within `ts`."""
        return self.result == RESULTS.detached

    @property
    def ok(self) -> Array:
        """Boolean: no error (detached or still in contact)."""
        return jnp.logical_not(is_error(self.result))
