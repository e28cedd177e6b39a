import os

# The command line's `main` adds XLA CPU options (jaxcontact.cli.tune_xla_cpu) when it runs
# before the first JAX computation; in a test session that would depend on which test runs
# first. Tests run XLA's defaults unless the environment says otherwise
# (test_cli.py::test_tune_xla_cpu checks the tuning in a fresh process).
os.environ.setdefault("JAXCONTACT_XLA_TUNING", "0")
# The command line keeps a persistent compilation cache; in-process in a test session it
# would serialise every later program of the worker to disk (measured: slower, and no
# program is compiled twice across tests the way the cache could serve).
os.environ.setdefault("JAXCONTACT_NO_CACHE", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
# Strict rank promotion (as diffrax's test suite): arrays of different rank never broadcast
# implicitly; the code broadcasts explicitly.
jax.config.update("jax_numpy_rank_promotion", "raise")

