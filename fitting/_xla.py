"""XLA options for the CPU that make the fitting Jacobian faster (`tune_xla_cpu`)."""

from __future__ import annotations

import os
import sys

__all__ = ["XLA_CPU_FLAGS", "tune_xla_cpu"]


#: XLA options for the CPU that ``jaxcontact fit`` applies (see `tune_xla_cpu`).
XLA_CPU_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def tune_xla_cpu() -> list[str]:
    """Add `XLA_CPU_FLAGS` to ``XLA_FLAGS`` before JAX starts its CPU backend.

    XLA's newer CPU fusion emitters compile the element-wise kernels of the fitting
    residuals and their forward-mode tangents into slower code than the previous emitters
    with jaxlib 0.10 (``python benchmarks/bench_fit.py`` and ``--no-xla-tuning`` measure
    it and print which flags were active). The
    flag only chooses the code generator; results agree to round-off (the test suite
    passes either way). Applied only where it is known to exist (jaxlib 0.10: an unknown
    flag makes XLA abort), only before the backend has started, never over a choice made in
    ``XLA_FLAGS`` already, and not at all with ``JAXCONTACT_XLA_TUNING=0``. Returns the
    flags added. ``jaxcontact fit`` and ``benchmarks/bench_fit.py`` call this first; library
    users who fit may call it at the top of a script, before any JAX computation. Not for
    forward runs: the same code generator makes them slower (a full-history sweep 1.5x in
    float64, the relaxed-start `retract` 5-8x in float32; jaxlib 0.10.2, 2-core CPU), so the
    other commands of the command line keep XLA's default.
    """
    if os.environ.get("JAXCONTACT_XLA_TUNING", "1") == "0":
        return []
    try:
        import jaxlib

        version = tuple(int(x) for x in jaxlib.__version__.split(".")[:2])
    except Exception:  # pragma: no cover - unusual installs
        return []
    if version != (0, 10):
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
