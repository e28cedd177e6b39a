import os

# Compilation dominates the suite's time (each test compiles its own programs), so the
# suite runs XLA's CPU backend as `jaxcontact fit --model history` does (`fitting.XLA_CPU_FLAGS`,
# added by `fitting.tune_xla_cpu` below: the code generator the main job uses; the relaxed
# model's fits run XLA's default outside the suite) and without LLVM's
# optimisation passes (`--xla_backend_optimization_level=0`). Neither changes IEEE
# arithmetic (no fast math); together they cut the suite's CPU time by about a third
# (measured 2026-11-24: tests/test_pulloff.py + test_elastic.py 136 -> 55 s,
# test_fitting_history.py + the fitting notebook 173 -> 112 s, same results). An
# `XLA_FLAGS` already set wins; `JAXCONTACT_XLA_TUNING=0` keeps XLA's defaults for the code
# generator. Subprocesses started by tests inherit the environment.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_backend_optimization_level=0").strip()
# The command line keeps a persistent compilation cache; in-process in a test session it
# would serialise every later program of the worker to disk (measured: slower, and no
# program is compiled twice across tests the way the cache could serve).
os.environ.setdefault("JAXCONTACT_NO_CACHE", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
# Strict rank promotion (as diffrax's test suite): arrays of different rank never broadcast
# implicitly; the code broadcasts explicitly.
jax.config.update("jax_numpy_rank_promotion", "raise")

import fitting  # noqa: E402

fitting.tune_xla_cpu()  # before the first computation: the backend reads XLA_FLAGS once

