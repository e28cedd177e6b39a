"""Events inside a sample interval: jump-off, instability under compliant loading, and
the dense-output force minimum along the receding front (functions of the model's
constants, `._model._Model`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from .._arms import arms_sum, attached_update, decay
from .._root import bracketed_root
from .._sharding import pick, searchsorted
from .._solvers import (
    golden_section,
    implicit_extremum,
    newton_iterate,
    quadratic_at,
    quadratic_newton_form,
    safe_div,
)
from ._state import JumpOff


def refine_jumpoff(model, pre):
    r"""Solve $\max_x R(x, t) = 0$ inside the jump-off step (exact in-step evolution).

    `pre`: the `StepStart` of the step that jumped off. The attached update is affine
    in $s$ with coefficients that do not depend on $x$, so inside the cell that holds
    the maximum the criterion is an explicit function of the step fraction $\theta$:
    $s_k(x, \theta) = e_k(\theta)\,s_k(x, 0) + b_k(\theta)$. The maximum of
    $R(\cdot, \theta)$ over that cell is then solved for $\theta$ by a scalar root.
    Returns (time, displacement, radius, force, valid); `valid` is False when the step
    does not bracket the fold.
    """
    V, vf, a, t0, d0, d1 = pre.nodes, pre.edge_spring, pre.radius, pre.t0, pre.d0, pre.d1
    dt, dd = pre.t1 - t0, d1 - d0
    ga = model.geo.g(a)
    # the cell of the maximum at the end of the step (no derivative needed for the choice)
    V1 = attached_update(V, d0 - model.gx, dd, dt, model.tau)
    vf1 = attached_update(vf, d0 - ga, dd, dt, model.tau)
    cell = lax.stop_gradient(model.max_criterion(V1, vf1, a, d1)[2])
    cell0 = model.cell(V, vf, a, d0, cell)
    s_lo0, slope0, z_lo = cell0.s_lo, cell0.slope, cell0.z_lo
    lo, hi = cell0.x_lo, cell0.x_hi

    def coefficients(theta):
        e, m1, ps = decay(jnp.asarray(theta * dt) / model.tau)
        b = -d0 * m1 + theta * dd * ps
        Gs = jnp.sum(model.Gk * (s_lo0 * e + b))
        Gm = jnp.sum(model.Gk * slope0 * e)
        alpha = 4.0 * (model.Gg * (d0 + theta * dd) - Gs + Gm * z_lo)
        beta = 4.0 * (model.Gi_g + Gm)
        return alpha, beta, e, b

    def argmax(alpha, beta):
        q = safe_div(model.c, 2.0 * beta, jnp.inf)
        xs = jnp.where(beta > 0, model.geo.stationary(jnp.where(beta > 0, q, 1.0), lo, hi), hi)
        cand = lax.stop_gradient(jnp.stack([lo, hi, xs]))
        vals = model.cell_R(cand, alpha, beta)
        return pick(cand, jnp.argmax(vals))

    def rmax(theta):
        alpha, beta, _, _ = coefficients(theta)
        return model.cell_R(argmax(alpha, beta), alpha, beta)

    valid = (rmax(0.0) >= 0) & (rmax(1.0) < 0)
    theta = bracketed_root(rmax, 0.0, 1.0, steps=48)
    alpha, beta, e, b = coefficients(theta)
    x_max = argmax(alpha, beta)
    # one Newton step on R'(x) = 0 at the converged maximiser: same value, and the exact
    # implicit derivative dx/dp = -R'_p / R'' when the maximum is interior to the cell
    dR = jax.grad(lambda xx: model.cell_R(xx, alpha, beta))
    x_cell = implicit_extremum(dR, x_max, lo, hi, maximum=True)
    d = d0 + theta * dd
    Va = attached_update(V, d0 - model.gx, theta * dd, theta * dt, model.tau)
    vfa = attached_update(vf, d0 - ga, theta * dd, theta * dt, model.tau)
    cells = model.attached_cells(Va, vfa, a, d)
    x_fold = _fold_radius(model, cells, a, d, x_cell)
    n_last = jnp.maximum(jnp.sum(cells.valid) - 1, 0)
    c = jnp.clip(searchsorted(model.x, x_fold, side="right") - 1, 0, n_last)
    s_edge = pick(cells.s_lo, c) + pick(cells.slope, c) * (
        model.geo.zeta(x_fold) - pick(cells.z_lo, c))
    F = model.force(Va, s_edge - model.geo.g(x_fold), x_fold, d)
    return JumpOff(time=t0 + theta * dt, displacement=d, radius=x_fold, force=F, valid=valid)

def _fold_radius(model, cells, a, d, fallback):
    r"""Second-order maximiser of the criterion near the fold.

    The maximiser of the piecewise-linear interpolant is only first-order accurate (its
    slope is). Here the interpolated part $S = \sum_k G_k s_k$ is replaced by the
    quadratic in $\zeta$ through the spring of largest $R$ and its two neighbours, and
    $R = 4(G_g d - G_\infty g - S) + c\sqrt{x}$ is maximised by Newton's method (exact
    for the elastic, glass and relaxed limits, where $S$ is at most linear in $\zeta$).
    Falls back to `fallback` where those springs are not available.
    """
    valid = cells.valid
    R_nodes = jnp.where(valid, cells.R_nodes, -jnp.inf)
    Gs = arms_sum(cells.s_lo, model.Gk)
    j = jnp.argmax(R_nodes)
    m = jnp.maximum(jnp.sum(valid) - 1, 0)
    Gs_front = jnp.sum(model.Gk * pick(cells.s_hi, m))
    jl = jnp.maximum(j - 1, 0)
    jr = jnp.minimum(j + 1, model.n_nodes - 1)
    right_is_node = pick(valid, jr) & (jr > j)
    x0 = pick(model.x, jl)
    x2 = jnp.where(right_is_node, pick(model.x, jr), a)
    z0, z1 = pick(model.zx, jl), pick(model.zx, j)
    z2 = jnp.where(right_is_node, pick(model.zx, jr), model.geo.zeta(a))
    S0, S1 = pick(Gs, jl), pick(Gs, j)
    S2 = jnp.where(right_is_node, pick(Gs, jr), Gs_front)
    ok = (j >= 1) & (z2 > z1) & (z1 > z0)
    b1, c2 = quadratic_newton_form(z0, z1, z2, S0, S1, S2, ok)

    def R(x):
        z = model.geo.zeta(x)
        S = quadratic_at(z, z0, z1, S0, b1, c2)
        return 4.0 * (model.Gg * d - model.Gi_g * z - S) + model.c * model.sqrt(x)

    dR = jax.grad(R)
    lo, hi = lax.stop_gradient(x0), lax.stop_gradient(x2)
    xs = newton_iterate(dR, fallback, lo, hi, steps=12)
    # one Newton step with derivatives: the implicit derivative of the maximiser
    return implicit_extremum(dR, xs, lo, hi, maximum=True, ok=ok, fallback=fallback)

def front_field(model, V, vf, a0, d0):
    r"""The attached field of a contact of radius `a0` as a function of the position.

    Returns `(field, cells)`: `field(x) -> (s(x), J(x))` for $0 \le x \le a_0$, the
    interpolated $s_k = v_k + g$ at $x$ and its integral $J_k(x) = \int_0^x s_k\,dx'$,
    exact over the interpolant (both of shape (N,)); `cells` from `attached_cells`.
    """
    cells = model.attached_cells(V, vf, a0, d0)
    valid = cells.valid
    h = jnp.where(valid, cells.x_hi - cells.x_lo, 0.0)
    dz = jnp.where(valid, cells.dz, 0.0)
    Z_hi = model.geo.zeta_integral(jnp.where(valid, cells.x_hi, cells.x_lo))
    num = jnp.where(valid, Z_hi - model.Zx - model.zx * h, 0.0)
    w = jnp.where(dz > 0, num / jnp.where(dz > 0, dz, 1.0), 0.5 * h)
    full = cells.s_lo * h[:, None] + (cells.s_hi - cells.s_lo) * w[:, None]
    full = jnp.where(valid[:, None], full, 0.0)
    cum = jnp.cumsum(full, axis=0) - full  # integral over the cells below cell j
    n_last = jnp.maximum(jnp.sum(valid) - 1, 0)

    def field(x):
        c = jnp.clip(searchsorted(model.x, x, side="right") - 1, 0, n_last)
        hc = x - pick(model.x, c)
        s_x = pick(cells.s_lo, c) + pick(cells.slope, c) * (model.geo.zeta(x) - pick(model.zx, c))
        part = model.geo.zeta_integral(x) - pick(model.Zx, c) - pick(model.zx, c) * hc
        J = pick(cum, c) + pick(cells.s_lo, c) * hc + pick(cells.slope, c) * part
        return s_x, J

    return field, cells

def refine_instability(model, pre, z0, z1, k):
    r"""Jump-off inside a step under a compliant loading system of stiffness `k`.

    Inside the step the drive is $z(\theta) = z_0 + \theta(z_1 - z_0)$ and the
    indentation is taken linear in time from $d_0$ to its value $d$ at $\theta$, so
    the attached field is $s_k(x, \theta) = e_k s_k(x, 0) - d_0(e_k - 1)
    + (d - d_0)\psi_k$ ($e_k = e^{-\theta\Delta t/\tau_k}$, $\psi_k =
    \psi(\theta\Delta t/\tau_k)$): affine in $d$. For a front at $x$ the criterion
    $R(x, \theta, d) = 0$ then gives $d_R(x, \theta)$ explicitly, and the drive position
    that holds that front in equilibrium is $z_\mathrm{eq}(x, \theta) = d_R + F/k$.
    Equilibria exist while $z(\theta) \ge \min_x z_\mathrm{eq}(x, \theta)$; the
    contact jumps off at the root $\theta^*$ of
    $H(\theta) = z(\theta) - \min_x z_\mathrm{eq}(x, \theta)$, at the minimiser
    $x^*$ (where $\mathrm{d}F/\mathrm{d}d = -k$ along the front, or the criterion's fold
    for a stiff spring, or the edge itself when a pinned edge is already unstable as
    it starts to recede). Exact for an elastic solid (no time dependence);
    otherwise as accurate as the linear-in-time indentation inside a step.
    The minimum over $x$ is a golden-section search (one minimum on $[0, a]$ assumed),
    differentiated by the envelope theorem; $x^*$ by one Newton step on
    $\partial_x z_\mathrm{eq} = 0$.

    `pre`: the `StepStart` of the step that jumped off.
    Returns (time, displacement, radius, force, valid); `valid` is False when the step
    does not bracket the instability.
    """
    V, vf, a, t0, d0 = pre.nodes, pre.edge_spring, pre.radius, pre.t0, pre.d0
    dt = pre.t1 - t0
    field, cells = front_field(model, V, vf, a, d0)

    def equilibrium(x, theta):
        sc = jnp.asarray(theta * dt) / model.tau
        e, m1, ps = decay(sc)
        s_x, J = field(x)
        P = jnp.sum(model.Gk * ps)
        # R = 4 (G_g d - G_inf g - sum G_k s_k) + c sqrt(x) = 0, solved for d
        rest = model.Gi_g * model.geo.zeta(x) + jnp.sum(model.Gk * (e * s_x - d0 * m1))
        d = (rest - d0 * P - 0.25 * model.c * model.sqrt(x)) / (model.Gg - P)
        b = -d0 * m1 + (d - d0) * ps
        F = model.Gg * x * d - model.Gi * model.geo.integral_g(x)
        F = 8.0 * (F - jnp.sum(model.Gk * (e * J + b * x)))
        return d, F

    def z_eq(x, theta):
        d, F = equilibrium(x, theta)
        return d + F / k

    a_sg = lax.stop_gradient(a)

    def argmin(theta):
        theta = lax.stop_gradient(theta)
        zero = jnp.zeros_like(a_sg)
        lo, hi = golden_section(lambda x: z_eq(x, theta), zero, a_sg, steps=60)
        mid = 0.5 * (lo + hi)
        # golden section resolves a smooth minimum to ~sqrt(eps) only: polish by Newton
        # steps, kept where they are as small as that (not across a kink of the
        # interpolant, where the minimum is the kink itself)
        dz = jax.grad(lambda x: z_eq(x, theta))
        mid = newton_iterate(dz, mid, zero, a_sg, steps=3, max_step=1e-6 * a_sg)
        # the minimum at the edge itself (a pinned edge unstable as it starts to recede)
        return jnp.where(a_sg - mid < 1e-9 * a_sg, a_sg, mid)

    def at_min(theta):
        xs = argmin(theta)
        # envelope theorem: the value at the fixed interior minimiser; at the edge the
        # edge moves with the parameters
        x = jnp.where(xs == a_sg, a, lax.stop_gradient(xs))
        return x

    def H(theta):
        return z0 + theta * (z1 - z0) - z_eq(at_min(theta), theta)

    valid = (H(0.0) >= 0) & (H(1.0) < 0)
    theta = bracketed_root(H, 0.0, 1.0, steps=48)
    x = at_min(theta)
    interior = lax.stop_gradient(x) < a_sg
    # the implicit derivative of the minimiser, dx/dp = -(d z'/dp) / z'' (a Newton step
    # on z' = 0 that only enters the derivative: the value stays the converged one)
    dz = jax.grad(lambda xx: z_eq(xx, theta))
    x = implicit_extremum(dz, x, -jnp.inf, a_sg, maximum=False, keep_value=True)
    x = jnp.where(interior, _instability_radius(model, cells, a, d0, dt, theta, k, x), x)
    d, F = equilibrium(x, theta)
    return JumpOff(time=t0 + theta * dt, displacement=d, radius=x, force=F, valid=valid)

def _instability_radius(model, cells, a, d0, dt, theta, k, fallback):
    r"""Second-order location of an interior minimum of $z_\mathrm{eq}(x, \theta)$.

    The slope of the piecewise-linear interpolant is only first-order accurate, so is
    the minimiser found on it. Here the interpolated part
    $S_e(x) = \sum_k G_k e_k s_k(x, 0)$ is replaced by the quadratic in $\zeta$ through
    three springs around the minimum (exact for the elastic, glass and relaxed limits,
    as in `_fold_radius`) and $\partial_x z_\mathrm{eq} = 0$ is solved by Newton's
    method, with one final step carrying the implicit derivative. Falls back to
    `fallback` where those springs are not available.
    """
    sc = jnp.asarray(theta * dt) / model.tau
    e, m1, ps = decay(sc)
    P = jnp.sum(model.Gk * ps)
    B0 = -d0 * jnp.sum(model.Gk * m1)
    den = model.Gg - P
    S_nodes = arms_sum(cells.s_lo * e[None, :], model.Gk)
    m = jnp.maximum(jnp.sum(cells.valid) - 1, 0)  # last node in contact
    S_front = jnp.sum(model.Gk * e * pick(cells.s_hi, m))
    xs = lax.stop_gradient(fallback)
    c = jnp.clip(searchsorted(model.x, xs, side="right") - 1, 0, m)
    n1 = model.n_nodes - 1
    up_node = pick(cells.up_node, c)
    z_up = jnp.where(up_node, pick(model.zx, jnp.minimum(c + 1, n1)), model.geo.zeta(a))
    S_up = jnp.where(up_node, pick(S_nodes, jnp.minimum(c + 1, n1)), S_front)
    x_up = jnp.where(up_node, pick(model.x, jnp.minimum(c + 1, n1)), a)
    # springs c-1, c and the upper end of cell c; c-2, c-1, c if that end is very close
    # to spring c (the front just past it)
    z_c = pick(model.zx, c)
    short = (z_up - z_c) < 0.1 * (z_c - pick(model.zx, jnp.maximum(c - 1, 0)))
    i0 = jnp.where(short, c - 2, c - 1)
    j0, j1 = jnp.maximum(i0, 0), jnp.maximum(i0 + 1, 0)
    z0, z1 = pick(model.zx, j0), pick(model.zx, j1)
    z2 = jnp.where(short, pick(model.zx, c), z_up)
    S0, S1 = pick(S_nodes, j0), pick(S_nodes, j1)
    S2 = jnp.where(short, pick(S_nodes, c), S_up)
    ok = (i0 >= 0) & (z2 > z1) & (z1 > z0)
    b1, c2 = quadratic_newton_form(z0, z1, z2, S0, S1, S2, ok)
    dzeta = jax.grad(model.geo.zeta)

    def slope(x):
        # d z_eq / dx with z_eq = d_R + F / k and the quadratic S_e
        zz, zd = model.geo.zeta(x), dzeta(x)
        S = quadratic_at(zz, z0, z1, S0, b1, c2)
        Sp = (b1 + c2 * (2.0 * zz - z0 - z1)) * zd
        dR = (model.Gi_g * zz + S + B0 - d0 * P - 0.25 * model.c * model.sqrt(x)) / den
        dRp = (model.Gi_g * zd + Sp - 0.125 * model.c / model.sqrt(x)) / den
        Fp = model.Gg * (dR + x * dRp) - model.Gi * model.geo.g(x) - S - B0
        Fp = 8.0 * (Fp - (dR - d0) * P - x * P * dRp)
        return dRp + Fp / k

    lo = lax.stop_gradient(pick(model.x, j0))
    hi = lax.stop_gradient(jnp.where(short, pick(model.x, c), x_up))
    xq = newton_iterate(slope, xs, lo, hi, steps=8)
    # one Newton step with derivatives: the implicit derivative of the minimiser
    return implicit_extremum(slope, xq, lo, hi, maximum=False, ok=ok, fallback=fallback)

def front_minimum(model, pre, a_end):
    r"""Smallest force along a receding front inside one step (dense output).

    The attached field is affine in time with $x$-independent coefficients,
    $s_k(x, \theta) = e_k(\theta)s_k(x, 0) + b_k(\theta)$, so for a front position
    $a$ in $[a_\mathrm{end}, a_\mathrm{start}]$ the time $\theta(a)$ at which the front
    passes solves the scalar criterion $R(a, \theta) = 0$, and the force there is
    $F = 8[G_g a d - G_\infty\int_0^a g - \sum_k G_k(e_k J_k(a) + b_k a)]$ with
    $J_k(a) = \int_0^a s_k(x, 0)\,dx$, minimised over $a$ by a golden-section search.
    `pre`: the `StepStart` of the step (its `radius` is the radius at the start).
    Returns `inf` if the front does not recede.
    """
    V, vf, a0, d0, d1 = pre.nodes, pre.edge_spring, pre.radius, pre.d0, pre.d1
    dt, dd = pre.t1 - pre.t0, d1 - d0
    recedes = (a_end < a0) & (a_end > 0)
    a_end = jnp.where(recedes, a_end, 0.5 * a0)
    field, _ = front_field(model, V, vf, a0, d0)

    def e_b(theta):
        e, m1, ps = decay(jnp.asarray(theta * dt) / model.tau)
        return e, -d0 * m1 + theta * dd * ps

    e1, b1 = e_b(1.0)

    def at(a):
        s_a, J = field(a)
        za = model.geo.zeta(a)

        def R(theta):
            e, b = e_b(theta)
            q = model.Gg * (d0 + theta * dd) - model.Gi_g * za - jnp.sum(model.Gk * (e * s_a + b))
            return 4.0 * q + model.c * model.sqrt(a)

        theta = bracketed_root(R, 0.0, 1.0, steps=40)
        # the ends: the front is already there at t0 (receding), or only at t1
        edge = model.c * model.sqrt(a) - 4.0 * model.Gi_g * za
        R0 = 4.0 * (model.Gg * d0 - jnp.sum(model.Gk * s_a)) + edge
        R1 = 4.0 * (model.Gg * d1 - jnp.sum(model.Gk * (e1 * s_a + b1))) + edge
        theta = jnp.where(R0 <= 0, 0.0, jnp.where(R1 >= 0, 1.0, theta))
        e, b = e_b(theta)
        d = d0 + theta * dd
        F = model.Gg * a * d - model.Gi * model.geo.integral_g(a)
        F = F - jnp.sum(model.Gk * (e * J + b * a))
        return 8.0 * F

    # golden-section search over the front path (F is continuous in a; one minimum per
    # step assumed)
    lo, hi = golden_section(at, a_end, a0, steps=48)
    # derivatives: at an interior minimum (smooth, or at the kink of a spring) only the
    # partial derivative at the fixed minimiser counts (envelope theorem); at an end of
    # the path the end moves with the parameters
    mid = 0.5 * (lo + hi)
    tol = 1e-8 * (a0 - a_end)
    x_best = jnp.where(
        mid - a_end < tol, a_end, jnp.where(a0 - mid < tol, a0, lax.stop_gradient(mid))
    )
    best = at(x_best)
    return jnp.where(recedes, best, jnp.inf)
