"""XLA options for the CPU that make the fitting programs faster: per compiled program, by
forward model (:func:`program_options`, :class:`ModelJit`: the one home of that choice), and
for a whole process (:func:`tune_xla_cpu`). Whether, when and which options may be given at
all is :func:`jaxcontact._xla.given`'s (one rule for the package)."""

from __future__ import annotations

import functools
import os
import sys

import jax

from jaxcontact._xla import given, tuning_possible

__all__ = ["XLA_CPU_FLAGS", "tune_xla_cpu", "program_options", "ModelJit"]


#: The fitting programs' own XLA options by forward model (:func:`program_options`). XLA's
#: newer CPU fusion emitters compile the full-history model's search 1.8x slower than the
#: older ones, and the relaxed model's search 1.2x faster (jaxlib 0.10.2, 2-core AMD EPYC,
#: 2026-11-27: `benchmarks/results/fit_each.md`, "XLA's code generator chosen per model").
_PROGRAM_OPTIONS = {"history": {"xla_cpu_use_fusion_emitters": False}}

#: XLA options for the CPU that ``jaxcontact fit --model history`` applies to its whole
#: process (see `tune_xla_cpu`): the history model's program options as flags.
XLA_CPU_FLAGS = tuple(f"--{k}={str(v).lower()}" for k, v in _PROGRAM_OPTIONS["history"].items())


def program_options(model: str) -> dict | None:
    """The XLA compiler options of a fitting program of the forward model `model`
    ("relaxed" or "history"), for ``jax.jit(..., compiler_options=...)``; `None`: XLA's
    defaults (or what ``XLA_FLAGS`` says).

    The full-history model's search runs XLA's older CPU fusion emitters
    (``xla_cpu_use_fusion_emitters=False``), the relaxed model's the default newer ones
    (`_PROGRAM_OPTIONS`, measured). Not the sweep's 512-bit vectors on AMD's AVX-512
    (:func:`jaxcontact._xla.cpu_options`): they make the search's pool faster but the
    full-history map slower in more of its runs (``benchmarks/results/fit_each.md``,
    "512-bit vectors"). An option of a program overrides the process's ``XLA_FLAGS``, so
    none is given where ``XLA_FLAGS`` already names it (the user's choice), with
    ``JAXCONTACT_XLA_TUNING=0``, where the option is not known to exist (jaxlib other
    than 0.10: an unknown option fails the compilation), or where JAX's default backend
    is not the CPU (the option chooses the CPU's code generator only). Results agree to
    round-off."""
    return given(_PROGRAM_OPTIONS.get(model))


class ModelJit:
    """``jax.jit(fun, **jit_keywords)`` compiled with :func:`program_options` of the
    forward model of its first argument (a :class:`fitting.ModelSpec`): one jitted
    function per set of options, so that a relaxed and a full-history fit in one process
    each get their code generator. Calls, ``.trace``, ``.lower`` and ``.clear_cache`` as of
    the jitted function."""

    def __init__(self, fun, **jit_keywords):
        functools.update_wrapper(self, fun)
        self._fun, self._keywords, self._jitted = fun, jit_keywords, {}

    def jitted(self, model: str):
        """The jitted function with the options of `model`."""
        options = program_options(model)
        key = tuple(sorted(options.items())) if options else ()
        fn = self._jitted.get(key)
        if fn is None:  # (two threads at once: both use the first one stored)
            fn = self._jitted.setdefault(key, jax.jit(self._fun, compiler_options=options,
                                                      **self._keywords))
        return fn

    def _for(self, args, kwargs):
        spec = args[0] if args else kwargs["spec"]  # (a keyword `spec` as well)
        return self.jitted(spec.model)

    def __call__(self, *args, **kwargs):
        return self._for(args, kwargs)(*args, **kwargs)

    def trace(self, *args, **kwargs):
        return self._for(args, kwargs).trace(*args, **kwargs)

    def lower(self, *args, **kwargs):
        return self._for(args, kwargs).lower(*args, **kwargs)

    def clear_cache(self) -> None:
        """Forget the traces and compilations of every jitted function (as
        ``jax.jit(...).clear_cache()``)."""
        for fn in self._jitted.values():
            fn.clear_cache()


def model_jit(**jit_keywords):
    """Decorator: :class:`ModelJit` of the decorated function with `jit_keywords`."""
    return lambda fun: ModelJit(fun, **jit_keywords)


def tune_xla_cpu() -> list[str]:
    """Add `XLA_CPU_FLAGS` to ``XLA_FLAGS`` before JAX starts its CPU backend.

    XLA's newer CPU fusion emitters compile the element-wise kernels of the full-history
    model's residuals and their forward-mode tangents into slower code than the previous
    emitters with jaxlib 0.10 (``python benchmarks/bench_fit.py`` and ``--no-xla-tuning``
    measure it and print which flags were active); the fitting's own search programs choose
    per model without it (:func:`program_options`), so this matters for the other
    programs of a history-model fit (the posterior's sampler, a profile likelihood). The
    flag only chooses the code generator; results agree to round-off (the test suite
    passes either way). Applied only where it is known to exist (jaxlib 0.10: an unknown
    flag makes XLA abort), only before the backend has started, never over a choice made in
    ``XLA_FLAGS`` already, and not at all with ``JAXCONTACT_XLA_TUNING=0``. Returns the
    flags added. ``jaxcontact fit --model history`` and ``benchmarks/bench_fit.py`` call
    this first; library users who fit the history model may call it at the top of a
    script, before any JAX computation. Not for forward runs, nor relaxed-model fits: the
    same code generator makes them slower (a full-history sweep 1.5x in float64, the
    relaxed-start `retract` 5-8x in float32, the relaxed model's search 1.2x; jaxlib
    0.10.2, 2-core CPU), so the other commands of the command line keep XLA's default.
    """
    if not tuning_possible():
        return []
    if "jax" in sys.modules:
        from jax._src import xla_bridge

        if getattr(xla_bridge, "_backends", None):
            return []  # the backend has started; XLA_FLAGS is no longer read
    current = os.environ.get("XLA_FLAGS", "")
    added = [f for f in XLA_CPU_FLAGS if f.split("=")[0] not in current]
    if added:
        os.environ["XLA_FLAGS"] = " ".join([current, *added]).strip()
    return added
