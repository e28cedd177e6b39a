"""fitting.preprocess on synthetic raw curves with known truth: baseline tilt (drift), a
slow soft onset, tethers after detachment, a dwell, a retract offset, noise."""

from __future__ import annotations

import numpy as np
import pytest

import fitting

FS = 1000.0  # samples per second
U_S = 1e-6  # base displacement where the probe meets the surface [m]


def synth(seed=0, *, tilt=20e-12, noise=5e-12, a=2.0, tethers=(), retract_shift=0.0):
    """Approach 0 -> 2 µm in 2 s, 1 s dwell, retract in 2 s; Hertz-like force
    ``a (u - U_S)_+^1.5`` [N]; raw force = force + 50 pN + tilt·t + noise (+ a constant
    ``retract_shift`` on the retract); ``tethers``: (force, base displacement where it
    lets go) plateaus after detachment. No cantilever: tip position = base position."""
    rng = np.random.default_rng(seed)
    ta = np.arange(0.0, 2.0, 1 / FS)
    th = np.arange(2.0, 3.0, 1 / FS)
    tr = np.arange(3.0, 5.0, 1 / FS)
    t = np.concatenate([ta, th, tr])
    u = np.concatenate([ta * 1e-6, np.full(len(th), 2e-6), 2e-6 - (tr - 3.0) * 1e-6])
    force = a * np.clip(u - U_S, 0.0, None) ** 1.5
    free_ret = (t >= 3.0) & (u < U_S)
    for depth, end in tethers:
        force = np.where(free_ret & (u > end), force + depth, force)
    seg = np.repeat([0, 1, 2], [len(ta), len(th), len(tr)])
    raw = force + 50e-12 + tilt * t + noise * rng.standard_normal(len(t))
    raw = raw + np.where(t >= 3.0, retract_shift, 0.0)
    curve = fitting.Curve(time=t, displacement=u, force=raw, segment=seg,
                          segment_names=("approach", "hold", "retract"))
    return curve, force


def contact_errors(method, baseline, **kw):
    return np.array([
        fitting.preprocess(synth(s, **kw)[0], baseline=baseline,
                           contact_point=method).contact.tip_position - U_S
        for s in range(3)
    ])


def test_tilted_baseline_linear_fit_recovers_contact():
    err = contact_errors("fit", "linear")
    assert np.all(np.abs(err) < 3e-9)
    # the drift (20 pN/s) read as a constant biases the onset fit by > 8 nm
    assert np.all(contact_errors("fit", "constant") < -8e-9)


def test_linear_baseline_and_noise_recovered():
    c, force = synth(1)
    p = fitting.preprocess(c, baseline="linear")
    cp = p.contact
    assert cp.baseline == "linear" and cp.baseline_region == "approach+retract"
    assert cp.force_slope == pytest.approx(20e-12, abs=2e-12)
    assert cp.force_offset == pytest.approx(50e-12, abs=3e-12)
    assert cp.noise == pytest.approx(5e-12, rel=0.15)
    # the baselined force is the true force within the noise
    assert np.std(p.force - force) == pytest.approx(5e-12, rel=0.15)
    # baseline_force draws exactly what was subtracted
    assert np.allclose(c.force - cp.baseline_force(c.time), p.force, atol=1e-20)
    assert cp.height == c.displacement[cp.index]
    assert cp.time == c.time[cp.index]


def test_baseline_trend_measured_and_flagged():
    """The free force's straight-line trend (``ContactPoint.trend``: its rise from the free
    samples' mean time to the end of the approach) against its closed form, tilt x that
    time; its scatter against the noise put in; its standard error (``trend_error``)
    against the scatter of the trend over 40 noise seeds; the constant baseline's noise
    against sqrt(sigma^2 + A^2/12) (A: the rise over the free samples themselves); and
    the flag (`fitting._quality.baseline_trend`): named for a constant baseline under a
    large, significant trend, not under a linear baseline, not for noise alone."""
    from fitting._quality import baseline_trend

    sigma = 5e-12
    end = 2.0 - 1 / FS  # the last approach sample's time [s]
    for tilt in (50e-12, -50e-12, 0.0):
        c, _ = synth(2, tilt=tilt, noise=sigma)
        cp = fitting.preprocess(c, baseline="constant").contact
        assert cp.baseline_region == "approach"
        n = int(0.9 * cp.index)  # the free samples (the detection's last refit)
        t = c.time[:n]
        assert cp.trend == pytest.approx(tilt * (end - t.mean()), abs=4 * cp.trend_error)
        # the slope itself, and its error (the rise's over the lever arm)
        assert cp.trend_slope == pytest.approx(tilt, abs=4 * cp.trend_slope_error)
        assert cp.trend_slope_error * (end - t.mean()) == pytest.approx(cp.trend_error)
        assert cp.trend_noise == pytest.approx(sigma, rel=0.1)
        free_rise = cp.trend * (t[-1] - t[0]) / (end - t.mean())
        assert cp.noise == pytest.approx(np.hypot(cp.trend_noise, free_rise / np.sqrt(12)),
                                         rel=0.02)
        msgs = baseline_trend([c.replace(contact=cp, source="s.jpk-force")])
        if tilt:  # 50 pN/s over ~1.5 s: ~15 sigma
            (msg,) = msgs
            assert msg.startswith("curve 0 (s.jpk-force)") and "--baseline linear" in msg
            assert "--force-drift" in msg
            # the relaxed model refuses a drift: not offered there
            (other,) = baseline_trend([c.replace(contact=cp)], drift=False)
            assert "--force-drift" not in other and "--baseline linear" in other
            assert ("rises" if tilt > 0 else "falls") in msg
        else:
            assert msgs == []
        lin = fitting.preprocess(c, baseline="linear")
        assert baseline_trend([lin]) == []  # the line is subtracted: nothing left to flag
    trends = [fitting.preprocess(synth(s, tilt=0.0, noise=sigma)[0]).contact
              for s in range(40)]
    errors = np.array([cp.trend_error for cp in trends])
    assert np.std([cp.trend for cp in trends]) == pytest.approx(np.mean(errors), rel=0.3)
    assert np.std([cp.trend_slope for cp in trends]) == pytest.approx(
        np.mean([cp.trend_slope_error for cp in trends]), rel=0.3)
    assert np.mean([abs(cp.trend) >= 5 * cp.trend_error for cp in trends]) == 0


def test_slow_soft_onset():
    # 10x softer: 0.2 nN at 1 µm, the force leaves the noise ~100 nm after contact
    fit = contact_errors("fit", "linear", a=0.2)
    det = contact_errors("detect", "linear", a=0.2)
    assert np.all(np.abs(fit) < 15e-9)
    assert np.all((det > 20e-9) & (det < 250e-9))  # a threshold detects late


def test_tethers_after_detachment_load_without_flags():
    # three detachment steps, the last inside the retract tail: the tail is not free
    c, _ = synth(2, tethers=((-40e-12, 0.8e-6), (-25e-12, 0.5e-6), (-15e-12, 0.2e-6)))
    p = fitting.preprocess(c, baseline="linear", contact_point="fit")
    assert p.segment_names == ("approach", "hold", "retract")
    assert p.contact.baseline_region == "approach"  # the step keeps the tail out
    assert abs(p.contact.tip_position - U_S) < 5e-9
    # the plateaus survive preprocessing (adhesive, negative)
    r = p.mask("retract") & (c.displacement < 0.75e-6) & (c.displacement > 0.55e-6)
    assert np.mean(p.force[r]) == pytest.approx(-40e-12, abs=5e-12)  # -25 - 15 pN


def test_separate_retract_offset():
    c, force = synth(0, tilt=0.0, retract_shift=-60e-12)
    p = fitting.preprocess(c, baseline="constant", retract_baseline="separate")
    cp = p.contact
    assert cp.retract_offset == pytest.approx(-60e-12, abs=2e-12)
    assert cp.retract_time == 3.0
    assert np.allclose(c.force - cp.baseline_force(c.time), p.force, atol=1e-20)
    free = p.mask("retract") & (c.displacement < 0.5e-6)
    assert abs(np.mean(p.force[free])) < 2e-12
    # without it, the free retract sits 60 pN (12 sigma) below zero
    q = fitting.preprocess(c, baseline="constant")
    assert np.mean(q.force[free]) == pytest.approx(-60e-12, abs=2e-12)


def test_dwell_segments_inferred():
    c, _ = synth(0)
    seg, names = fitting.infer_segments(c.time, c.displacement)
    assert names == ("approach", "hold", "retract")
    # the hold takes the samples within hold_tolerance (2 %) of the 2 µm span of the
    # maximum: 40 nm = 40 ms = 40 samples of each ramp at 1 µm/s
    assert np.array_equal(np.bincount(seg), [1960, 40 + 1000 + 41, 1959])


def test_none_options_leave_the_curve():
    c, _ = synth(0)
    p = fitting.preprocess(c, baseline="none", contact_point="none")
    assert np.array_equal(p.force, c.force)
    assert np.array_equal(p.displacement, c.displacement - c.displacement[0])
    assert p.contact.method == "none" and p.contact.baseline == "none"


@pytest.mark.parametrize(
    "kw, word",
    [
        (dict(baseline="quadratic"), "baseline"),
        (dict(contact_point="guess"), "contact_point"),
        (dict(retract_baseline="yes"), "retract_baseline"),
        (dict(baseline_fraction=1.5), "baseline_fraction"),
    ],
)
def test_bad_options_name_the_parameter(kw, word):
    c, _ = synth(0)
    with pytest.raises(ValueError, match=word):
        fitting.preprocess(c, **kw)


def test_no_contact_is_data_error():
    c, _ = synth(0, a=0.0)
    with pytest.raises(fitting.DataError, match="no contact found"):
        fitting.preprocess(c)


def test_steps_are_registered_by_name_and_run_in_the_pipeline_order(monkeypatch):
    # a user lists the steps (named, described); preprocess runs exactly those, in order:
    # each registered function is wrapped by a spy that records its name
    from fitting import _preprocess

    steps = fitting.preprocessing_steps()
    assert list(steps) == ["free_region", "baseline", "contact_index", "retract_baseline",
                           "baseline_trend", "tip_position", "contact_point"]
    assert all(isinstance(d, str) and d for d in steps.values())
    calls = []
    for name, s in list(_preprocess.STEPS.items()):
        def spy(st, fn=s.function, name=name):
            calls.append(name)
            fn(st)
        monkeypatch.setitem(_preprocess.STEPS, name, _preprocess.Step(name, spy, s.description))
    c, _ = synth(1)
    p = fitting.preprocess(c, baseline="linear", contact_point="fit")
    assert calls == list(steps)
    # the result is the pipeline's: the truth of the synthetic curve (see above)
    assert abs(p.contact.tip_position - U_S) < 3e-9 and p.contact.method == "fit"
    with pytest.raises(ValueError, match="'baseline' is registered twice"):
        _preprocess.step("baseline")(lambda st: None)
