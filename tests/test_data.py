"""Data in: fitting data loaders (CSV/TSV and AFM loaders, Curve validation, contact point)."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

import fitting
from fitting import Curve, Limits

DATA = pathlib.Path(__file__).parent / "data"
JPK = DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force"
IBW = DATA / "sin-force-distance.ibw"


# --- real curves -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def jpk() -> Curve:
    pytest.importorskip("afmformats")
    (c,) = fitting.load_curve(JPK)
    return c


@pytest.fixture(scope="module")
def ibw() -> Curve:
    pytest.importorskip("afmformats")
    (c,) = fitting.load_curve(IBW)
    return c


def test_jpk_segments_and_timing(jpk):
    assert jpk.segment_names == ("rest", "approach", "hold", "retract")
    counts = [int(np.sum(jpk.segment == j)) for j in range(4)]
    assert counts == [256, 2048, 7680, 1951]
    hold = jpk.time[jpk.mask("hold")]
    assert hold[-1] - hold[0] == pytest.approx(30.0, abs=0.1)
    assert jpk.spring_constant == pytest.approx(1.0677)
    assert jpk.metadata["height column"] == "height (measured)"
    # approach speed from the data: base displacement u = indentation + F/k + p_c
    m = jpk.mask("approach")
    u = jpk.displacement[m] + jpk.force[m] / jpk.spring_constant
    speed = np.polyfit(jpk.time[m], u, 1)[0]
    assert speed == pytest.approx(20e-6, rel=0.02)
    mr = jpk.mask("retract")
    ur = jpk.displacement[mr] + jpk.force[mr] / jpk.spring_constant
    assert np.polyfit(jpk.time[mr], ur, 1)[0] == pytest.approx(-20e-6, rel=0.02)


def test_jpk_forces_after_baseline(jpk):
    assert jpk.contact.baseline_region == "rest"
    assert abs(np.mean(jpk.force[jpk.mask("rest")])) < 1e-12
    peak = jpk.force.max()
    assert 0.28e-6 < peak < 0.36e-6  # about 0.3 µN
    assert int(np.argmax(jpk.force)) in np.flatnonzero(jpk.mask("approach", "hold"))
    assert -0.12e-6 < jpk.force[jpk.mask("retract")].min() < -0.08e-6  # about -0.1 µN
    end_of_hold = jpk.force[jpk.mask("hold")][-50:].mean()
    assert 0.25 < end_of_hold / peak < 0.45  # relaxes to about a third
    # indentation: ~20 µm of travel minus the ~0.3 µm deflection; contact at the approach start
    assert jpk.contact.index == 256
    assert 19.5e-6 < jpk.displacement.max() < 20.0e-6
    # constant height during the hold: the tip creeps in by the deflection change ΔF/k
    hd = jpk.displacement[jpk.mask("hold")]
    hf = jpk.force[jpk.mask("hold")]
    assert hd[-1] - hd[0] == pytest.approx((hf[0] - hf[-1]) / jpk.spring_constant, rel=0.05)


def test_ibw_segments_and_forces(ibw):
    assert ibw.segment_names == ("approach", "retract")
    app = ibw.mask("approach")
    # split where the wave note says (Indexes: 0,1008,2015; Direction: NaN,1,-1), one
    # sample before the force maximum
    assert int(np.flatnonzero(app)[-1]) == 1008
    assert abs(int(np.argmax(ibw.force)) - 1008) <= 1
    assert len(ibw) == 2016
    assert np.allclose(np.diff(ibw.time), 5e-4)  # 2000 samples/s, no time column in .ibw
    assert ibw.spring_constant == pytest.approx(1.1841)
    assert ibw.force.max() == pytest.approx(10e-9, abs=0.5e-9)
    assert -ibw.force.min() == pytest.approx(12.9e-9, abs=0.3e-9)  # pull-off
    # heights decrease toward the sample: base displacement increases on the approach
    u = ibw.displacement[app] + ibw.force[app] / ibw.spring_constant
    assert np.polyfit(ibw.time[app], u, 1)[0] > 0
    # jump to contact: contact point just before the attractive dip, ~0.45 s
    assert ibw.contact.method == "detect"
    assert 880 < ibw.contact.index < 910
    assert ibw.force[ibw.contact.index + 1 : ibw.contact.index + 10].min() < -2e-9
    assert 0 < ibw.displacement.max() < 30e-9


def test_spring_constant_override_rescales_force():
    pytest.importorskip("afmformats")
    (c1,) = fitting.load_afm(IBW, contact_point=None)
    (c2,) = fitting.load_afm(IBW, contact_point=None, spring_constant=2 * 1.1841)
    assert c2.spring_constant == pytest.approx(2 * 1.1841)
    assert np.allclose(c2.force, 2 * c1.force, rtol=1e-6, atol=1e-15)
    assert np.allclose(c2.displacement, c1.displacement, atol=1e-15)  # same deflection
    assert c1.contact.method == "none"


def test_fit_contact_on_real_curve(ibw):
    pytest.importorskip("afmformats")
    (c,) = fitting.load_afm(IBW, contact_point="fit")
    assert c.contact.method == "fit"
    # the Hertz-like fit ignores the jump-in, so it lies later than the detection
    assert abs(c.contact.tip_position - ibw.contact.tip_position) < 10e-9


# --- contact point on a synthetic Hertz curve ------------------------------------------


def _hertz_curve(seed: int, k: float | None, sigma: float = 0.5e-9) -> Curve:
    """Hertz approach: F = a p_+^1.5, 100 nN at 300 nm, contact at base position 37 nm,
    raw force offset −4 nN, Gaussian force noise `sigma` (0.5 % of the peak)."""
    rng = np.random.default_rng(seed)
    n = 2000
    p = np.linspace(-300e-9, 300e-9, n)
    f = 100e-9 * np.clip(p / 300e-9, 0.0, None) ** 1.5
    u = p + (f / k if k else 0.0) + 37e-9
    force = f - 4e-9 + sigma * rng.standard_normal(n)
    return Curve(
        time=np.linspace(0.0, 1.0, n), displacement=u, force=force,
        segment=np.zeros(n, int), segment_names=("approach",), spring_constant=k,
    )


@pytest.mark.parametrize("k", [None, 0.5])
def test_contact_point_synthetic_hertz(k):
    # tolerances: detection is biased late by where the signal emerges from the noise
    # (~11 nm here, < 25 nm = 8 % of the 300 nm indentation); the power-law fit < 2 nm
    for seed in range(3):
        raw = _hertz_curve(seed, k)
        det = fitting.preprocess(raw, contact_point="detect")
        fit = fitting.preprocess(raw, contact_point="fit")
        assert 0 <= det.contact.tip_position - 37e-9 < 25e-9
        assert abs(fit.contact.tip_position - 37e-9) < 2e-9
        assert fit.contact.force_offset == pytest.approx(-4e-9, abs=0.1e-9)
        assert fit.displacement.max() == pytest.approx(300e-9, abs=3e-9)
        assert fit.force.max() == pytest.approx(100e-9, abs=3e-9)
        # baseline=None: same contact, force left as given
        keep = fitting.preprocess(raw, baseline=None, contact_point="fit")
        assert keep.contact.tip_position == pytest.approx(fit.contact.tip_position, abs=1e-12)
        np.testing.assert_array_equal(keep.force, raw.force)


def test_contact_not_found():
    n = 200
    c = Curve(time=np.arange(n) * 1e-3, displacement=np.linspace(0, 1e-6, n),
              force=np.zeros(n), segment=np.zeros(n, int), segment_names=("approach",))
    with pytest.raises(ValueError, match="no contact found"):
        fitting.preprocess(c)
    with pytest.raises(ValueError, match="already preprocessed"):
        fitting.preprocess(fitting.preprocess(c, contact_point=None))


# --- CSV / TSV and units ---------------------------------------------------------------


def _protocol(n=300):
    t = np.linspace(0.0, 3.0, n)
    d = np.interp(t, [0.0, 1.0, 2.0, 3.0], [-50e-9, 400e-9, 400e-9, -80e-9])
    f = 2e-6 * np.clip(d, 0, None) ** 1.5 / (400e-9) ** 0.5 - 1e-9 * (t > 2.0)
    return t, d, f


def _write(path, header, rows, sep=","):
    lines = [sep.join(header)] + [sep.join(repr(float(v)) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_csv_units_round_trip(tmp_path):
    t, d, f = _protocol()
    extra = np.arange(len(t))
    si = fitting.load_csv(_write(tmp_path / "si.csv", ["time_s", "displacement_m", "force_N", "junk"],
                                 np.c_[t, d, f, extra]))
    nm = fitting.load_csv(_write(tmp_path / "nm.csv", ["time (ms)", "displacement [nm]", "force_nN"],
                                 np.c_[t * 1e3, d * 1e9, f * 1e9]))
    tsv = fitting.load_csv(_write(tmp_path / "um.tsv", ["force", "t", "indentation"],
                                  np.c_[f * 1e6, t * 1e6, d * 1e6], sep="\t"),
                           units="time=µs,displacement=um,force=µN")
    plain = fitting.load_csv(_write(tmp_path / "plain.txt", ["time", "displacement", "force"],
                                    np.c_[t, d * 1e9, f * 1e12], sep=" "),
                             units={"displacement": "nm", "force": "pN"})
    for other in (nm, tsv, plain):
        np.testing.assert_allclose(other.time, si.time, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(other.displacement, si.displacement, rtol=1e-12, atol=1e-21)
        np.testing.assert_allclose(other.force, si.force, rtol=1e-12, atol=1e-24)
        assert other.segment_names == si.segment_names
    # segments inferred from the ramp-hold-ramp displacement
    assert si.segment_names == ("approach", "hold", "retract")
    assert si.contact is None and si.spring_constant is None


def test_csv_default_cli_header_and_loader_dispatch(tmp_path):
    t, d, f = _protocol()
    p = _write(tmp_path / "curve.csv", ["time_s", "displacement_m", "force_N"], np.c_[t, d, f])
    (c,) = fitting.load_curve(p)
    assert c.source == str(p)
    np.testing.assert_array_equal(c.force, f)
    with pytest.raises(ValueError, match="format"):
        fitting.load_curve(p, format="xls")


def test_csv_segment_column_and_triangle(tmp_path):
    t = np.linspace(0, 2, 101)
    d = 1e-6 * (1 - np.abs(t - 1))
    f = 1e-9 * d / 1e-6
    lines = ["time_s;displacement_m;force_N;segment"]
    for ti, di, fi in zip(t, d, f, strict=True):
        lines.append(f"{float(ti)!r};{float(di)!r};{float(fi)!r};{'extend' if ti <= 1 else 'retract'}")
    p = tmp_path / "seg.csv"
    p.write_text("# comment line\n" + "\n".join(lines) + "\n")
    c = fitting.load_csv(p)
    assert c.segment_names == ("approach", "retract")
    assert int(np.sum(c.mask("approach"))) == 51
    seg, names = fitting.infer_segments(t, d)  # triangle: no hold
    assert names == ("approach", "retract")
    np.testing.assert_array_equal(seg, c.segment)


def test_csv_with_cantilever_and_contact(tmp_path):
    raw = _hertz_curve(7, 0.5)
    p = _write(tmp_path / "afm.csv", ["time_s", "displacement_m", "force_N"],
               np.c_[raw.time, raw.displacement, raw.force])
    c = fitting.load_csv(p, spring_constant=0.5, contact_point="fit")
    assert abs(c.contact.tip_position - 37e-9) < 2e-9
    assert c.spring_constant == 0.5


def test_units_helpers():
    assert fitting.unit_factor("µm/s") == ("length/time", pytest.approx(1e-6))
    assert fitting.unit_factor("\u03bcN") == ("force", 1e-6)
    assert fitting.parse_units("displacement=nm, force=nN") == {"displacement": "nm", "force": "nN"}
    with pytest.raises(ValueError, match="unknown unit 'parsec'"):
        fitting.unit_factor("parsec")
    with pytest.raises(ValueError, match="force needs a force unit"):
        fitting.parse_units({"force": "nm"})
    with pytest.raises(ValueError, match="unknown column role 'speed'"):
        fitting.parse_units("speed=um/s")


# --- bad input -------------------------------------------------------------------------


def test_csv_nan_row_named(tmp_path):
    p = tmp_path / "nan.csv"
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n1,1e-9,1e-9\n2,2e-9,nan\n")
    with pytest.raises(ValueError, match=r"column 'force_N'.*data row 3 \(line 4\)"):
        fitting.load_csv(p)
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n1,,1e-9\n")
    with pytest.raises(ValueError, match=r"column 'displacement_m', data row 2"):
        fitting.load_csv(p)


def test_csv_non_monotonic_time(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n2,1e-9,1e-9\n1,2e-9,2e-9\n")
    with pytest.raises(ValueError, match=r"column 'time_s' is not strictly increasing at data row 3"):
        fitting.load_csv(p)


def test_csv_empty_and_missing(tmp_path):
    p = tmp_path / "e.csv"
    p.write_text("")
    with pytest.raises(ValueError, match="file is empty"):
        fitting.load_csv(p)
    p.write_text("time_s,displacement_m,force_N\n")
    with pytest.raises(ValueError, match="no data rows"):
        fitting.load_csv(p)
    p.write_text("time_s,displacement_m\n0,0\n1,1e-9\n")
    with pytest.raises(ValueError, match="no force column"):
        fitting.load_csv(p)
    p.write_text("0,0,0\n1,1e-9,1e-9\n")
    with pytest.raises(ValueError, match="no column names"):
        fitting.load_csv(p)
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n1,1e-9\n")
    with pytest.raises(ValueError, match="line 3 has 2 fields"):
        fitting.load_csv(p)
    with pytest.raises(FileNotFoundError):
        fitting.load_csv(tmp_path / "missing.csv")


def test_csv_unit_conflict(tmp_path):
    p = tmp_path / "u.csv"
    p.write_text("time_s,displacement [nm],force_N\n0,0,0\n1,1,1e-9\n")
    with pytest.raises(ValueError, match=r"declares unit 'nm' but units\['displacement'\]"):
        fitting.load_csv(p, units={"displacement": "um"})
    p.write_text("time_s,displacement [nN],force_N\n0,0,0\n1,1,1e-9\n")
    with pytest.raises(ValueError, match="its unit 'nN' is a force"):
        fitting.load_csv(p)


def test_absurd_units(tmp_path):
    # 1 m of indentation: nm given as m
    p = tmp_path / "a.csv"
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n1,1.0,1e-9\n")
    with pytest.raises(ValueError, match=r"displacement reaches 1 m.*nm or µm as m.*units="):
        fitting.load_csv(p)
    # overridable
    c = fitting.load_csv(p, limits=Limits(max_displacement=2.0))
    assert c.displacement.max() == 1.0
    assert fitting.load_csv(p, limits=None).displacement.max() == 1.0
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n1,1e-9,5\n")
    with pytest.raises(ValueError, match=r"force reaches 5 N.*max_force"):
        fitting.load_csv(p)
    p.write_text("time_s,displacement_nm,force_N\n0,0,0\n1,1e-9,1e-9\n")  # m given as nm
    with pytest.raises(ValueError, match="displacement spans only"):
        fitting.load_csv(p)


def test_curve_validation_messages():
    t = np.arange(4.0)
    d = np.array([0.0, 1e-9, 2e-9, 1e-9])
    f = np.array([0.0, 1e-9, 2e-9, 1e-9])
    with pytest.raises(ValueError, match="different lengths"):
        Curve(time=t, displacement=d[:3], force=f)
    with pytest.raises(ValueError, match="curve is empty"):
        Curve(time=[], displacement=[], force=[])
    with pytest.raises(ValueError, match=r"force has a non-finite value \(nan\) at sample 2"):
        Curve(time=t, displacement=d, force=[0, 1e-9, np.nan, 0])
    with pytest.raises(ValueError, match=r"time is not strictly increasing at sample 2"):
        Curve(time=[0, 1, 1, 2], displacement=d, force=f)
    with pytest.raises(ValueError, match=r"segment 1 \('hold'\) has no samples"):
        Curve(time=t, displacement=d, force=f, segment=[0, 0, 2, 2],
              segment_names=("approach", "hold", "retract"))
    with pytest.raises(ValueError, match="must not decrease"):
        Curve(time=t, displacement=d, force=f, segment=[0, 1, 0, 1])
    with pytest.raises(ValueError, match="'dwell' is not one of"):
        Curve(time=t, displacement=d, force=f, segment=[0, 0, 1, 1],
              segment_names=("approach", "dwell"))
    with pytest.raises(ValueError, match="spring_constant must be finite and > 0"):
        Curve(time=t, displacement=d, force=f, spring_constant=-1.0)
    c = Curve(time=t, displacement=d, force=f)
    assert c.segment_names == ("approach", "retract")
    assert not c.time.flags.writeable
    with pytest.raises(ValueError, match="no 'hold' segment"):
        fitting.select_segments(c, "hold")


def test_select_and_resample(jpk):
    c = fitting.select_segments(jpk, "approach", "hold", "retract")
    assert c.segment_names == ("approach", "hold", "retract")
    assert len(c) == len(jpk) - 256
    r = fitting.resample(c, 50)
    assert len(r) == 150 and r.segment_names == c.segment_names
    for j in range(3):  # segment end points kept exactly
        a, b = c.time[c.segment == j], r.time[r.segment == j]
        assert (a[0], a[-1]) == (b[0], b[-1])
    assert r.force[r.segment == 0][-1] == c.force[c.segment == 0][-1]
    r2 = fitting.resample(c, {"hold": 20})
    assert int(np.sum(r2.segment == 1)) == 20
    assert int(np.sum(r2.segment == 0)) == 2048
