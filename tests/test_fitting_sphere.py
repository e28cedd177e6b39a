"""Fitting with the exact sphere: curves deep in the sphere (a0 = 0.7 R, far beyond the
paraboloid's 0.3 R) are fitted back by `profile=jc.Sphere(R)`."""

import warnings

import numpy as np
import pytest

import fitting
import jaxcontact as jc

R = 10e-6
A0 = 0.7 * R
D0 = 0.5 * A0 * np.log((R + A0) / (R - A0))  # Sneddon: g(a0) = d0
TRUE = {"G0": 10e3, "G1": 5e3, "eta1": 7.5e3, "work_of_adhesion": 2e-3}


def _curves(profile):
    out = []
    rh = jc.StandardModel(TRUE["G0"], TRUE["G1"], TRUE["eta1"])
    for v in (2e-6, 8e-6):
        ts = np.linspace(0.0, 1.2 * D0 / v, 40)
        sol = jc.retract(rh, profile, work_of_adhesion=TRUE["work_of_adhesion"], depth=D0,
                         ts=ts, velocity=v)
        out.append(fitting.Curve(time=ts, displacement=np.asarray(sol.displacement),
                                 force=np.asarray(sol.force), segment=np.zeros(40, int),
                                 segment_names=("retract",)))
    return out


@pytest.mark.slow  # extended: `python -m pytest -m slow` (the default run's time)
def test_fit_with_the_exact_sphere_recovers_the_parameters():
    sphere = jc.Sphere(R)
    curves = _curves(sphere)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fitting.IdentifiabilityWarning)
        warnings.simplefilter("ignore", fitting.ModelValidityWarning)
        res = fitting.fit(curves, profile=sphere, model="relaxed", n_starts=2, local_rounds=1,
                          progress=False)
    for k, v in TRUE.items():
        assert abs(res[k] / v - 1) < 0.01, (k, res[k])
    assert res.r_squared > 0.99999
    assert res.radius == R and res.profile is sphere
