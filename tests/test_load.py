"""Loader dispatch and real instrument files: fitting.load_curve, fitting.DataError."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

import fitting

DATA = pathlib.Path(__file__).parent / "data"
JPK = DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force"
CHIARO = DATA / "chiaro-indentation-AEBP1-002.txt"
CREEP = DATA / "creep-compliance-polymergel.jpk-force"
QI = DATA / "qi-2x2-2020.02.07.jpk-qi-data"
MAP = DATA / "force-map-2x2.jpk-force-map"

afmformats = pytest.importorskip("afmformats")


# --- clear errors for files nothing reads ------------------------------------------------


@pytest.mark.parametrize(
    "name, content",
    [
        ("junk.jpk-force", bytes(range(256)) * 4),
        ("empty.jpk-force", b""),
        ("junk.ibw", b"\x05\x00" + bytes(range(200))),
        ("junk.csv", bytes(range(256))),
        ("empty.txt", b""),
        ("junk.h5", b"not hdf5 at all"),
    ],
)
def test_junk_and_empty_files_raise_data_error(tmp_path, name, content):
    p = tmp_path / name
    p.write_bytes(content)
    with pytest.raises(fitting.DataError, match=name.replace(".", r"\.")):
        fitting.load_curve(p)


def test_truncated_jpk_raises_data_error(tmp_path):
    raw = JPK.read_bytes()
    for cut in (100, len(raw) // 2):
        p = tmp_path / f"cut{cut}.jpk-force"
        p.write_bytes(raw[:cut])
        with pytest.raises(fitting.DataError, match=f"cut{cut}"):
            fitting.load_curve(p)


def test_unknown_suffix_lists_supported_formats(tmp_path):
    p = tmp_path / "curve.xyz"
    p.write_text("time_s,displacement_m,force_N\n0,0,0\n")
    with pytest.raises(fitting.DataError) as info:
        fitting.load_curve(p)
    msg = str(info.value)
    for s in (".csv", ".jpk-force", ".jpk-force-map", ".ibw", "Chiaro"):
        assert s in msg
    assert issubclass(fitting.DataError, ValueError)


def test_plain_txt_table_still_read_as_table(tmp_path):
    p = tmp_path / "curve.txt"
    t = np.linspace(0, 1, 20)
    rows = "\n".join(f"{a:.6g}\t{1e-6 * a:.6g}\t{1e-9 * a**1.5:.6g}" for a in t)
    p.write_text("time_s\tdisplacement_m\tforce_N\n" + rows + "\n")
    (c,) = fitting.load_curve(p)
    assert len(c) == 20 and c.metadata["columns"]["force"] == "force_N"


# --- real files from several instruments --------------------------------------------------


def test_chiaro_txt_goes_through_afmformats():
    # Optics11 Chiaro export: a 'Time (s)'/'Load (uN)' text table with a long header that
    # the CSV reader cannot parse; afmformats' Chiaro recogniser claims it.
    (c,) = fitting.load_curve(CHIARO, contact_point=None, baseline=None)
    assert c.spring_constant == pytest.approx(0.019)
    assert c.segment_names == ("approach", "retract")
    assert len(c) == 13827
    assert np.allclose(np.diff(c.time), 1e-3)  # 1 kHz
    assert c.time[-1] == pytest.approx(13.826)
    assert 10e-6 < np.ptp(c.displacement) < 15e-6  # the probe travels ~12 µm
    assert c.force.max() == pytest.approx(49.2e-9, rel=0.01)


def test_chiaro_drift_needs_linear_baseline():
    # Manual reading: the force drifts from -0.3 to +0.7 nN over the first 10 s (no
    # motion), then the 100-sample running mean leaves that drift at 10.25-10.3 s.
    (lin,) = fitting.load_curve(CHIARO, baseline="linear")
    assert lin.contact.baseline == "linear"
    assert 10.15 < lin.contact.time < 10.45
    assert lin.contact.force_slope == pytest.approx(60e-12, rel=0.3)  # ~1 nN in 10 s
    # the drawn baseline is what was subtracted
    raw = fitting.load_curve(CHIARO, baseline="none", contact_point="none")[0]
    assert np.allclose(raw.force - lin.contact.baseline_force(raw.time), lin.force)
    # a constant baseline mistakes the drift for contact, seconds too early
    (const,) = fitting.load_curve(CHIARO, baseline="constant")
    assert const.contact.time < lin.contact.time - 2.0


def test_jpk_creep_compliance_segments():
    (c,) = fitting.load_curve(CREEP)
    assert c.segment_names == ("approach", "hold", "retract")
    assert [int(np.sum(c.segment == j)) for j in range(3)] == [3000, 3000, 3000]
    assert c.spring_constant == pytest.approx(0.061)
    assert c.time[-1] - c.time[0] == pytest.approx(9.0, abs=0.01)
    # creep: the hold is at constant force (feedback), the indentation grows
    hold = c.mask("hold")
    fh, dh = c.force[hold], c.displacement[hold]
    assert np.ptp(fh) < 0.1 * np.max(np.abs(fh))
    assert dh[-100:].mean() > dh[:100].mean()


def test_jpk_force_map_has_four_curves():
    curves = fitting.load_curve(MAP)
    assert len(curves) == 4
    for c in curves:
        assert c.segment_names == ("approach", "retract")
        assert c.spring_constant == pytest.approx(0.01548, rel=1e-3)
        assert c.contact.method == "detect"
        assert 0.5e-6 < c.displacement.max() < 3e-6
    grid = {(c.metadata["grid index x"], c.metadata["grid index y"]) for c in curves}
    assert grid == {(0, 0), (9, 0), (0, 9), (9, 9)}


def test_qi_curves_without_contact_fail_clearly():
    # the four QI curves of this file never touch the sample on the approach
    curves = fitting.load_curve(QI, contact_point=None, baseline=None)
    assert len(curves) == 4
    assert all(c.segment_names == ("approach", "retract") for c in curves)
    with pytest.raises(fitting.DataError, match="no contact found"):
        fitting.load_curve(QI)


def test_table_options_on_an_instrument_file_are_an_error():
    assert len(fitting.load_curve(CHIARO, units=None, contact_point="none")) == 1
    with pytest.raises(ValueError, match="units"):
        fitting.load_curve(CHIARO, units="force=nN")


# --- property: malformed files give DataError and nothing else ---------------------------

hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

_SUFFIXES = (".csv", ".txt", ".tsv", ".jpk-force", ".ibw", ".jpk-force-map", ".h5", ".tab")


def _load_or_data_error(path):
    try:
        curves = fitting.load_curve(path)
    except fitting.DataError:
        return
    assert all(isinstance(c, fitting.Curve) for c in curves)


@hypothesis.settings(max_examples=25, deadline=None)
@hypothesis.given(data=st.binary(max_size=600), suffix=st.sampled_from(_SUFFIXES))
def test_random_bytes_only_data_error(tmp_path_factory, data, suffix):
    p = tmp_path_factory.mktemp("junk") / f"f{suffix}"
    p.write_bytes(data)
    _load_or_data_error(p)


_TOKEN = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", "x", "nan", "1e400", "approach", "-", "1,5", '"']),
    st.integers(-5, 5).map(str),
)


@hypothesis.settings(max_examples=25, deadline=None)
@hypothesis.given(
    header=st.lists(st.sampled_from(["time_s", "displacement_nm", "force [nN]", "segment",
                                     "height", "junk", "t", "force_N"]), min_size=0,
                    max_size=5),
    rows=st.lists(st.lists(_TOKEN, min_size=0, max_size=6), max_size=8),
    sep=st.sampled_from([",", "\t", ";", " "]),
)
def test_malformed_tables_only_data_error(tmp_path_factory, header, rows, sep):
    text = sep.join(header) + "\n" + "\n".join(sep.join(r) for r in rows)
    p = tmp_path_factory.mktemp("tab") / "t.csv"
    p.write_text(text)
    _load_or_data_error(p)


def test_jpk_segment_names_follow_the_segment_headers(tmp_path):
    import zipfile

    (c,) = fitting.load_curve(JPK, contact_point="none", baseline="none")
    assert c.segment_names == ("rest", "approach", "hold", "retract")
    # the same file with the first segment's header relabelled as a second retract
    out = tmp_path / "relabelled.jpk-force"
    with zipfile.ZipFile(JPK) as zin, zipfile.ZipFile(out, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "segments/0/segment-header.properties":
                data = data.replace(b"segment-settings.style=pause",
                                    b"segment-settings.style=retract")
            zout.writestr(item, data)
    (r,) = fitting.load_curve(out, contact_point="none", baseline="none")
    assert r.segment_names == ("retract", "approach", "hold", "retract")
    assert np.array_equal(r.segment, c.segment)


def test_ibw_dwell_from_the_wave_note(monkeypatch):
    # the shipped .ibw has no dwell (Indexes 0,1008,2015; Direction NaN,1,-1); give its
    # wave note a dwell between samples 1009 and 1500 and check the segments follow it
    from igor2 import binarywave

    ibw = DATA / "sin-force-distance.ibw"
    real = binarywave.load(ibw)
    note = real["wave"]["note"]
    assert b"Indexes:0,1008,2015" in note.replace(b" ", b"")
    lines = [ln for ln in note.split(b"\r")
             if not ln.startswith((b"Indexes", b"Direction"))]
    fake = b"\r".join([*lines, b"Indexes: 0,1008,1500,2015", b"Direction: NaN,1,0,-1,"])

    def load(path, *a, **k):
        out = binarywave.__dict__["_real_load"](path, *a, **k)
        out["wave"]["note"] = fake
        return out

    monkeypatch.setitem(binarywave.__dict__, "_real_load", binarywave.load)
    monkeypatch.setattr(binarywave, "load", load)
    (c,) = fitting.load_curve(ibw, contact_point="none", baseline="none")
    assert c.segment_names == ("approach", "hold", "retract")
    assert np.bincount(c.segment).tolist() == [1009, 492, 515]


def _workshop_csv(path, volts_ext, volts_ret, z_ext, z_ret):
    """An AFM Workshop force-distance export (deflection in volts, no time base)."""
    head = ("Force-Distance Curve\nFile Format:\t3\n\nDate:\tWednesday, August 1, 2018\n"
            "Time:\t1:06:09 PM\nMode:\tSingle\nPoint:\t1\nX, um:\t25.000000\n"
            "Y, um:\t25.000000\n\n"
            "Extend Z-Sense(nm),Extend T-B(V),Retract Z-Sense(nm),Retract T-B(V)\n")
    rows = "".join(f"{a:.4f},{b:.6f},{c:.4f},{d:.6f}\n"
                   for a, b, c, d in zip(z_ext, volts_ext, z_ret, volts_ret, strict=True))
    path.write_text(head + rows)


def test_workshop_volts_need_sensitivity_spring_constant_and_rate(tmp_path):
    """An AFM Workshop .csv stores the deflection in volts and no time base: without the
    sensitivity and spring constant it is refused naming both, without a rate naming
    sample_rate; with them the force is k s V and the time index / rate."""
    pytest.importorskip("afmformats")
    n = 200
    z_ext = np.linspace(1000.0, 2000.0, n)          # Z-sense [nm]; deeper = larger
    z_ret = z_ext[::-1].copy()
    pen = np.clip(z_ext - 1500.0, 0.0, None)       # [nm] past a contact at 1500 nm
    v_ext = 1e-3 * pen**1.5                          # [V]
    v_ret = v_ext[::-1] - 0.02 * np.exp(-((z_ret - 1480.0) / 20.0) ** 2)
    path = tmp_path / "ws.csv"
    _workshop_csv(path, v_ext, v_ret, z_ext, z_ret)
    with pytest.raises(fitting.DataError, match=r"sensitivity \[m/V\]"):
        fitting.load_curve(path, sample_rate=100.0)
    with pytest.raises(fitting.DataError, match="sample_rate"):
        fitting.load_curve(path, spring_constant=0.1, sensitivity=50e-9)
    k, s, rate = 0.1, 50e-9, 100.0
    c = fitting.load_curve(path, spring_constant=k, sensitivity=s, sample_rate=rate,
                           baseline="none", contact_point="none")[0]
    assert c.segment_names == ("approach", "retract")
    written = np.round(np.concatenate([v_ext, v_ret]), 6)       # the file has 6 decimals
    np.testing.assert_allclose(c.force, k * s * written,
                               rtol=1e-5, atol=1e-15)
    np.testing.assert_allclose(c.time, np.arange(2 * n) / rate)
    with pytest.raises(ValueError, match="sensitivity must be finite and > 0"):
        fitting.load_curve(path, spring_constant=k, sensitivity=-1.0, sample_rate=rate)


def test_sample_rate_for_a_file_with_a_time_base_is_an_error(tmp_path):
    pytest.importorskip("afmformats")
    with pytest.raises(fitting.DataError, match="sample_rate was given"):
        fitting.load_curve(DATA / "creep-compliance-polymergel.jpk-force", sample_rate=1e3)
    table = tmp_path / "t.csv"
    table.write_text("time_s,displacement_m,force_N\n0,0,0\n1,1e-6,1e-9\n2,0,0\n")
    with pytest.raises(ValueError, match="apply to instrument files only"):
        fitting.load_curve(table, sample_rate=1e3)


@pytest.mark.parametrize("name", ["force-map-2x2.jpk-force-map",
                                  "oocyte-stress-relaxation-cell1-0008.jpk-force",
                                  "sin-force-distance.ibw"])
def test_loaded_curves_pickle_with_plain_metadata(name):
    # curves (and the results that keep them) travel between processes by pickle
    # (`fitting.fit_each` under jax.distributed): afmformats' lazy metadata values (e.g.
    # "z range", a function of the data) are evaluated when loaded; the evaluated value
    # equals the data's own range
    import pickle

    curves = fitting.load_afm(DATA / name, on_error="keep")
    back = pickle.loads(pickle.dumps(curves))
    for a, b in zip(curves, back, strict=True):
        assert type(a) is type(b)
        if isinstance(a, fitting.Curve):
            np.testing.assert_array_equal(a.force, b.force)
            assert a.metadata.keys() == b.metadata.keys()
            assert not any(callable(v) or type(v).__name__ == "LazyMetaValue"
                           for v in a.metadata.values())
    meta = curves[0].metadata
    if "z range" in meta:
        import afmformats

        raw = afmformats.load_data(DATA / name)[0]
        assert meta["z range"] == pytest.approx(np.ptp(raw["height (piezo)"]))


def test_height_frame_of_instrument_files():
    """`metadata["height at start"]`: the first sample's height in the instrument's frame,
    equal to the file's own first height as afmformats reads it, and different between a
    map's points (JPK strain gauge, Asylum Z sensor); absent where each curve's heights
    start at 0 (Bruker force volumes: the nominal ramp; Optics11 exports), whose surface
    heights are therefore nan, not a false topography."""
    curves = fitting.load_afm(MAP)
    raw = afmformats.load_data(MAP)
    starts = [c.metadata["height at start"] for c in curves]
    assert starts == [float(ds["height (measured)"][0]) for ds in raw]
    assert len(set(starts)) == len(starts)  # one frame: the points start at other heights
    for c, h0 in zip(curves, starts, strict=True):
        assert c.surface_height() == pytest.approx(h0 - c.contact.tip_position, rel=1e-12)
    ibw = fitting.load_afm(DATA / "sin-force-distance.ibw")[0]
    assert ibw.metadata["height at start"] == float(
        afmformats.load_data(DATA / "sin-force-distance.ibw")[0]["height (measured)"][0])
    for path in (DATA / "bruker-egel-force-volume-16x16.spm", CHIARO):
        c = fitting.load_curve(path, on_error="keep")[0]
        assert "height at start" not in c.metadata and np.isnan(c.surface_height())
