"""XLA's compiler options for the CPU where they make this package's programs faster, and
the one rule of when and which options may be given at all (:func:`given`, also for the
fitting's per-model options, :func:`fitting._xla.program_options`).

**Vector width** (:func:`cpu_options`, the sweep's chunks). XLA compiles its CPU kernels for
256-bit vectors by default (its ``xla_cpu_prefer_vector_width``), also on CPUs with
AVX-512. On AMD's AVX-512 (Zen 4 and later: no clock penalty for 512-bit instructions)
512-bit vectors make the sweep's chunks faster, measured on an AMD EPYC of family 26 (jaxlib
0.10.2; the same numbers to the bit): a 10^3-point relaxed chunk 11 %, 10^5 points up to 20 %
(``benchmarks/results/sweep.md``, section 11). Not the fitting's programs: there the
objective's Jacobian and the search's pool are 8-11 % faster, but the full-history map ran a
third slower in more of its runs (7 of 11 against 2 of 11), the relaxed map the same within
noise (``benchmarks/results/fit_each.md``, "512-bit vectors"). Other
CPUs keep XLA's default: on some Intel parts 512-bit instructions lower the clock, and
nothing else was measured.

Every option is left out where ``XLA_FLAGS`` names it (the user's choice wins), with
``JAXCONTACT_XLA_TUNING=0``, where it is not known to exist (jaxlib other than 0.10: XLA
aborts on an unknown option) and for programs that do not run on the CPU.
"""

from __future__ import annotations

import functools
import os

import jax

__all__ = ["cpu_options", "cpu_vector_width", "given", "tuning_possible"]

#: XLA's option of the preferred vector width of its CPU kernels [bits].
VECTOR_WIDTH_OPTION = "xla_cpu_prefer_vector_width"


@functools.lru_cache(maxsize=1)
def _jaxlib_minor() -> tuple[int, ...]:
    try:
        import jaxlib

        return tuple(int(x) for x in jaxlib.__version__.split(".")[:2])
    except Exception:  # pragma: no cover - unusual installs
        return ()


def tuning_possible() -> bool:
    """Options may be given: not switched off (``JAXCONTACT_XLA_TUNING=0``) and known to
    exist (jaxlib 0.10: an unknown option makes XLA abort)."""
    return (os.environ.get("JAXCONTACT_XLA_TUNING", "1") != "0"
            and _jaxlib_minor() == (0, 10))


@functools.lru_cache(maxsize=1)
def _host_cpu() -> tuple[str, frozenset]:
    """The host CPU's vendor and feature flags (Linux's ``/proc/cpuinfo``; empty elsewhere
    or when it cannot be read)."""
    vendor, flags = "", frozenset()
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                key, _, value = line.partition(":")
                key = key.strip()
                if key == "vendor_id" and not vendor:
                    vendor = value.strip()
                elif key == "flags" and not flags:
                    flags = frozenset(value.split())
                if vendor and flags:
                    break
    except OSError:
        pass
    return vendor, flags


def cpu_vector_width() -> int | None:
    """The vector width [bits] the CPU kernels are compiled for: 512 on AMD CPUs with
    AVX-512 (``avx512f``), else `None` (XLA's default)."""
    vendor, flags = _host_cpu()
    return 512 if vendor == "AuthenticAMD" and "avx512f" in flags else None


def given(options: dict | None, *, platform: str | None = None) -> dict | None:
    """`options` as they may be given to XLA for a program on `platform` (default: JAX's
    default backend), for ``jax.jit(..., compiler_options=...)``; `None` for XLA's defaults:
    nothing on a platform other than the CPU (they are CPU options), with
    ``JAXCONTACT_XLA_TUNING=0`` or with a jaxlib other than 0.10 (:func:`tuning_possible`);
    an option named in ``XLA_FLAGS`` is left to it (the user's choice)."""
    if not options or not tuning_possible() or (platform or jax.default_backend()) != "cpu":
        return None
    flags = os.environ.get("XLA_FLAGS", "")
    chosen = {k: v for k, v in options.items() if k not in flags}
    return chosen or None


def cpu_options(*, platform: str | None = None) -> dict | None:
    """The host's CPU options (:func:`cpu_vector_width`) as they may be given for a program
    on `platform` (:func:`given`)."""
    width = cpu_vector_width()
    return given(None if width is None else {VECTOR_WIDTH_OPTION: width}, platform=platform)
