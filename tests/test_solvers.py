"""Small shared algorithms of `jaxcontact._solvers`: golden section (traced and on the host) and
the Gauss-Legendre table."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcontact._solvers import gauss_legendre_unit, golden_section, golden_section_host


def test_host_golden_section_takes_the_traced_steps():
    f = lambda x: (x - 0.3) ** 2 + 0.1 * x**4  # noqa: E731 - unimodal on [-1, 2]
    lo, hi = golden_section_host(f, -1.0, 2.0, steps=40)
    lo_j, hi_j = jax.jit(lambda: golden_section(f, jnp.asarray(-1.0), jnp.asarray(2.0),
                                                steps=40))()
    assert lo == pytest.approx(float(lo_j), abs=1e-14) and hi == pytest.approx(float(hi_j), abs=1e-14)
    # the minimiser of f: 2(x - 0.3) + 0.4 x^3 = 0, by numpy's cubic roots
    roots = np.roots([0.4, 0.0, 2.0, -0.6])
    x_star = float(roots[np.abs(roots.imag) < 1e-12].real[0])
    assert lo <= x_star <= hi and hi - lo < 3.0 * 0.62**40


def test_gauss_legendre_on_the_unit_interval():
    u, w = gauss_legendre_unit(8)
    assert np.all((u > 0) & (u < 1)) and w.sum() == pytest.approx(1.0, rel=1e-15)
    for k in range(16):  # exact up to degree 2n - 1 = 15
        assert float(w @ u**k) == pytest.approx(1.0 / (k + 1), rel=1e-13)
    assert float(w @ np.exp(u)) == pytest.approx(math.e - 1.0, rel=1e-13)
    assert gauss_legendre_unit(8)[0] is u  # cached, read-only
    assert not u.flags.writeable
