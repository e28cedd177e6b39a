"""Typed state of the discretised foundation (what flows through the history loop)."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Bool, Float


class FoundationState(eqx.Module):
    """State of the discretised foundation at one time.

    **Fields:**

    - `nodes`: dashpot displacements $v_{jk}$ of the springs at the nodes [m], shape
      `(n_nodes, N)` (N Maxwell arms).
    - `edge`: the two sides of the contact edge [m], shape `(2, N)`: `edge[0]` the attached
      edge spring at $a^-$, `edge[1]` the free spring at $a^+$ (they differ while the edge
      is pinned).
    - `radius`: contact radius $a$ [m] (0 out of contact).
    - `depth`: indentation $d$ [m].
    """

    nodes: Float[Array, "nodes arms"]
    edge: Float[Array, "2 arms"]
    radius: Float[Array, ""]
    depth: Float[Array, ""]


class StepStart(eqx.Module):
    """A sample interval and the state at its start (what the in-step refinements need).

    **Fields:** `nodes` `(n_nodes, N)` and `edge_spring` `(N,)` (the attached edge spring)
    [m], `radius` $a$ [m] at `t0`; the interval `t0`, `t1` [s]; the indentation `d0`, `d1`
    [m] at its ends (linear in between).
    """

    nodes: Float[Array, "nodes arms"]
    edge_spring: Float[Array, " arms"]
    radius: Float[Array, ""]
    t0: Float[Array, ""]
    t1: Float[Array, ""]
    d0: Float[Array, ""]
    d1: Float[Array, ""]


class StepBranch(eqx.Module):
    r"""The end of one branch of a step (pinned, advancing or receding edge).

    **Fields:** `inner`, `outer` [m]: the nodes at $x$ < `inner` were attached over the whole
    step, those at `inner` $\le x <$ `outer` were swept by the front during it and end at
    `swept` `(n_nodes, N)` [m] (read there only), the others were free (pinned: `inner` =
    `outer` = $a$; advancing: $a$ and the new radius; receding: the new radius and $a$);
    `edge` `(2, N)` [m] and `radius` [m] at the end of the step; `jumped` (the contact
    jumped off in the step); `theta_jump` (the step fraction of that jump-off from the
    criterion, `nan` without); `overflow` (the contact outgrew the grid).
    """

    inner: Float[Array, ""]
    outer: Float[Array, ""]
    swept: Float[Array, "nodes arms"]
    edge: Float[Array, "2 arms"]
    radius: Float[Array, ""]
    jumped: Bool[Array, ""]
    theta_jump: Float[Array, ""]
    overflow: Bool[Array, ""]


class StepEnd(eqx.Module):
    """The state at the end of a step and its events: `nodes` `(n_nodes, N)`, and the
    fields of `StepBranch` after `swept`."""

    nodes: Float[Array, "nodes arms"]
    edge: Float[Array, "2 arms"]
    radius: Float[Array, ""]
    jumped: Bool[Array, ""]
    theta_jump: Float[Array, ""]
    overflow: Bool[Array, ""]


class JumpOff(eqx.Module):
    """A jump-off located inside a step.

    **Fields:** `time` [s], `displacement` (indentation) [m], `radius` [m], `force` [N];
    `valid`: the step brackets the event (else the values are a stand-in).
    """

    time: Float[Array, ""]
    displacement: Float[Array, ""]
    radius: Float[Array, ""]
    force: Float[Array, ""]
    valid: Bool[Array, ""]


class StepOutput(eqx.Module):
    """What one step reports besides the new state.

    **Fields:** `force` $F$ [N], `radius` $a$ [m] and `depth` (indentation) $d$ [m] at the
    end of the step; `jumped`
    (the contact jumped off in the step); `theta_jump` (the step fraction of the jump-off
    estimated from the criterion, `nan` without jump-off); `ok` (the ODE solver succeeded);
    `overflow` (the contact outgrew the grid); `newton_failed` (compliant loading: Newton's
    method did not converge at this sample).
    """

    force: Float[Array, ""]
    radius: Float[Array, ""]
    depth: Float[Array, ""]
    jumped: Bool[Array, ""]
    theta_jump: Float[Array, ""]
    ok: Bool[Array, ""]
    overflow: Bool[Array, ""]
    newton_failed: Bool[Array, ""]


class Cells(eqx.Module):
    r"""Linear-in-$\zeta$ representation of $s = v + g$ on the contact side, per cell
    $j$ = $[x_j, \min(x_{j+1}, a)]$: arrays of shape `(n_nodes,)` or `(n_nodes, N)`.

    **Fields:** `valid` ($x_j < a$), `up_node` (the cell ends at node $j+1$, not at the
    front), `x_lo`, `x_hi` [m] and `z_lo`, `z_hi`, `dz` (in $\zeta$) the cell's ends,
    `s_lo`, `s_hi` [m] $s$ at the ends, `slope` $ds/d\zeta$, and the criterion inside the
    cell, $R(x) = \alpha_j - \beta_j\zeta(x) + c\sqrt x$: `alpha`, `beta`, `R_nodes`
    ($R$ at $x_j$) [N/m].
    """

    valid: Bool[Array, " nodes"]
    up_node: Bool[Array, " nodes"]
    x_lo: Float[Array, " nodes"]
    x_hi: Float[Array, " nodes"]
    z_lo: Float[Array, " nodes"]
    z_hi: Float[Array, " nodes"]
    dz: Float[Array, " nodes"]
    s_lo: Float[Array, "nodes arms"]
    s_hi: Float[Array, "nodes arms"]
    slope: Float[Array, "nodes arms"]
    alpha: Float[Array, " nodes"]
    beta: Float[Array, " nodes"]
    R_nodes: Float[Array, " nodes"]


class _MinimumPair(eqx.Module):
    """The states at the start and at the end of the step with the lowest sampled force
    (their in-step dense output refines the largest tensile force)."""

    nodes_before: Float[Array, "nodes arms"]
    edge_before: Float[Array, " arms"]
    radius_before: Float[Array, ""]
    nodes_at: Float[Array, "nodes arms"]
    edge_at: Float[Array, " arms"]
    radius_at: Float[Array, ""]


class _Carry(eqx.Module):
    """Carry of the history loop (`lax.scan` over the samples)."""

    state: FoundationState
    jumpoff_step: StepStart  # the step of the first jump-off (a stand-in until found)
    found: Bool[Array, ""]
    stiffness: Float[Array, ""]  # dF/dd at the last sample (compliant Newton guess)
    min_pair: _MinimumPair
    min_force: Float[Array, ""]
