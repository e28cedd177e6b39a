"""Tests of the scalar root finders (`jaxcontact._root`: `bracketed_root`, `concave_root`,
`convex_root`, `fold_root`)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

from jaxcontact._root import bracketed_root, concave_root, convex_root, fold_root


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_simple_root_to_round_off(dtype):
    eps = float(jnp.finfo(dtype).eps)
    c = jnp.asarray(2.0, dtype)
    x = bracketed_root(lambda x: x**3 - c, jnp.asarray(0.0, dtype), jnp.asarray(2.0, dtype))
    assert x.dtype == dtype
    assert abs(float(x) - 2.0 ** (1.0 / 3.0)) <= 4 * eps * 2.0 ** (1.0 / 3.0)


def test_small_root_in_a_wide_bracket_keeps_relative_accuracy():
    # a contact radius of ~1e-6 m bracketed by [0, 1 m]: stopping is relative to the root
    R, d = 1e-5, 1e-7
    a = bracketed_root(lambda a: a * a / R - d, 0.0, 1.0)
    assert float(a) == pytest.approx(np.sqrt(R * d), rel=1e-14)


def test_multiple_root_stops_at_the_round_off_floor():
    # f = (x - 1)^3: f' = 0 at the root, Newton converges linearly; the result is limited by
    # the round-off of f, |x - 1| ~ eps^(1/3)
    x = bracketed_root(lambda x: (x - 1.0) ** 3, 0.0, 3.0)
    assert abs(float(x) - 1.0) < 1e-5


def test_vmap_lanes_match_scalar_calls_and_jit():
    cs = jnp.array([0.5, 2.0, 7.0, 1e-6, 1e6])

    def root(c):
        return bracketed_root(lambda x: x**3 - c, 0.0, jnp.maximum(c, 1.0))

    lanes = jax.jit(jax.vmap(root))(cs)
    for c, x in zip(cs, lanes, strict=True):
        assert float(x) == pytest.approx(float(root(c)), rel=1e-15)
        assert float(x) == pytest.approx(float(c) ** (1 / 3), rel=1e-14)


def test_implicit_derivative_against_closed_form():
    # x(c) = c^(1/3): dx/dc = c^(-2/3)/3, forward and reverse mode
    def root(c):
        return bracketed_root(lambda x: x**3 - c, 0.0, 10.0)

    for c in (0.3, 2.0, 50.0):
        expect = c ** (-2.0 / 3.0) / 3.0
        assert float(jax.grad(root)(c)) == pytest.approx(expect, rel=1e-12)
        assert float(jax.jvp(root, (c,), (1.0,))[1]) == pytest.approx(expect, rel=1e-12)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_one_sided_newton_stops_at_the_root(dtype):
    # f convex and decreasing: Newton from the left approaches the root from one side and
    # only the lower bracket end moves; its last correction (below round-off) lands on that
    # end. The root must come out in a handful of steps, not after a bisection from the far
    # end (which left a relative error of 0.03 after 10 steps before the fix).
    eps = float(jnp.finfo(dtype).eps)
    ratio, tau, target = 7.49361904, 0.09854755, -0.01

    def f(t):
        return 1.0 - t + ratio * tau * jnp.expm1(-t / tau) - target

    x = bracketed_root(f, jnp.asarray(0.0, dtype), jnp.asarray(1.0 - target, dtype), steps=10)
    # independent: bisection in Python floats to the last bit
    lo, hi = 0.0, 1.0 - target
    g = lambda t: 1.0 - t + ratio * tau * math.expm1(-t / tau) - target  # noqa: E731
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) > 0 else (lo, mid)
    assert float(x) == pytest.approx(lo, rel=8 * eps)


def test_root_at_a_bracket_end_is_returned_at_once():
    # a linear function whose root is the upper end of the bracket (the sweep's elastic
    # lift, D(t) = 1 - t, bracketed by [0, 1 - y]): the end itself, in one step
    for y in (0.25, -0.5, 2.0**-30):  # exact in binary: f(end) == 0
        x = bracketed_root(lambda t, y=y: 1.0 - t - y, 0.0, 1.0 - y, steps=2)
        assert float(x) == 1.0 - y
        x = bracketed_root(lambda t, y=y: t - y, y, 5.0, steps=2)
        assert float(x) == y


def test_no_sign_change_returns_the_closer_end_at_once():
    # no root in the bracket: the end where |f| is smaller, without iterating (steps=1 gives
    # what steps=64 gives); lanes with a root beside it under vmap are unaffected
    for steps in (1, 64):
        assert float(bracketed_root(lambda x: x * x + 1.0, 0.0, 2.0, steps=steps)) == 0.0
        assert float(bracketed_root(lambda x: x * x + 1.0, -3.0, -0.5, steps=steps)) == -0.5
    cs = jnp.array([2.0, -1.0, 27.0])  # x^3 = c on [0, 4]: no root for c = -1

    def root(c):
        return bracketed_root(lambda x: x**3 - c, 0.0, 4.0)

    got = jax.vmap(root)(cs)
    np.testing.assert_allclose(np.asarray(got), [2.0 ** (1 / 3), 0.0, 3.0], rtol=1e-14)


def test_root_within_round_off_of_a_bracket_end():
    # f(hi) = -1.1e-16: a sign change, the root within round-off of hi (an elastic lift time
    # of the sweep); Newton from inside lands on hi, which is tried next instead of bisecting
    # towards it (3 steps gave 1.38 for 1.48 before)
    y = -0.4768613102600593
    x = bracketed_root(lambda t: 1.0 - t - y, 0.0, 1.0 - y, steps=3)
    assert float(x) == pytest.approx(1.0 - y, rel=1e-15)


# a lift's effective displacement minus its jump-off value, d0 - v u + w exp(-u/tau) - h
# (the jump-off time of `retract`): terms of ~1e-6 m cancel, so f is quantised at ~1e-22 m,
# more than f' times the spacing of neighbouring u. Newton from each of two adjacent points
# of opposite sign lands on the other; the loop alternated between them until `steps`
# (64 evaluations, and under vmap every lane waited: 50-60 % of the fitting Jacobian's time)
_TRAPPED = [(9.468129517344518e-07, 2.487418279480424e-06, 2.4376626276230124e-07,
             0.3915858526232482, 1.166448411710508e-06)]


def test_trapped_by_round_off_stops_early_with_the_full_loops_answer():
    evaluations = [0]

    def tick(_):
        evaluations[0] += 1

    def lift(d0, v, w, tau, h, *, count=False):
        def f(u):
            if count:
                jax.debug.callback(tick, u)
            return d0 - v * u + w * jnp.exp(-u / tau) - h
        return f

    for case in _TRAPPED:
        got = {}
        for steps in (62, 63, 64):
            evaluations[0] = 0
            got[steps] = float(jax.jit(
                lambda c, s=steps: bracketed_root(lift(*c, count=True), 0.0, 0.03, steps=s))(
                    case))
            # the two regula-falsi ends and a handful of Newton steps, not `steps`
            assert evaluations[0] <= 14, (steps, evaluations[0])
        # the loop would alternate between two adjacent points that bracket the root (the
        # root to round-off): `steps` of either parity give the one the full loop ends on
        a, b = got[63], got[64]
        assert a != b and got[62] == b
        assert abs(a - b) <= 1e-13 * abs(b)
        # both are the root to round-off (a second method: numpy's float64 and Brent)
        root = brentq(lambda u, c=case: c[0] - c[1] * u + c[2] * np.exp(-u / c[3]) - c[4],
                      0.0, 0.03, xtol=1e-30, rtol=1e-15)
        assert abs(a - root) <= 1e-13 * root and abs(b - root) <= 1e-13 * root
        # every lane of a vmap stops early too, with the same answers
        evaluations[0] = 0
        lanes = jax.jit(jax.vmap(
            lambda *c: bracketed_root(lift(*c, count=True), 0.0, 0.03, steps=64)))(
                *[jnp.asarray([v, v]) for v in case])
        assert evaluations[0] <= 2 * 14
        assert [float(x) for x in lanes] == [b, b]


def _counted(f, evaluations):
    def tick(_):
        evaluations[0] += 1

    def g(x):
        jax.debug.callback(tick, x)
        return f(x)
    return g


def test_concave_root_stops_at_the_root_and_idle_lanes_do_not_hold_the_loop():
    # the criterion of the detachment front inside a cell: R(x) = al - be x^2 + c sqrt(x),
    # concave; its root right of the maximum, by Brent on the same formula in numpy
    al, be, c = 1.0, 3.0, 0.5
    lo, hi = 0.2, 1.5

    def crit(x):
        return al - be * x * x + c * jnp.sqrt(x)

    root = brentq(lambda x: al - be * x * x + c * np.sqrt(x), lo, hi, xtol=1e-30, rtol=1e-15)
    evaluations = [0]
    got = jax.jit(lambda: concave_root(_counted(crit, evaluations), lo, hi, steps=16))()
    assert abs(float(got) - root) <= 4e-16 * root
    one = evaluations[0]
    assert one <= 9, one  # quadratic convergence: far fewer than the 16 steps allowed
    # under vmap: a lane that is not active returns at once (its bracket is not even a
    # valid one: f(hi) > 0 would bisect for all 16 steps) and the active lane's root is
    # the same, to the bit
    evaluations[0] = 0
    both = jax.jit(jax.vmap(lambda h, act: concave_root(
        _counted(crit, evaluations), lo, h, steps=16, active=act)))(
            jnp.asarray([hi, 0.3]), jnp.asarray([True, False]))
    assert float(both[0]) == float(got)
    assert evaluations[0] <= 2 * one, evaluations[0]
    # implicit derivative: d root / d al = -1 / R'(root)
    d = jax.grad(lambda a: concave_root(lambda x: a - be * x * x + c * jnp.sqrt(x), lo, hi,
                                        steps=16))(al)
    np.testing.assert_allclose(d, 1.0 / (2 * be * root - 0.5 * c / math.sqrt(root)),
                               rtol=1e-12)


def test_concave_root_unrolled_iterations_give_the_loops_iterates():
    # `unrolled`: the first iterations written out before the loop; a lane that has
    # stopped keeps its values, so every root is the loop's to the bit (a quick root, the
    # fold's slow one, an idle lane, the implicit derivative)
    al, be, c = 1.0, 3.0, 0.5

    def crit(x, a=al):
        return a - be * x * x + c * jnp.sqrt(x)

    lo = jnp.asarray([0.2, 0.2, 1.0])
    hi = jnp.asarray([1.5, 0.3, 2.0])
    act = jnp.asarray([True, False, True])
    eps = 1e-8

    def lane(k, lo_, hi_, act_, fold):
        f = (lambda x: eps - (x - 1.0) ** 2) if fold else crit
        return concave_root(f, lo_, hi_, steps=16, active=act_, unrolled=k)

    fold = jnp.asarray([False, False, True])
    for k in (1, 3, 16):
        loop = jax.jit(jax.vmap(lambda a, b, t, f: jax.lax.cond(
            f, lambda: lane(0, a, b, t, True), lambda: lane(0, a, b, t, False))))
        unrolled = jax.jit(jax.vmap(lambda a, b, t, f, k=k: jax.lax.cond(
            f, lambda: lane(k, a, b, t, True), lambda: lane(k, a, b, t, False))))
        np.testing.assert_array_equal(np.asarray(unrolled(lo, hi, act, fold)),
                                      np.asarray(loop(lo, hi, act, fold)))
        d = jax.grad(lambda a, k=k: concave_root(lambda x: crit(x, a), 0.2, 1.5, steps=16,
                                                 unrolled=k))(al)
        d0 = jax.grad(lambda a: concave_root(lambda x: crit(x, a), 0.2, 1.5, steps=16))(al)
        assert float(d) == float(d0)


def test_concave_root_near_a_double_root():
    # the fold of the front: R = eps - (x - 1)^2 on [1, 2], roots 1 +- sqrt(eps); Newton
    # converges linearly from the right as eps -> 0, the loop ends at `steps`
    for eps in (1e-4, 1e-8):
        got = float(concave_root(lambda x, e=eps: e - (x - 1.0) ** 2, 1.0, 2.0, steps=16))
        want = 1.0 + math.sqrt(eps)
        np.testing.assert_allclose(got, want, rtol=1e-12 if eps > 1e-6 else 1e-6)


def test_concave_root_stops_at_the_round_off_floor_and_on_a_collapsed_bracket():
    # the fold of the detachment front (the history model's criterion in a cell): a
    # concave function whose maximum lies just above zero, written with cancellation
    # (f = e - (x^2 - 2x + 1), root 1 + 1e-6): Newton halves its step down to the root's
    # neighbourhood, then reaches the round-off of f (~1e-16, so ~1e-10 in x at
    # f' = 2e-6) and wanders there; the loop stops at that floor instead of running to
    # `steps`, with the root to that floor
    e = 1e-12
    evaluations = [0]
    got = jax.jit(lambda: concave_root(_counted(lambda x: e - (x * x - 2.0 * x + 1.0),
                                                evaluations), 1.0, 2.0, steps=200))()
    assert abs(float(got) - (1.0 + 1e-6)) <= 1e-9
    assert evaluations[0] <= 40, evaluations[0]
    # f(hi) > 0 (no root inside: by round-off, the root at the end): the bracket collapses
    # onto hi, which is returned after one iteration (the loop bisected in place before)
    evaluations[0] = 0
    got = jax.jit(lambda: concave_root(_counted(lambda x: 1.0 - x, evaluations), 0.0, 0.5,
                                       steps=200))()
    assert float(got) == 0.5 and evaluations[0] <= 2, evaluations[0]


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_convex_root_from_the_right_and_clipped_ends(dtype):
    # x^(3/2) (1 + x^2) = q: increasing and convex on [0, 2]; starts at the power law's
    # root (q)^(2/3), which lies at or right of the root
    def f(q):
        return lambda x: x**1.5 * (1 + x * x) - q

    eps = float(jnp.finfo(dtype).eps)
    for q in (1e-6, 0.3, 2.0, 5.0):
        want = brentq(lambda x, q=q: x**1.5 * (1 + x * x) - q, 0.0, 2.0, xtol=1e-30, rtol=1e-15)
        got = convex_root(f(dtype(q)), dtype(q) ** (2 / 3), dtype(0.0), dtype(2.0), steps=8)
        assert got.dtype == dtype
        assert abs(float(got) - want) <= 8 * eps * want, (q, float(got), want)
    # a root below lo gives lo, above hi gives hi
    assert float(convex_root(f(0.3), 0.3 ** (2 / 3), 0.8, 2.0, steps=8)) == 0.8
    assert float(convex_root(f(50.0), 50.0 ** (2 / 3), 0.0, 2.0, steps=8)) == 2.0
    # implicit derivative: d root / dq = 1 / f'(root)
    if dtype == jnp.float64:
        r = brentq(lambda x: x**1.5 * (1 + x * x) - 0.3, 0.0, 2.0, xtol=1e-30, rtol=1e-15)
        d = jax.grad(lambda q: convex_root(f(q), 0.3 ** (2 / 3), 0.0, 2.0, steps=8))(0.3)
        np.testing.assert_allclose(d, 1.0 / (1.5 * r**0.5 + 3.5 * r**2.5), rtol=1e-12)


def test_convex_root_runs_its_steps_in_a_loop_on_the_cpu_written_out_elsewhere():
    # exactly `steps` Newton iterations from the start, clipped to the bracket: against the
    # iteration written out in NumPy (after 1 and 3 steps far from converged, so a missing or
    # extra iteration shows)
    def f(x, q):
        return x**1.5 * (1 + x * x) - q

    def newton(q, x, steps):
        for _ in range(steps):
            fx, dfx = f(x, q), 1.5 * x**0.5 + 3.5 * x**2.5
            x = min(max(x - fx / dfx, 0.0), 2.0)
        return x

    for q in (1e-3, 0.3, 2.0):
        for steps in (1, 3, 8):
            got = float(convex_root(lambda x, q=q: f(x, q), q ** (2 / 3), 0.0, 2.0, steps=steps))
            np.testing.assert_allclose(got, newton(q, q ** (2 / 3), steps), rtol=1e-13)
    # the program: one loop on the CPU, straight-line code for a GPU (lowered here for CUDA
    # without one: `lowering_platforms`), the same under `vmap`
    traced = jax.jit(jax.vmap(lambda q: convex_root(lambda x: f(x, q), q ** (2 / 3), 0.0, 2.0,
                                                    steps=8))).trace(jnp.linspace(0.1, 2.0, 4))
    loops = {p: traced.lower(lowering_platforms=(p,)).as_text().count("stablehlo.while")
             for p in ("cpu", "cuda")}
    assert loops == {"cpu": 1, "cuda": 0}, loops


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_fold_root_is_regular_at_the_fold(dtype):
    # cosh(x) = m on [0, hi]: the minimum (fold) at lo = 0, a double root as m -> 1. From
    # the start min(1.5 sqrt(2 (m - 1)), log(2 m) + 1) (to the right of the root, 50 % off
    # at the fold: cosh x - 1 >= x^2/2, cosh x >= e^x / 2), 5 steps reach NumPy's arccosh to
    # the root's conditioning (the rounding of cosh: eps / sinh x, at the fold sqrt(8 eps))
    # from m - 1 = 1e-14 to m = 1e4; Newton on cosh x - m itself from the same start
    # (`convex_root`, the same steps) is still more than 100 times that far off near the
    # fold, where it halves its error each step.
    eps = float(jnp.finfo(dtype).eps)
    m = 1.0 + np.geomspace(1e-14 if dtype == jnp.float64 else 1e-6, 1e4, 60)
    m = m.astype(dtype)
    want = np.arccosh(m.astype(np.float64))
    hi = dtype(12.0)

    def start(mm):
        return jnp.minimum(1.5 * jnp.sqrt(2.0 * (mm - 1.0)), jnp.log(2.0 * mm) + 1.0)

    def solve(root):
        return jax.jit(jax.vmap(lambda mm: root(lambda x: jnp.cosh(x) - mm, start(mm))))(m)

    got = solve(lambda f, x0: fold_root(f, x0, dtype(0.0), hi, steps=5))
    assert got.dtype == dtype
    x = want
    tol = 8 * eps * x + np.minimum(4 * eps * np.cosh(x) / np.sinh(x), np.sqrt(8 * eps))
    assert np.all(np.abs(np.asarray(got, np.float64) - want) <= tol), \
        np.max(np.abs(np.asarray(got, np.float64) - want) / tol)
    if dtype == jnp.float64:  # (float32's sqrt(8 eps) at the fold hides Newton's 2^-5)
        newton = solve(lambda f, x0: convex_root(f, x0, dtype(0.0), hi, steps=5))
        assert np.max(np.abs(np.asarray(newton, np.float64) - want) / tol) > 100
    # no root in the bracket: lo (m below the minimum), hi (the root beyond it)
    f = lambda mm: lambda x: jnp.cosh(x) - mm  # noqa: E731
    assert float(fold_root(f(dtype(0.5)), dtype(0.1), dtype(0.0), hi, steps=5)) == 0.0
    assert float(fold_root(f(dtype(1e6)), dtype(14.0), dtype(0.0), dtype(3.0), steps=5)) == 3.0
    # implicit derivative: d arccosh(m) / dm = 1 / sinh(x)
    if dtype == jnp.float64:
        d = jax.grad(lambda mm: fold_root(f(mm), start(mm), 0.0, 12.0, steps=5))(3.0)
        np.testing.assert_allclose(d, 1.0 / np.sinh(np.arccosh(3.0)), rtol=1e-12)
    # written out: no loop in the program
    text = jax.jit(jax.vmap(lambda mm: fold_root(f(mm), start(mm), dtype(0.0), hi,
                                                 steps=5))).lower(m).as_text()
    assert "stablehlo.while" not in text


def test_fold_root_round_off_next_to_the_fold_stays_bounded():
    # x - c sqrt(x) = m (a cone's front): U = sqrt(f - f0) is concave, so Newton from the
    # right steps past the fold and lands on `lo`. With `lo` a constant of the compiled
    # program (closed over), f(lo) and f at the iterate x = lo come from differently
    # compiled code and differ by round-off: U' = f'/(2u) was then a ratio of round-off and
    # sent the iterate to 1.2e-4 for a root at 7.7e-13 (5e8 times too far). The fold's own
    # slope is used at lo, and each step stays inside the bracket the evaluations narrow.
    c = 1e-6
    fold = (c / 2) ** 2

    def want(m):  # sqrt(x) = (c + sqrt(c^2 + 4 m)) / 2, the stable root
        return ((c + np.sqrt(c * c + 4 * m)) / 2) ** 2

    def solve(m, lo, steps=6):
        start = jnp.maximum(2 * jnp.maximum(m, 0.0), 4 * c * c)  # right of the root
        return fold_root(lambda x: x - c * jnp.sqrt(x) - m, start, lo, jnp.inf, steps=steps)

    x = fold * np.array([1 + 1e-6, 1.01, 1.5, 3.073, 10.0, 100.0])
    m = x - c * np.sqrt(x)
    ref = np.array([want(mm) for mm in m])
    closed = jax.jit(jax.vmap(lambda mm: solve(mm, jnp.asarray(fold))))(m)
    traced = jax.jit(jax.vmap(solve, in_axes=(0, None)))(m, fold)
    eager = np.array([float(solve(mm, jnp.asarray(fold))) for mm in m])
    # to round-off, but sqrt(eps) at 1e-6 of the fold (a near-double root)
    tol = np.where(x < 1.001 * fold, 1e-8, 1e-13) * ref
    for got in (closed, traced, eager):
        assert np.all(np.abs(np.asarray(got) - ref) <= tol), np.abs(np.asarray(got) - ref) / ref
