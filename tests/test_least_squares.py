"""The least-squares drivers on closed-form problems (no contact model: cheap to compile):
per-lane result codes, per-lane step limits, and the local rounds' continuation of a best
end point stopped at the local step limit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitting import LBFGS, RESULTS, LevenbergMarquardt, Solution, _optimise
from fitting._least_squares import run_pool, run_starts
from fitting._parameters import make_parameterisation


def rosenbrock(z, ctx):
    # minimum 0 at z = (1, 1) (closed form)
    return jnp.stack([10.0 * (z[1] - z[0] ** 2), 1.0 - z[0]]) * ctx


def rosenbrock_floor(z, ctx):
    # minimum 1 at z = (1, 1): a loss whose relative changes are not round-off
    return jnp.concatenate([rosenbrock(z, ctx), jnp.ones(1)])


def _pool(solver, z0s, limits=None, workers=2, fn=rosenbrock, bounds=None):
    z0s = jnp.asarray(z0s, dtype=float)
    ctxs = jnp.ones(len(z0s))
    return jax.device_get(run_pool(solver, fn, z0s, ctxs, workers, limits=limits,
                                   bounds=bounds, keep_jacobian=True))


def test_result_code_per_lane():
    # one pool, four lanes: converged, stopped by its own step limit, a non-finite start,
    # and a lane with limit 0 (not run)
    lm = LevenbergMarquardt(max_steps=200)
    z0s = [[-1.2, 1.0], [-1.2, 1.0], [np.nan, 1.0], [-1.2, 1.0]]
    sol = _pool(lm, z0s, limits=np.array([200, 3, 200, 0]))
    assert isinstance(sol, Solution)
    assert sol.result.tolist() == [RESULTS.successful, RESULTS.max_steps_reached,
                                   RESULTS.nonfinite, RESULTS.max_steps_reached]
    assert sol.converged.tolist() == [True, False, False, False]
    np.testing.assert_allclose(sol.z[0], [1.0, 1.0], atol=1e-6)
    assert sol.chi2[0] < 1e-12
    # the step limit: the evaluation at the start counts; stopped when steps > limit
    assert sol.steps[1] == 4 and sol.chi2[1] > 1e-3
    assert sol.steps[2] == 1 and not np.isfinite(sol.chi2[2])
    assert sol.steps[3] == 0 and sol.chi2[3] == np.inf
    # the Jacobian kept at the end point is the exact one (closed form)
    x, y = sol.z[0]
    np.testing.assert_allclose(sol.J[0], [[-20.0 * x, 10.0], [-1.0, 0.0]], rtol=1e-12)
    assert RESULTS.describe(sol.result[1]) == "stopped at the step limit"


def test_solver_step_limit_without_limits_argument_and_lbfgs_codes():
    # the solver's own max_steps stops a lane (step limit), as before
    sol = jax.device_get(run_starts(LevenbergMarquardt(max_steps=2), rosenbrock,
                                    jnp.asarray([[-1.2, 1.0]]), 1.0))
    assert sol.result.tolist() == [RESULTS.max_steps_reached] and sol.steps[0] == 3
    lb = _pool(LBFGS(max_steps=500), [[-1.2, 1.0], [-1.2, 1.0], [np.nan, 0.0]],
               limits=np.array([500, 2, 500]))
    assert lb.result.tolist() == [RESULTS.successful, RESULTS.max_steps_reached,
                                  RESULTS.nonfinite]
    assert lb.r is None and lb.J is None  # L-BFGS carries no Jacobian
    np.testing.assert_allclose(lb.z[0], [1.0, 1.0], atol=1e-4)


def _two_rosenbrock_problems():
    """The parameterisation of two bounded coordinates, a `run(starts, limits, bounds)` of
    the pool per problem on the floored Rosenbrock function that records the limits of each
    call (`calls`; the bounds in `run.bounds`), and four starts."""
    info = [("a", "1", "modulus"), ("b", "1", "modulus")]
    param = make_parameterisation(info, {"a": 1.0, "b": 1.0},
                                  bounds={"a": (1e-3, 1e3), "b": (1e-3, 1e3)})
    lm = LevenbergMarquardt(max_steps=200)
    calls = []

    def run(starts, limits, bounds=None):
        calls.append([np.asarray(lim).tolist() for lim in limits])
        bounds = [None] * len(starts) if bounds is None else bounds
        run.bounds.append([None if b is None else np.asarray(b).tolist() for b in bounds])
        return [_pool(lm, zs, limits=lim, fn=rosenbrock_floor, bounds=b)
                for zs, lim, b in zip(starts, limits, bounds, strict=True)]

    run.bounds = []  # the bounds on chi2 of each call
    z0 = np.array([[-1.2, 1.0], [-1.0, 2.0], [2.0, 2.0], [0.0, -1.0]])
    return param, run, calls, z0


def test_local_rounds_skip_problems_whose_rounds_are_done():
    # two problems in one pool: the first's local round improves (its global search was
    # stopped early), the second's does not (already at the closed-form minimum): the
    # second's rounds end after the widest one, and from then on its starts get limit 0
    # (not run) while the first's still run with max_steps
    param, run, calls, z0 = _two_rosenbrock_problems()
    n = len(z0)
    first = run([z0, z0], [np.full(n, 2), np.full(n, 200)])
    assert not np.any(first[0].converged) and np.all(first[1].converged)
    out = _optimise._local_search([param, param], first, run, n=n, local_rounds=4, seed=0,
                                  max_steps=200, explore_steps=200,
                                  limits=[np.full(n, 2), np.full(n, 200)])
    # the second problem: widths 1, 2.5, 6.25 without a decrease, then done
    assert [c[1] for c in calls[1:]] == [[200] * n] * 3 + [[0] * n]
    assert calls[4][0] == [200] * n
    assert len(out[1].chi2) == 4 * n and len(out[0].chi2) == 5 * n
    for o in out:
        best = int(np.argmin(o.chi2))
        assert o.result[best] == RESULTS.successful
        assert o.chi2[best] == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(o.z[best], [1.0, 1.0], atol=1e-6)


def test_exploring_starts_and_the_best_continued():
    # with explore_steps, a round's starts but the first (the best so far, continued) get
    # the exploring limit; a best end point stopped at an exploring limit is continued with
    # max_steps after the rounds, and reaches the closed-form minimum (1, 1); a problem
    # whose best converged is not run again (limit 0)
    param, run, calls, z0 = _two_rosenbrock_problems()
    n = len(z0)
    first = run([z0, z0], [np.full(n, 2), np.full(n, 200)])
    out = _optimise._local_search([param, param], first, run, n=n, local_rounds=1, seed=0,
                                  max_steps=200, explore_steps=2,
                                  limits=[np.full(n, 2), np.full(n, 200)])
    assert calls[1] == [[200, 2, 2, 2]] * 2
    # problem 0's best start of the round converged from the continued best; problem 1 was
    # at its minimum: the continuation only where needed
    assert len(calls) == 2 or calls[2][1] == [0] * n
    for o in out:
        best = int(np.argmin(o.chi2))
        assert o.result[best] == RESULTS.successful
        np.testing.assert_allclose(o.z[best], [1.0, 1.0], atol=1e-6)
    # no rounds: the global search's best, stopped at the exploring limit 2, is continued
    calls.clear()
    first = run([z0, z0], [np.full(n, 2), np.full(n, 200)])
    out = _optimise._local_search([param, param], first, run, n=n, local_rounds=0, seed=0,
                                  max_steps=200, explore_steps=2,
                                  limits=[np.full(n, 2), np.full(n, 200)])
    assert calls[1] == [[200, 0, 0, 0], [0] * n]
    assert len(out[0].chi2) == n + 1 and len(out[1].chi2) == n
    best = int(np.argmin(out[0].chi2))
    assert best == n and out[0].result[best] == RESULTS.successful
    np.testing.assert_allclose(out[0].z[best], [1.0, 1.0], atol=1e-6)


@pytest.mark.parametrize("limit", [0, 1])
def test_pool_with_fewer_lanes_than_tasks_writes_every_task(limit):
    # six tasks on two lanes, mixed limits: every task written once, in its own slot
    z0s = [[-1.2, 1.0], [0.5, 0.5], [-1.2, 1.0], [2.0, 3.0], [0.0, 0.0], [1.0, 1.0]]
    limits = np.array([200, limit, 200, 200, limit, 200])
    sol = _pool(LevenbergMarquardt(), z0s, limits=limits)
    run = limits > 0
    assert np.all(sol.converged[limits == 200])
    assert np.all(sol.steps[~run] == 0) and np.all(sol.steps[run] >= 1)
    np.testing.assert_allclose(sol.z[limits == 200], 1.0, atol=1e-6)


@pytest.mark.parametrize("solver", [LevenbergMarquardt(max_steps=200), LBFGS(max_steps=500)])
def test_pool_with_a_lane_per_problem_equals_the_queued_pool(solver):
    # the accelerator schedule (every problem its own lane: no queue) ends every problem
    # where the queued pool of 2 lanes ends it, codes, step counts and limits per problem
    # included (each problem's trajectory is its own); the end points are the closed-form
    # minimum (1, 1)
    z0s = [[-1.2, 1.0], [0.5, 2.0], [np.nan, 1.0], [-1.2, 1.0], [2.0, 3.0]]
    limits = np.array([200, 200, 200, 3, 0])
    queued = _pool(solver, z0s, limits=limits, workers=2)
    every = _pool(solver, z0s, limits=limits, workers=len(z0s))
    assert every.result.tolist() == queued.result.tolist()
    assert every.steps.tolist() == queued.steps.tolist()
    np.testing.assert_allclose(every.z, queued.z, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(every.chi2, queued.chi2, rtol=1e-10, atol=1e-20)
    np.testing.assert_allclose(every.z[[0, 1]], 1.0, atol=1e-4)
    if every.J is not None:
        np.testing.assert_allclose(every.J, queued.J, rtol=1e-12)


def test_pool_lanes_past_the_queue_step_stand_ins_that_are_never_written():
    # more lanes than problems to run (three of five not run: limit 0): the not-run
    # problems take no lane and read their initial states, the lanes past the queue step
    # stand-ins whose states are never written, and a lane whose problem has finished
    # keeps stepping (no choice of its old state) after its result was written: every
    # problem ends where the schedule with a lane per problem (each lane's own state kept
    # once done) ends it
    z0s = [[0.5, 2.0], [-1.2, 1.0], [2.0, 3.0], [0.0, 0.0], [2.0, 3.0]]
    limits = np.array([0, 200, 0, 0, 4])
    for workers in (2, 4):
        queued = _pool(LevenbergMarquardt(max_steps=200), z0s, limits=limits,
                       workers=workers)
        every = _pool(LevenbergMarquardt(max_steps=200), z0s, limits=limits,
                      workers=len(z0s))
        assert queued.steps.tolist() == every.steps.tolist() == [0, every.steps[1], 0, 0, 5]
        assert queued.result.tolist() == every.result.tolist()
        np.testing.assert_array_equal(queued.z, every.z)
        np.testing.assert_array_equal(queued.J, every.J)
        assert queued.converged[1] and np.all(np.isinf(queued.chi2[[0, 2, 3]]))
        np.testing.assert_allclose(queued.z[1], 1.0, atol=1e-6)


def test_a_run_above_its_bound_is_abandoned_after_its_steps():
    """A bound on chi2 stops a run that is still above it after ABANDON_AFTER steps (the
    first evaluation counted), with RESULTS.abandoned; a run below its bound, or with an
    infinite one, runs as without bounds: the same steps, end point and chi2 to the bit.
    Checked against the same starts run without bounds (a second run of the pool)."""
    from fitting._least_squares import ABANDON_AFTER

    lm = LevenbergMarquardt(max_steps=200)
    z0s = [[-1.2, 1.0], [-1.2, 1.0], [-1.2, 1.0], [3.0, -2.0]]
    free = _pool(lm, z0s, workers=2)
    assert free.result.tolist() == [RESULTS.successful] * 4
    # the chi2 of each run after ABANDON_AFTER steps, from a run stopped there by its limit
    early = _pool(lm, z0s, limits=np.full(4, ABANDON_AFTER - 1), workers=2)
    assert early.steps.tolist() == [ABANDON_AFTER] * 4
    above = early.chi2[1] * 0.5  # lane 1 is still above this bound after its steps
    bounds = np.array([np.inf, above, early.chi2[2] * 2.0, np.inf])
    for workers in (2, 4):  # the queue, and a lane per problem
        sol = _pool(lm, z0s, bounds=bounds, workers=workers)
        assert sol.result.tolist() == [RESULTS.successful, RESULTS.abandoned,
                                       RESULTS.successful, RESULTS.successful]
        assert sol.steps[1] == ABANDON_AFTER and sol.chi2[1] > above
        assert sol.chi2[1] == early.chi2[1]
        np.testing.assert_array_equal(sol.z[1], early.z[1])
        for i in (0, 2, 3):
            assert sol.steps[i] == free.steps[i] and sol.chi2[i] == free.chi2[i]
            np.testing.assert_array_equal(sol.z[i], free.z[i])
    assert RESULTS.describe(RESULTS.abandoned).startswith("abandoned")
    # L-BFGS: the same rule (the driver's, through the solver's chi2)
    lb = _pool(LBFGS(max_steps=500), z0s[:2], bounds=np.array([np.inf, 1e-30]), workers=2)
    assert lb.result.tolist() == [RESULTS.successful, RESULTS.abandoned]
    assert lb.steps[1] == ABANDON_AFTER


def test_local_rounds_bound_their_exploring_starts():
    """A local round that is not widened gives every start but the continued best the bound
    `abandon` x the best chi2 known before the round; a widened round (after one without
    progress), the global search, the continued best and the continuation of a best
    stopped at its limit have none (infinite)."""
    param, run, calls, z0 = _two_rosenbrock_problems()
    n = len(z0)
    first = run([z0, z0], [np.full(n, 2), np.full(n, 200)])
    before = [float(np.min(o.chi2)) for o in first]
    out = _optimise._local_search([param, param], first, run, n=n, local_rounds=2, seed=0,
                                  max_steps=200, explore_steps=2, abandon=10.0,
                                  limits=[np.full(n, 2), np.full(n, 200)])
    one, two = run.bounds[1], run.bounds[2]
    for j in range(2):  # the first round: neither is widened
        assert one[j][0] == np.inf
        np.testing.assert_allclose(one[j][1:], 10.0 * before[j], rtol=1e-15)
    # the second round: problem 0 improved in the first (its global search was stopped
    # early), problem 1 did not (at its minimum already): its round is widened, unbounded
    assert np.min(out[0].chi2[n:2 * n]) < before[0] * (1 - 1e-7)
    assert one != two and two[0][0] == np.inf and two[0][1] < np.inf
    assert all(b == np.inf for b in two[1])
    for later in run.bounds[3:]:  # the continuation of a best stopped at its limit
        assert all(b == np.inf for lane in later for b in lane)
    # without `abandon`, no bound
    run.bounds.clear()
    _optimise._local_search([param, param], first, run, n=n, local_rounds=1, seed=0,
                            max_steps=200, explore_steps=2, abandon=None,
                            limits=[np.full(n, 2), np.full(n, 200)])
    assert all(b == np.inf for call in run.bounds for lane in call for b in lane)
