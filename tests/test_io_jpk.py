"""The built-in JPK reader (fitting._io_jpk): the same arrays as afmformats on the files
both read, and the files afmformats refuses (segment layouts its recogniser does not know),
read through fitting.load_curve and the command line."""

from __future__ import annotations

import pathlib
import sys
import zipfile

import numpy as np
import pytest

import fitting
from fitting._io_jpk import read_jpk, segment_kinds

DATA = pathlib.Path(__file__).parent / "data"
OOCYTE = DATA / "oocyte-stress-relaxation-cell1-0008.jpk-force"
MAP = DATA / "force-map-2x2.jpk-force-map"
QI = DATA / "qi-2x2-2020.02.07.jpk-qi-data"
QI_JPK8 = DATA / "qi-10px-2026-jpk8.jpk-qi-data"
JPK_FILES = [OOCYTE, DATA / "creep-compliance-polymergel.jpk-force", MAP, QI, QI_JPK8]

COLUMNS = ("force", "height (measured)", "height (piezo)", "time", "segment")
META = ("spring constant", "sensitivity", "imaging mode", "grid index x", "grid index y",
        "grid shape x", "grid shape y", "position x", "position y", "point count",
        "duration")


def _afm_load(path, **kw):
    afmformats = pytest.importorskip("afmformats")
    return afmformats.load_data(path, **kw)


def _restructured(src, dst, *, keep):
    """A copy of the JPK file `src` whose curves keep only the segments `keep` (in order,
    renumbered from 0): the real data, in a segment layout afmformats' recogniser does not
    know (e.g. extend, constant-height pause, retract: what newer JPK software writes for
    a map with a dwell)."""
    new = {old: j for j, old in enumerate(keep)}
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            parts = item.filename.split("/")
            if "segments" in parts:
                k = parts.index("segments")
                if k + 1 < len(parts) and parts[k + 1].isdigit():
                    if int(parts[k + 1]) not in new:
                        continue
                    parts[k + 1] = str(new[int(parts[k + 1])])
            zout.writestr("/".join(parts), zin.read(item.filename))
    return dst


def _refused(path):
    afmformats = pytest.importorskip("afmformats")
    with pytest.raises(afmformats.errors.FileFormatNotSupportedError,
                       match="Could not determine file format recipe"):
        afmformats.load_data(path)


# --- the files both read: the same numbers --------------------------------------------------


@pytest.mark.parametrize("path", JPK_FILES, ids=lambda p: p.name)
def test_reader_equals_afmformats(path):
    ref = _afm_load(path)
    mine = read_jpk(path)
    assert len(mine) == len(ref)
    for a, b in zip(ref, mine, strict=True):
        assert sorted(b.columns) == sorted(c for c in COLUMNS if c in a.columns)
        for col in COLUMNS:
            x = np.asarray(a[col], dtype=np.float64)
            np.testing.assert_allclose(b[col], x, rtol=1e-13, atol=1e-13 * np.max(np.abs(x)),
                                       err_msg=f"{path.name} {col}")
        for key in META:
            if key in a.metadata:
                want = a.metadata[key]
                want = pytest.approx(want, rel=1e-13) if isinstance(want, float) else want
                assert b.metadata[key] == want, key


def test_newest_software_file_loads_with_contact():
    # JPK SPM software 8.1.64 (2026, file-format-version 2.0): ten QI pixels of one line
    curves = fitting.load_curve(QI_JPK8)
    assert len(curves) == 10
    assert {c.metadata["grid index y"] for c in curves} == set(range(10))
    for c in curves:
        assert c.segment_names == ("approach", "retract")
        assert c.spring_constant == pytest.approx(2.8308, rel=1e-4)
        assert 1e-8 < c.force.max() < 1e-7 and 1e-9 < c.displacement.max() < 2e-8


def test_float_channel_agrees_with_the_integer_channel():
    # the QI file stores the measured height twice: integer-encoded (measuredHeight) and
    # as float values (smoothedMeasuredHeight); the float decoding is checked by the other
    from fitting._io_jpk import _Archive, _channel

    with zipfile.ZipFile(QI) as z:
        arc = _Archive(z)
        seg = "index/0/segments/0/"
        props = {**arc.resolve(arc.properties(seg + "segment-header.properties")),
                 **arc.general}
        assert props["channel.smoothedMeasuredHeight.type"] == "float-data"
        smooth = _channel(arc, props, seg, "smoothedMeasuredHeight", "nominal", "m")
        raw = _channel(arc, props, seg, "measuredHeight", "nominal", "m")
    assert np.ptp(raw) > 1e-7
    assert np.median(np.abs(smooth - raw)) < 2e-9


def test_sensitivity_and_spring_constant_replace_the_calibration_as_in_afmformats(tmp_path):
    s, k = 5.0e-8, 0.5
    ref = _afm_load(OOCYTE, meta_override={"sensitivity": s, "spring constant": k})[0]
    (mine,) = read_jpk(OOCYTE, sensitivity=s, spring_constant=k)
    np.testing.assert_allclose(mine["force"], ref["force"], rtol=1e-13)
    assert mine.metadata["spring constant"] == k and mine.metadata["sensitivity"] == s


def test_segment_names_from_the_styles():
    assert segment_kinds(["extend", "pause", "retract"]) == ("approach", "hold", "retract")
    assert segment_kinds(["pause", "extend", "pause", "retract", "pause"]) == (
        "rest", "approach", "hold", "retract", "rest")
    assert segment_kinds(["extend"]) == ("approach",)
    with pytest.raises(ValueError, match="segment 1 has the style 'modulation'"):
        segment_kinds(["extend", "modulation", "retract"])


# --- the files afmformats refuses --------------------------------------------------------------


def test_refused_extend_pause_retract_curve_loads(tmp_path):
    # the oocyte curve without its rest segment: extend, constant-height pause, retract
    path = _restructured(OOCYTE, tmp_path / "no-rest.jpk-force", keep=(1, 2, 3))
    _refused(path)
    (c,) = fitting.load_curve(path, baseline="none", contact_point="none")
    (o,) = fitting.load_curve(OOCYTE, baseline="none", contact_point="none")
    assert c.metadata["reader"] == "jaxcontact-jpk" and o.metadata["reader"] == "afmformats"
    assert c.segment_names == ("approach", "hold", "retract")
    assert c.metadata["imaging mode"] == "stress-relaxation"
    same = o.segment > 0
    np.testing.assert_array_equal(c.force, o.force[same])
    np.testing.assert_allclose(c.time + 1.0, o.time[same], rtol=0, atol=1e-12)  # rest: 1 s
    np.testing.assert_allclose(np.diff(c.displacement), np.diff(o.displacement[same]),
                               rtol=0, atol=1e-15)
    # preprocessed: the physical magnitudes of the original (20 µm, 0.3 µN, k 1.068 N/m)
    (p,) = fitting.load_curve(path)
    assert p.spring_constant == pytest.approx(1.0677, rel=1e-4)
    assert 15e-6 < p.displacement.max() < 25e-6 and 2e-7 < p.force.max() < 4e-7
    assert p.time[-1] - p.time[0] == pytest.approx(31.95, abs=0.01)
    # a modality asked for keeps only such curves, as afmformats does
    with pytest.raises(fitting.DataError, match="no force-distance curves.*stress-relax"):
        fitting.load_afm(path, modality="force-distance")
    assert len(fitting.load_afm(path, modality="stress-relaxation")) == 1


def test_refused_map_keeps_its_good_curves_and_names_the_bad_one(tmp_path):
    # the 2x2 map with the approach only (one segment per curve: refused), one data file cut
    path = _restructured(MAP, tmp_path / "approach-only.jpk-force-map", keep=(0,))
    _refused(path)
    cut = tmp_path / "cut.jpk-force-map"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(cut, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "index/2/segments/0/channels/vDeflection.dat":
                data = data[:-3]
            zout.writestr(item, data)
    raw = {"baseline": "none", "contact_point": "none"}
    curves = fitting.load_curve(cut, on_error="keep", **raw)
    assert [type(c).__name__ for c in curves] == ["Curve", "Curve", "FailedCurve", "Curve"]
    assert "vDeflection" in curves[2].reason and "bytes" in curves[2].reason
    ref = fitting.load_curve(MAP, **raw)
    for j in (0, 1, 3):
        assert curves[j].segment_names == ("approach",)
        for key in ("grid index x", "grid index y", "position x", "position y"):
            assert curves[j].metadata[key] == ref[j].metadata[key]
        app = ref[j].segment == 0
        np.testing.assert_array_equal(curves[j].force, ref[j].force[app])
        np.testing.assert_array_equal(curves[j].displacement, ref[j].displacement[app])
    assert fitting.load_curve(cut, on_error="keep")[0].contact.method == "detect"
    with pytest.raises(fitting.DataError, match=r"cut\.jpk-force-map \(curve 2\).*bytes"):
        fitting.load_curve(cut)


def test_refused_map_through_the_command_line_is_one_line(tmp_path, capsys):
    # the command line reaches the JPK reader; a map without retracts cannot be fitted by
    # the relaxed model: one line naming why, no traceback, nothing written
    from jaxcontact_cli import main

    path = _restructured(MAP, tmp_path / "approach-only.jpk-force-map", keep=(0,))
    out = tmp_path / "out"
    rc = main(["fit", str(path), "--radius", "10e-6", "--model", "relaxed", "--quiet",
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "retract" in err and "Traceback" not in err, err
    assert not out.exists()


@pytest.mark.slow  # a full fit through the command line (about a minute)
def test_refused_curve_fitted_through_the_command_line(tmp_path, capsys):
    import json

    from jaxcontact_cli import main

    path = _restructured(OOCYTE, tmp_path / "no-rest.jpk-force", keep=(1, 2, 3))
    out = tmp_path / "fit"
    rc = main(["fit", str(path), "--radius", "10e-6", "--model", "relaxed", "--quiet",
               "--no-figure", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    table = json.loads((out / "parameters.json").read_text())
    # measured 2026-11-26: converged, R² 0.99968, G0 240 Pa, Δγ 0.53 mJ/m² (a soft cell)
    assert table["converged"] is True and table["r_squared"] > 0.99
    assert 10.0 < table["G0_Pa"]["value"] < 1e5
    assert 0.0 < table["work_of_adhesion_J_m2"]["value"] < 1e-2


# --- without afmformats, and files nothing reads -----------------------------------------------


def test_jpk_files_load_without_afmformats(monkeypatch):
    with_afm = fitting.load_curve(MAP)
    monkeypatch.setitem(sys.modules, "afmformats", None)  # `import afmformats` fails
    monkeypatch.setitem(sys.modules, "afmformats.formats", None)
    curves = fitting.load_curve(MAP)
    assert len(curves) == len(with_afm) == 4
    for a, b in zip(with_afm, curves, strict=True):
        assert b.metadata["reader"] == "jaxcontact-jpk"
        assert a.segment_names == b.segment_names and a.spring_constant == b.spring_constant
        for f in ("time", "displacement", "force", "segment"):
            np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=1e-12, atol=1e-20)
        assert b.contact.time == a.contact.time
    assert ".jpk-force-map" in fitting.supported_formats()
    with pytest.raises(fitting.DataError, match="other instrument files need afmformats"):
        fitting.load_curve(DATA / "sin-force-distance.ibw")


def test_junk_jpk_gives_each_readers_reason(tmp_path):
    p = tmp_path / "junk.jpk-force-map"
    p.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(fitting.DataError) as info:
        fitting.load_curve(p)
    msg = str(info.value)
    assert msg.startswith(str(p)) and "afmformats" in msg and "JPK reader" in msg
    assert "zip" in msg


def test_a_map_point_afmformats_cannot_read_is_a_failed_point(tmp_path):
    # afmformats accepts the map (its recogniser reads curve 0 only) and raises its own
    # BaseException-derived error when curve 2's deflection is read: that point fails
    # with the reason, the others load (before: the error escaped as a traceback)
    path = tmp_path / "no-deflection.jpk-force-map"
    with zipfile.ZipFile(MAP) as zin, zipfile.ZipFile(path, "w") as zout:
        for item in zin.infolist():
            if item.filename != "index/2/segments/1/channels/vDeflection.dat":
                zout.writestr(item, zin.read(item.filename))
    curves = fitting.load_curve(path, on_error="keep")
    assert [type(c).__name__ for c in curves] == ["Curve", "Curve", "FailedCurve", "Curve"]
    assert curves[0].metadata["reader"] == "afmformats"
    assert "vDeflection" in curves[2].reason
    with pytest.raises(fitting.DataError, match=r"\(curve 2\).*vDeflection"):
        fitting.load_curve(path)
