"""The foundation model: constants, cells of the attached side, criterion, one step."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from .. import _sharding
from .._arms import arms_apply, arms_sum, attached_update
from .._criteria import line_load_coefficient
from .._method import AbstractMethod
from .._profiles import TouchCoordinate
from .._root import concave_root
from .._sharding import pick
from .._solvers import safe_div
from ._state import Cells, FoundationState, StepBranch, StepEnd, StepOutput

_ROOT_STEPS = 16
#: the receding front's first Newton iterations written out (`concave_root(unrolled=)`):
#: a step takes ~2.5 on average; the history objective's Jacobian 3-6 % faster with 3
_ROOT_UNROLLED = 3
#: at most this many nodes swept by the front in a step are updated alone
#: (`_Model._swept_springs`; more: every node)
_SWEPT_NODES = 2


def _upper_weight(h, dz, num):
    r"""The weight of a cell's upper end in $\int S\,dx$ over the cell, for $S$ linear in
    $\zeta$: $\int (\zeta - \zeta_\mathrm{lo})\,dx / \Delta\zeta$ = `num / dz` (`num`:
    $\int\zeta\,dx - \zeta_\mathrm{lo} h$), the trapezoid's $h/2$ where $\Delta\zeta = 0$;
    the lower end's is $h$ minus it. Shapes broadcast."""
    pos = dz > 0
    return jnp.where(pos, num / jnp.where(pos, dz, 1.0), 0.5 * h)


class _Model(eqx.Module):
    r"""The constants of one simulation of the foundation model and its step (built inside
    the traced function, closed over by the loop); the in-step events are the functions of
    `._events` over it.

    **Fields** (arrays in the simulation's precision):

    - `Gi`, `Gk`, `tau`: the relaxation form $G_\infty$ [Pa], $G_k$ [Pa] and $\tau_k$ [s],
      shape `(N,)` (an elastic rheology: one inert arm, $G_1 = 0$, $\tau_1 = 1$);
    - `Gg`: the glass modulus $G_g = G_\infty + \sum_k G_k$ [Pa]; `arm_ratio`: $G_k/G_g$;
      `A`: the load-free springs' rate matrix $\mathrm{diag}(1/\tau)(\mathbf 1 r^\top - I)$
      [1/s], shape `(N, N)`;
    - `c`: the energetic criterion's coefficient: an edge at $x$ holds while its line load
      $q \ge -c\sqrt x$ (`line_load_coefficient`);
    - `geo`: the profile's `TouchCoordinate`; `Gi_g`: the elastic part of beta,
      $4G_\infty g(x)$'s weight;
    - `x`: the grid's nodes [touch coordinate], shape `(n_nodes,)`; `n_nodes` (static);
      `L`: the last node; `gx`, `zx`, `Zx`: $g$, $\zeta$ and $\int\zeta$ at the nodes;
      `x_next`, `z_next`: $x$ and $\zeta$ at the next node (the last: $\infty$ and
      repeated);
    - `w_lo`, `w_hi`: the weights of a whole cell $[x_j, x_{j+1}]$ in the force integral,
      $\int_{x_j}^{x_{j+1}} S\,dx = w_{\mathrm{lo},j} S_j + w_{\mathrm{hi},j} S_{j+1}$ for
      $S$ linear in $\zeta$ (`force`); `w_hi` shifted by one node (the weight of node
      $j$ as the upper end of cell $j-1$; 0 at node 0), both 0 at the last node;
    - `method`: the `AbstractMethod` of the dashpots' update.
    """

    Gi: Array
    Gk: Array
    tau: Array
    Gg: Array
    arm_ratio: Array
    A: Array
    c: Array
    geo: TouchCoordinate
    Gi_g: Array
    x: Array
    n_nodes: int = eqx.field(static=True)
    L: Array
    gx: Array
    zx: Array
    Zx: Array
    x_next: Array
    z_next: Array
    w_lo: Array
    w_hi: Array
    method: AbstractMethod

    def __init__(self, rheology, profile, work_of_adhesion, x_nodes, method):
        prony = rheology.to_prony()
        Gi = prony.G_inf
        Gk = jnp.atleast_1d(prony.G)
        tau = jnp.atleast_1d(prony.tau)
        if Gk.shape[0] == 0:  # elastic: one inert arm keeps the shapes non-empty
            Gk = jnp.zeros((1,), dtype=Gi.dtype)
            tau = jnp.ones((1,), dtype=Gi.dtype)
        self.Gi, self.Gk, self.tau = Gi, Gk, tau
        self.Gg = Gi + jnp.sum(Gk)
        self.arm_ratio = Gk / self.Gg
        self.A = (self.arm_ratio[None, :] - jnp.eye(Gk.shape[0], dtype=Gi.dtype)) / tau[:, None]
        # the energetic criterion: an edge at x holds while its line load q >= -c sqrt(x)
        self.c = line_load_coefficient(work_of_adhesion, self.Gg)
        self.geo = profile.touch_coordinate()
        # the elastic part of beta: 4 G_inf g(x) (absent for the flat punch, where g = 0)
        self.Gi_g = Gi * self.geo.g_weight
        self.x = x_nodes
        self.n_nodes = x_nodes.shape[0]
        self.L = x_nodes[-1]
        self.gx = self.geo.g(x_nodes)
        self.zx = self.geo.zeta(x_nodes)
        self.Zx = self.geo.zeta_integral(x_nodes)
        inf = jnp.full((1,), jnp.inf, dtype=x_nodes.dtype)
        self.x_next = jnp.concatenate([x_nodes[1:], inf])
        self.z_next = jnp.concatenate([self.zx[1:], self.zx[-1:]])
        # a whole cell's weights in the force integral (`_upper_weight`), fixed by the grid
        h = x_nodes[1:] - x_nodes[:-1]
        w_up = _upper_weight(h, self.zx[1:] - self.zx[:-1], self.Zx[1:] - self.Zx[:-1]
                             - self.zx[:-1] * h)
        zero = jnp.zeros((1,), dtype=x_nodes.dtype)
        self.w_lo = jnp.concatenate([h - w_up, zero])
        self.w_hi = jnp.concatenate([zero, w_up])
        self.method = method

    def free_propagator(self, h):
        r"""$e^{A h}$ for the load-free springs, shape (len(h), N, N).

        $A = \mathrm{diag}(1/\tau)(\mathbf 1 r^\top - I)$ ($r_k = G_k/G_g$, `arm_ratio`) is
        similar to the symmetric $B = y y^\top - \mathrm{diag}(1/\tau)$,
        $y_k = \sqrt{r_k/\tau_k}$, through $S = \mathrm{diag}(\sqrt{r_k\tau_k})$, so
        $e^{Ah} = S^{-1} Q e^{\Lambda h} Q^\top S$
        with one symmetric eigenproblem (its eigenvalues are minus the retardation rates).
        """
        if self.Gk.shape[0] == 1:
            return jnp.exp(self.A[None] * h[:, None, None])
        y = jnp.sqrt(self.arm_ratio / self.tau)
        lam, Q = jnp.linalg.eigh(y[:, None] * y[None, :] - jnp.diag(1.0 / self.tau))
        sig = jnp.sqrt(self.arm_ratio * self.tau)
        P = jnp.einsum("km,im,jm->ikj", Q, jnp.exp(lam[None, :] * h[:, None]), Q)
        return P * (sig[None, None, :] / sig[None, :, None])

    # ---- line load and criterion ----------------------------------------------------------

    def sqrt(self, x):
        return jnp.sqrt(jnp.maximum(x, 0.0))

    # ---- attached side: cells [x_j, min(x_{j+1}, a)] ----------------------------------------

    def attached_cells(self, V, vf, a, d):
        r"""Linear-in-zeta representation of $s = v + g$ on the contact side.

        Cell $j$ is $[x_j, \min(x_{j+1}, a)]$ (valid where $x_j < a$); inside it
        $R(x) = \alpha_j - \beta_j\zeta(x) + c\sqrt{x}$. Returns the per-cell arrays as
        `Cells`, shape `(n_nodes,)` (`(n_nodes, N)` for `s_lo`, `s_hi`, `slope`).
        """
        s_nodes = V + self.gx[:, None]
        s_next = jnp.concatenate([s_nodes[1:], s_nodes[-1:]], axis=0)
        return self._cells(self.x, self.x_next, self.zx, self.z_next, s_nodes, s_next,
                           vf + self.geo.g(a), a, d)

    def cell(self, V, vf, a, d, j):
        """Cell `j` of `attached_cells` alone (the same values), for an integer index `j` of
        any shape: `Cells` of shape `j.shape` (`j.shape + (N,)` for `s_lo`, `s_hi`,
        `slope`). A step reads a few cells: picking their inputs leaves the others' work
        (and its derivatives) out."""
        j = jnp.asarray(j)
        up = jnp.minimum(j + 1, self.n_nodes - 1)
        s_lo = pick(V, j) + pick(self.gx, j)[..., None]
        s_next = pick(V, up) + pick(self.gx, up)[..., None]
        return self._cells(pick(self.x, j), pick(self.x_next, j), pick(self.zx, j),
                           pick(self.z_next, j), s_lo, s_next, vf + self.geo.g(a), a, d)

    def _cells(self, x_lo, x_next, z_lo, z_next, s_lo, s_next, s_front, a, d):
        # the formula of `attached_cells` on gathered inputs (one home for both)
        up_node = x_next < a
        x_hi = jnp.where(up_node, x_next, a)
        z_hi = jnp.where(up_node, z_next, self.geo.zeta(a))
        s_hi = jnp.where(up_node[..., None], s_next, jnp.broadcast_to(s_front, s_next.shape))
        dz = z_hi - z_lo
        slope = safe_div(s_hi - s_lo, dz[..., None])
        Gs = arms_sum(s_lo, self.Gk)
        Gm = arms_sum(slope, self.Gk)
        alpha = 4.0 * (self.Gg * d - Gs + Gm * z_lo)
        beta = 4.0 * (self.Gi_g + Gm)
        R_nodes = 4.0 * (self.Gg * d - self.Gi_g * z_lo - Gs) + self.c * jnp.sqrt(x_lo)
        return Cells(
            valid=x_lo < a, up_node=up_node, x_lo=x_lo, x_hi=x_hi, z_lo=z_lo, z_hi=z_hi,
            dz=dz, s_lo=s_lo, s_hi=s_hi, slope=slope, alpha=alpha, beta=beta, R_nodes=R_nodes,
        )

    def cell_R(self, x, alpha, beta):
        return alpha - beta * self.geo.zeta(x) + self.c * self.sqrt(x)

    def force(self, V, vf, a, d):
        r"""$F = 8[G_g a d - G_\infty\int_0^a g - \sum_k G_k\int_0^a s_k]$ [N].

        $S = \sum_k G_k s_k$ is linear in $\zeta$ on each cell, so its integral over a whole
        cell $[x_j, x_{j+1}] \subset [0, a]$ is $w_{\mathrm{lo},j} S_j + w_{\mathrm{hi},j}
        S_{j+1}$ with weights fixed by the grid (`w_lo`, `w_hi`), and over the front's cell
        $[x_m, a]$ the same with weights of $a$. Node $j$'s weight is the sum of its two
        cells' (a select of constants per node: no derivative of $a$ reaches the nodes, and
        the forward-mode Jacobian's directions cost one product a node).
        """
        Gs = arms_sum(V + self.gx[:, None], self.Gk)
        whole = self.x_next < a  # cell j lies in the contact
        after_whole = jnp.concatenate([jnp.zeros((1,), bool), whole[:-1]])
        weight = jnp.where(whole, self.w_lo, 0.0) + jnp.where(after_whole, self.w_hi, 0.0)
        # the front's cell [x_m, a]: m the last node in contact (node 0 where a = 0)
        m = jnp.maximum(jnp.sum(self.x < a) - 1, 0)
        x_m, z_m, Z_m = pick(self.x, m), pick(self.zx, m), pick(self.Zx, m)
        h = a - x_m
        w_up = _upper_weight(h, self.geo.zeta(a) - z_m,
                             self.geo.zeta_integral(a) - Z_m - z_m * h)
        Gs_front = jnp.sum(self.Gk * (vf + self.geo.g(a)))
        int_Gs = jnp.sum(Gs * weight) + pick(Gs, m) * (h - w_up) + Gs_front * w_up
        return 8.0 * (self.Gg * a * d - self.Gi * self.geo.integral_g(a) - int_Gs)

    def criterion_nodes(self, V, vf, a, d):
        """R at the nodes in contact, `-inf` at the others, shape `(n_nodes,)` [N/m]; for
        decisions (callers use no derivative of it: the compiler leaves them out)."""
        return jnp.where(self.x < a, self.attached_cells(V, vf, a, d).R_nodes, -jnp.inf)

    def max_criterion(self, V, vf, a, d, R_nodes=None):
        """Largest value of R on [0, a] (concave R per cell assumed) and where it is, for
        the attached side of `attached_cells(V, vf, a, d)`; `R_nodes`: its
        `criterion_nodes` where the caller has them.

        Returns (R_max, x_max, cell index of x_max); R_max carries gradients (envelope
        theorem), x_max does not. Reads $R$ at the nodes and three cells.
        """
        if R_nodes is None:
            R_nodes = self.criterion_nodes(V, vf, a, d)
        m = jnp.maximum(jnp.sum(self.x < a) - 1, 0)  # last contact node; its cell ends at the front
        front = self.cell(V, vf, a, d, m)
        R_front = self.cell_R(a, front.alpha, front.beta)
        j_star = jnp.argmax(R_nodes)
        at_front = R_front >= pick(R_nodes, j_star)
        c1 = jnp.where(at_front, m, jnp.maximum(j_star - 1, 0))
        c2 = jnp.where(at_front, m, j_star)

        def cell_max(j):
            cj = self.cell(V, vf, a, d, j)
            lo, hi, al, be = cj.x_lo, cj.x_hi, cj.alpha, cj.beta
            q = safe_div(self.c, 2.0 * be, jnp.inf)
            xs = jnp.where(be > 0, self.geo.stationary(jnp.where(be > 0, q, 1.0), lo, hi), hi)
            cand = lax.stop_gradient(jnp.stack([lo, hi, xs]))
            vals = self.cell_R(cand, al, be)
            i = jnp.argmax(vals)
            return pick(vals, i), pick(cand, i)

        r1, x1 = cell_max(c1)
        r2, x2 = cell_max(c2)
        take2 = r2 >= r1
        return jnp.where(take2, r2, r1), jnp.where(take2, x2, x1), jnp.where(take2, c2, c1)

    def _swept_springs(self, lo, hi, some, every, *, unused, all_nodes):
        r"""The springs the front swept in a step (touched or released): those at
        `lo` $\le x <$ `hi`, shape `(n_nodes, N)`, read only there.

        `every()`: their update at every node; `some(i)`: at the node indices `i` (shape
        `(K,)`, the same formula on picked inputs). Where at most $K$ = `_SWEPT_NODES` nodes
        were swept (or the result is `unused`: a lane of another branch), `some` at the
        first $K$ nodes from `lo` on, spread over the nodes (the others hold the last
        one's: never read); elsewhere, and where `all_nodes` (a jump-off, a contact over
        the whole grid), `every` — under `vmap` run only where some lane needs it (the
        contact's first touch, a jump-off). The per-node update with its derivatives was
        the step's largest kernel, needed at one or two nodes.
        """
        n = self.n_nodes
        k = jnp.arange(_SWEPT_NODES)
        first = jnp.sum(self.x < lo)
        narrow = unused | (jnp.logical_not(all_nodes)
                           & (jnp.sum(self.x < hi) - first <= _SWEPT_NODES))

        def window(_):
            win = some(jnp.minimum(first + k, n - 1))
            j = jnp.arange(n)[:, None]
            out = jnp.broadcast_to(win[-1], (n,) + win.shape[1:])
            for i in range(_SWEPT_NODES - 2, -1, -1):
                out = jnp.where(j == first + i, win[i], out)
            return out

        return _sharding.cond(narrow, window, lambda _: every(), None, masked=False)

    # ---- propagation over one step ------------------------------------------------------------

    def propagate(self, Vp, gp, t0, t1, d0, d1, P):
        """Attached and free evolution of all points over the full step (by the method).

        `Vp`: (p, N) states, `gp`: (p,) g at the points, or tuples of such blocks.
        Returns (V_att, V_free, ok), blocks as `Vp`.
        """
        return self.method.propagate(Vp, gp, t0, t1, d0, d1, P, self.tau, self.A)

    # ---- one step -------------------------------------------------------------------------------

    def step(self, state, t0, t1, d1, P, force_detach=False):
        r"""Advance the foundation from `state` (at t0) to t1 with $d$ linear to `d1`.

        `state`: a `FoundationState`. Returns `(new_state, out)`, a `FoundationState` at t1
        and a `StepOutput`.
        """
        V, E, a, d0 = state.nodes, state.edge, state.radius, state.depth
        vf = E[0]
        x, gx, arm_ratio = self.x, self.gx, self.arm_ratio
        dt = t1 - t0
        dd = d1 - d0
        ga = self.geo.g(a)
        (V_att, E_att), (V_free, E_free), ok = self.propagate(
            (V, E), (gx, jnp.stack([ga, ga])), t0, t1, d0, d1, P)
        vf_att, vf_free = E_att[0], E_free[1]
        # when out of contact the edge sits at x = 0 and carries node 0's state
        vf_free = jnp.where(a > 0, vf_free, V_free[0])

        in_contact = a > 0
        q_edge = 4.0 * (self.Gg * (d1 - ga) - jnp.sum(self.Gk * vf_att))
        R_edge = q_edge + self.c * self.sqrt(a)
        phi_edge = d1 - ga - jnp.sum(arm_ratio * vf_free)
        recede = in_contact & ((R_edge < 0) | force_detach)
        advance = jnp.logical_not(recede) & (phi_edge > 0) & (a < self.L)
        branch = jnp.where(recede, 2, jnp.where(advance, 1, 0))

        nan = jnp.asarray(jnp.nan, dtype=a.dtype)
        no = jnp.asarray(False)

        def pinned(_):
            E_new = jnp.stack([jnp.where(in_contact, vf_att, V_free[0]), vf_free])
            return StepBranch(inner=a, outer=a, swept=jnp.zeros_like(V), edge=E_new, radius=a,
                              jumped=no, theta_jump=nan, overflow=no)

        def advancing(_):
            # free side: cells [max(x_j, a), x_{j+1}] for x_{j+1} > a, v linear in zeta; the
            # front stops in the first such cell whose upper node is not reached (phi < 0)
            phi_nodes = d1 - gx - arms_sum(V_free, arm_ratio)
            stop = (x[1:] > a) & (phi_nodes[1:] < 0)
            exists = jnp.any(stop)
            j = jnp.argmax(stop)
            # cell j from max(x_j, a) (the edge where x_j <= a) to x_{j+1}
            beyond = pick(x, j) > a
            phi_lo = jnp.where(beyond, pick(phi_nodes, j), phi_edge)
            phi_hi = pick(phi_nodes, j + 1)
            frac = safe_div(phi_lo, phi_lo - phi_hi)
            frac = jnp.clip(jnp.where(exists, frac, 1.0), 0.0, 1.0)
            z_lo = jnp.where(beyond, pick(self.zx, j), self.geo.zeta(a))
            z_star = z_lo + frac * (pick(self.zx, j + 1) - z_lo)
            a_root = self.geo.zeta_inverse(z_star, jnp.where(beyond, pick(x, j), a),
                                           pick(x, j + 1))
            a_new = jnp.where(exists, a_root, self.L)
            # springs touched during the step: free until theta, attached afterwards
            def touched(Vs, Vs_free, gs, phi1):
                phi0 = d0 - gs - arms_sum(Vs, arm_ratio)
                theta = jnp.where(phi0 >= 0, 0.0,
                                  jnp.clip(safe_div(phi0, phi0 - phi1), 0, 1))
                v_theta = Vs + theta[..., None] * (Vs_free - Vs)
                return attached_update(v_theta, d0 + theta * dd - gs, (1 - theta) * dd,
                                       (1 - theta) * dt, self.tau)

            # usually the front crosses a node or two: those alone (`_swept_springs`)
            V_touch = self._swept_springs(
                a, a_new, lambda i: touched(pick(V, i), pick(V_free, i), pick(gx, i),
                                            pick(phi_nodes, i)),
                lambda: touched(V, V_free, gx, phi_nodes),
                unused=jnp.logical_not(advance), all_nodes=jnp.logical_not(exists))
            # the contact covers the whole grid (the flat punch): the edge is the last node
            v_lo = jnp.where(beyond, pick(V_free, j), vf_free)
            vf_new = jnp.where(exists, v_lo + frac * (pick(V_free, j + 1) - v_lo), V_touch[-1])
            E_new = jnp.stack([vf_new, vf_new])
            return StepBranch(inner=a, outer=a_new, swept=V_touch, edge=E_new, radius=a_new,
                              jumped=no, theta_jump=nan, overflow=jnp.logical_not(exists))

        def receding(_):
            R_nodes = self.criterion_nodes(V_att, vf_att, a, d1)
            R_max, x_max, c_max = self.max_criterion(V_att, vf_att, a, d1, R_nodes)
            ok_nodes = R_nodes >= 0  # in contact and holding
            idx = jnp.arange(self.n_nodes)
            m_R = jnp.max(jnp.where(ok_nodes, idx, -1))
            x_mR = jnp.where(m_R >= 0, pick(x, jnp.maximum(m_R, 0)), -jnp.inf)
            use_xmax = (R_max >= 0) & (x_max > x_mR)
            cell = jnp.where(use_xmax, c_max, jnp.maximum(m_R, 0))
            lo = jnp.where(use_xmax, x_max, x_mR)
            picked = self.cell(V_att, vf_att, a, d1, cell)
            hi = picked.x_hi
            jump = (R_max < 0) | force_detach
            lo = jnp.where(jump, 0.25 * a, lo)
            hi = jnp.where(jump, 0.75 * a, hi)
            al, be = picked.alpha, picked.beta
            mid = 0.5 * (lo + hi)

            def resid(xx):
                # a harmless stand-in on lanes that jump off (finite derivative for the
                # implicit-function tangent)
                return jnp.where(jump, xx - mid, self.cell_R(xx, al, be))

            # `active`: under vmap the lanes that do not recede do not hold the loop
            root = concave_root(resid, lo, hi, steps=_ROOT_STEPS, active=recede,
                                unrolled=_ROOT_UNROLLED)
            a_new = jnp.where(jump, 0.0, root)
            s_edge = picked.s_lo + picked.slope * (self.geo.zeta(root) - picked.z_lo)
            # springs released during the step: attached until theta, free afterwards.
            # Jump-off: theta from the edge criterion at t0 and max R at t1 (linear in time).
            R0 = 4.0 * (self.Gg * (d0 - ga) - jnp.sum(self.Gk * vf)) + self.c * self.sqrt(a)
            theta_jump = jnp.clip(safe_div(R0, R0 - R_max, 1.0), 0.0, 1.0)
            theta_jump = jnp.where(jump, theta_jump, jnp.nan)
            def released(xs, Vs, gs):
                theta_front = jnp.clip(safe_div(a - xs, a - a_new, 1.0), 0.0, 1.0)
                theta = jnp.where(jump, theta_jump, theta_front)
                theta = jnp.where(jnp.isfinite(theta), theta, 1.0)
                v_theta = attached_update(Vs, d0 - gs, theta * dd, theta * dt, self.tau)
                return v_theta + (1 - theta)[..., None] * (arms_apply(P, v_theta) - v_theta)

            # usually the front recedes over a node or two: those alone (a jump-off
            # releases every spring in contact)
            V_rel = self._swept_springs(
                a_new, a, lambda i: released(pick(x, i), pick(V, i), pick(gx, i)),
                lambda: released(x, V, gx), unused=jnp.logical_not(recede), all_nodes=jump)
            # a jump-off releases every spring (node 0 included: x_0 = 0 < a)
            vf_new = jnp.where(jump, V_rel[0], s_edge - self.geo.g(root))
            E_new = jnp.stack([vf_new, vf_new])
            return StepBranch(inner=a_new, outer=a, swept=V_rel, edge=E_new, radius=a_new,
                              jumped=jump, theta_jump=theta_jump, overflow=no)

        def touching(_):
            new = _sharding.switch(branch, (pinned, advancing, receding), None)
            V_new = jnp.where((x < new.inner)[:, None], V_att,
                              jnp.where((x < new.outer)[:, None], new.swept, V_free))
            F = jnp.where(new.radius > 0, self.force(V_new, new.edge[0], new.radius, d1), 0.0)
            return StepEnd(nodes=V_new, edge=new.edge, radius=new.radius, jumped=new.jumped,
                           theta_jump=new.theta_jump, overflow=new.overflow), F

        def apart(_):
            # out of contact before and after the step (the pinned branch at a = 0): the
            # springs relax load-free and carry no force
            free = StepEnd(nodes=V_free, edge=jnp.stack([vf_free, vf_free]), radius=a,
                           jumped=no, theta_jump=nan, overflow=no)
            return free, jnp.zeros_like(a)

        # under vmap the contact's work runs only where some lane is in contact or touches
        # (on a QI curve most samples are apart on every lane: before the touch, after the
        # jump-off). Unmasked: `apart` is linear, and `touching` on an apart lane is what
        # every lane computed before (its branches mask their own inputs)
        new, F = _sharding.cond(in_contact | (branch != 0), touching, apart, None,
                                masked=False)
        a_new = new.radius
        out = StepOutput(
            force=F, radius=a_new, depth=d1, jumped=new.jumped, theta_jump=new.theta_jump,
            ok=ok, overflow=new.overflow & jnp.logical_not(self.geo.covers_contact),
            newton_failed=jnp.asarray(False),
        )
        return FoundationState(nodes=new.nodes, edge=new.edge, radius=a_new, depth=d1), out
