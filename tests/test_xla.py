"""The fitting programs' XLA options chosen per forward model (`fitting._xla`)."""

import jax
import jax.numpy as jnp
import jaxlib
import numpy as np
import pytest

import fitting
from fitting import _programs, _xla

KNOWN = tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) == (0, 10)
# XLA's newer CPU fusion emitters wrap single operations into fusions of their own
# ("wrapped_..." in the compiled HLO); the older ones do not: which generator compiled a
# program shows in its text
NEWER = "wrapped_"


def _program(x):
    return jnp.cumsum(jnp.sort(jnp.exp(x)))


def test_program_options_by_model(monkeypatch):
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("JAXCONTACT_XLA_TUNING", raising=False)
    history = _xla.program_options("history")
    assert history == ({"xla_cpu_use_fusion_emitters": False} if KNOWN else None)
    assert _xla.program_options("relaxed") is None  # XLA's default generator
    # the user's own choice in XLA_FLAGS is not overridden
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert _xla.program_options("history") is None
    monkeypatch.delenv("XLA_FLAGS")
    with monkeypatch.context() as m:  # another platform: the CPU's option is not given
        m.setattr(_xla.jax, "default_backend", lambda: "gpu")
        assert _xla.program_options("history") is None
    monkeypatch.setenv("JAXCONTACT_XLA_TUNING", "0")
    assert _xla.program_options("history") is None


@pytest.mark.skipif(not KNOWN or jax.default_backend() != "cpu",
                    reason="the option exists in jaxlib 0.10's CPU compiler")
def test_each_model_is_compiled_with_its_options(monkeypatch, tmp_path):
    # the suite's process runs the older generator for everything (XLA_FLAGS, conftest);
    # a model whose program options ask for the newer one gets it, the other keeps the
    # process's: the options reach the compiler, per model, for a jitted program and for
    # a program loaded from the on-disk cache of traced programs
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("JAXCONTACT_XLA_TUNING", raising=False)
    monkeypatch.setattr(_xla, "_PROGRAM_OPTIONS",
                        {"history": {"xla_cpu_use_fusion_emitters": True}})
    fn = _xla.ModelJit(lambda spec, x: _program(x))
    x = jnp.linspace(0.0, 1.0, 64)
    history, relaxed = fitting.make_spec("history"), fitting.make_spec("relaxed")
    assert NEWER in fn.lower(history, x).compile().as_text()
    assert NEWER not in fn.lower(relaxed, x).compile().as_text()
    np.testing.assert_array_equal(fn(history, x), fn(relaxed, x))  # the same answers
    np.testing.assert_array_equal(fn(spec=history, x=x), fn(history, x))  # keywords too

    try:
        assert _programs.enable(tmp_path)
        for model, newer in (("history", True), ("relaxed", False)):
            options = _xla.program_options(model)
            run = _programs.cached("test_xla", lambda v: _program(v), (x,), {},
                                   flatten_out=lambda out: (out,),
                                   unflatten_out=lambda out: out[0],
                                   compiler_options=options)
            np.testing.assert_array_equal(run(), _program(x))
            key = next(k for k in _programs._LOADED if k[1] == tuple(sorted(
                (options or {}).items())))
            text = _programs._LOADED[key].lower(x).compile().as_text()
            assert (NEWER in text) == newer, model
    finally:
        _programs.enable(None)
