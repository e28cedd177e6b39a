"""The on-disk cache of traced programs (`fitting._programs`): the search's pool through it
gives the results of the traced program to the bit, a later call loads the program
instead of tracing it, and a damaged file or another key is traced again."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting import _optimise as O
from fitting import _programs

R = 12e-6


@pytest.fixture(scope="module")
def problem():
    ts = np.linspace(0.0, 1.5, 40)
    sol = jc.retract(jc.StandardModel(10e3, 5e3, 7.5e3), jc.Parabola(R), work_of_adhesion=1e-3,
                     depth=1e-6, ts=ts, velocity=2e-6)
    f = np.asarray(sol.force) + 0.01 * np.ptp(sol.force) * np.random.default_rng(0).standard_normal(40)
    curve = fitting.Curve(time=ts, displacement=np.asarray(sol.displacement), force=f,
                          segment=np.zeros(40, int), segment_names=("retract",))
    opts = fitting.FitOptions(radius=R, n_starts=4, progress=False)
    pb = O._problem([curve], opts, rheology="standard", contact_point="fixed", previous=None)
    n = len(pb.zs)
    return pb.spec, O._stack([pb.param], n), O._stack([pb.data], n), pb.zs


def _solve(problem, **kw):
    spec, params, datas, zs = problem
    out = O.solve_batch(spec, params, datas, zs, workers=2, max_steps=40, keep_jacobian=True,
                        **kw)
    return jax.tree.map(np.asarray, out)


def test_cached_program_equals_the_traced_one_and_is_loaded_later(problem, tmp_path,
                                                                  monkeypatch):
    _programs.enable(None)
    native = _solve(problem)
    try:
        assert _programs.enable(tmp_path)
        first = _solve(problem)  # traced and written
        files = sorted(tmp_path.glob("solve_batch-*.jaxexport"))
        assert len(files) == 1 and files[0].stat().st_size > 1000
        assert not list(tmp_path.glob("*.tmp"))  # written whole, renamed into place

        def no_trace(*a, **k):
            raise AssertionError("traced again although the program is on disk")

        monkeypatch.setattr(jax.export, "export", no_trace)
        _programs.enable(tmp_path)  # as a new process: nothing loaded yet
        again = _solve(problem)  # loaded from the file, not traced
        assert _solve(problem).steps.tolist() == again.steps.tolist()  # kept in memory
        for a, b, c in zip(jax.tree.leaves(native), jax.tree.leaves(first),
                           jax.tree.leaves(again), strict=True):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, c)
    finally:
        _programs.enable(None)


def test_damaged_file_and_other_keys_are_traced_again(tmp_path, monkeypatch):
    """A file that cannot be read is traced again and replaced; another static option or
    argument shape is another key (another file): no program serves a call it was not
    traced for."""
    traces = []
    export = jax.export.export

    def counted(*a, **k):
        traces.append(1)
        return export(*a, **k)

    monkeypatch.setattr(jax.export, "export", counted)

    @functools.partial(jax.jit, static_argnames=("power",))
    def f(x, *, power):
        return x**power

    def call(x, power):
        run = _programs.cached("f", f, (jnp.asarray(x),), {"power": power},
                               flatten_out=lambda y: (y,), unflatten_out=lambda t: t[0])
        return np.asarray(run())

    try:
        assert _programs.enable(tmp_path)
        np.testing.assert_array_equal(call(np.arange(3.0), 2), np.arange(3.0) ** 2)
        (path,) = tmp_path.glob("f-*.jaxexport")
        path.write_bytes(b"not a program")
        _programs.enable(tmp_path)  # as a new process
        np.testing.assert_array_equal(call(np.arange(3.0), 2), np.arange(3.0) ** 2)
        assert path.stat().st_size > 100 and len(traces) == 2
        np.testing.assert_array_equal(call(np.arange(3.0), 3), np.arange(3.0) ** 3)
        np.testing.assert_array_equal(call(np.arange(4.0), 2), np.arange(4.0) ** 2)
        assert len(list(tmp_path.glob("f-*.jaxexport"))) == 3 and len(traces) == 4
    finally:
        _programs.enable(None)


def test_off_by_default_and_without_a_folder(problem):
    assert _programs.enable(None) is False
    spec, params, datas, zs = problem
    assert _programs.cached("solve_batch", O._solve_batch, (spec, params, datas,
                                                             jnp.asarray(zs)), {},
                            flatten_out=tuple, unflatten_out=tuple) is None


def test_threads_asking_for_one_new_program_trace_it_once(tmp_path, monkeypatch):
    """Threads that ask for the same program at once (the search's chunks in threads) get
    one trace and one program: the first traces it, the others wait for it."""
    import threading
    import time

    traces = []
    export = jax.export.export

    def slow(*a, **k):  # a trace that takes a while: the other threads ask meanwhile
        traces.append(1)
        time.sleep(0.2)
        return export(*a, **k)

    monkeypatch.setattr(jax.export, "export", slow)

    @jax.jit
    def f(x):
        return 2.0 * x

    got = []

    def ask():
        run = _programs.cached("g", f, (jnp.arange(3.0),), {},
                               flatten_out=lambda y: (y,), unflatten_out=lambda t: t[0])
        got.append(np.asarray(run()))

    try:
        assert _programs.enable(tmp_path)
        threads = [threading.Thread(target=ask) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(traces) == 1 and len(list(tmp_path.glob("g-*.jaxexport"))) == 1
        assert len(got) == 3
        for y in got:
            np.testing.assert_array_equal(y, 2.0 * np.arange(3.0))
    finally:
        _programs.enable(None)
