"""The on-disk cache of traced programs (`fitting._programs`): the search's pool through it
gives the results of the traced program to the bit, a later call loads the program
instead of tracing it, and a damaged file or another key is traced again."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting import _optimise as O
from fitting import _programs

pytest.importorskip("flatbuffers")

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
        # a damaged file is traced again and replaced
        monkeypatch.undo()
        files[0].write_bytes(b"not a program")
        _programs.enable(tmp_path)
        fixed = _solve(problem)
        np.testing.assert_array_equal(fixed.chi2, native.chi2)
        assert files[0].stat().st_size > 1000
        # another static option (the tolerance) is another key: a second file
        _solve(problem, rtol=1e-6)
        assert len(list(tmp_path.glob("solve_batch-*.jaxexport"))) == 2
    finally:
        _programs.enable(None)


def test_off_by_default_and_without_a_folder(problem):
    assert _programs.enable(None) is False
    spec, params, datas, zs = problem
    assert _programs.cached("solve_batch", O._solve_batch, (spec, params, datas,
                                                             jnp.asarray(zs)), {},
                            flatten_out=tuple, unflatten_out=tuple) is None
