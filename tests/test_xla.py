"""XLA's options: the fitting programs' chosen per forward model (`fitting._xla`), the CPU's
vector width for every program on the CPU (`jaxcontact._xla`)."""

import jax
import jax.numpy as jnp
import jaxlib
import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting import _programs, _xla
from jaxcontact import _xla as jc_xla
from jaxcontact._sweep import _run

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


@pytest.mark.parametrize("vendor, flags, width", [
    ("AuthenticAMD", "fpu sse2 avx2 avx512f avx512dq", 512),
    ("AuthenticAMD", "fpu sse2 avx2", None),  # no AVX-512
    ("GenuineIntel", "fpu sse2 avx2 avx512f avx512dq", None),  # not measured: XLA's default
    ("", "", None),  # no /proc/cpuinfo (macOS, Windows)
])
def test_vector_width_by_cpu(monkeypatch, vendor, flags, width):
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("JAXCONTACT_XLA_TUNING", raising=False)
    monkeypatch.setattr(jc_xla, "_host_cpu", lambda: (vendor, frozenset(flags.split())))
    assert jc_xla.cpu_vector_width() == width
    expected = {"xla_cpu_prefer_vector_width": width} if (KNOWN and width) else None
    assert jc_xla.cpu_options(platform="cpu") == expected
    assert jc_xla.cpu_options(platform="gpu") is None  # a CPU option only
    # not the fitting's programs (measured slower for the history map's search)
    if KNOWN and jax.default_backend() == "cpu":
        assert _xla.program_options("history") == {"xla_cpu_use_fusion_emitters": False}
        assert _xla.program_options("relaxed") is None
    # the user's choice in XLA_FLAGS wins; JAXCONTACT_XLA_TUNING=0 switches all off
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=256")
    assert jc_xla.cpu_options(platform="cpu") is None
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setenv("JAXCONTACT_XLA_TUNING", "0")
    assert jc_xla.cpu_options(platform="cpu") is None


def test_host_cpu_is_read():
    vendor, flags = jc_xla._host_cpu()
    assert isinstance(vendor, str) and isinstance(flags, frozenset)
    try:
        with open("/proc/cpuinfo") as f:
            text = f.read()
    except OSError:
        assert (vendor, flags) == ("", frozenset())
        return
    assert vendor in text and ("avx2" in flags) == (" avx2" in text)


@pytest.mark.skipif(not KNOWN or jax.default_backend() != "cpu",
                    reason="the option exists in jaxlib 0.10's CPU compiler")
def test_sweep_compiled_with_the_cpu_options_gives_the_same_numbers(monkeypatch):
    # the sweep's chunks are compiled with `cpu_options` of their devices' platform; the
    # vector width changes the code, not the arithmetic: the same summaries as XLA's
    # default width (to round-off) and as the flag off
    seen = []

    def recording(*, platform=None):
        seen.append(platform)
        return jc_xla.cpu_options(platform=platform)

    points = dict(G0=np.array([1e4, 3e4]), G1=5e3, eta1=np.array([7.5e3, 2e2]),
                  work_of_adhesion=5e-3, velocity=1e-6, R=1e-5, depth=1e-6)
    out = {}
    for width in (512, None):
        monkeypatch.setattr(jc_xla, "cpu_vector_width", lambda w=width: w)
        monkeypatch.setattr(_run, "cpu_options", recording)
        _run._compiled.cache_clear()
        ds = jc.sweep(points=points, model=jc.RelaxedStart(samples=64), progress=False)
        out[width] = {k: np.asarray(ds[k]) for k in ("jumpoff_force_N", "separation_work_J")}
    _run._compiled.cache_clear()
    assert seen == ["cpu", "cpu"]
    for k in out[512]:
        np.testing.assert_allclose(out[512][k], out[None][k], rtol=1e-12)


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
