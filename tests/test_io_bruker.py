"""The built-in Bruker NanoScope reader (:mod:`fitting._io_bruker`) on real files.

The checks are physical, read from the files' headers by hand here (regular
expressions on the text, not the reader's parser):

* the relative trigger: an approach stops when the deflection has risen by the
  threshold above its start, so on every curve the rise read back through the reader
  (force / (k · sensitivity)) equals the threshold within the overshoot of a sample or
  two; this is what fixes the 32-bit scale (x 1 for the single curve, 1/256 for the
  force volume);
* the height sensor spans the nominal Z ramp (ramp size [V] × piezo Zsens [nm/V]).
"""

from __future__ import annotations

import pathlib
import re

import numpy as np
import pytest

import fitting
from fitting import DataError
from fitting._io_bruker import read_bruker

DATA = pathlib.Path(__file__).parent / "data"
SAPPHIRE = DATA / "bruker-sapphire-force-TAP525.001"  # 16-bit, height sensor
SINGLE32 = DATA / "bruker-egel-force-v92-32bit.spm"  # 32-bit single curve
VOLUME32 = DATA / "bruker-egel-force-volume-16x16.spm"  # 32-bit force volume


def _header(path) -> str:
    raw = path.read_bytes()
    return raw[: raw.index(b"\\*File list end")].decode("latin-1")


def _header_number(text: str, pattern: str) -> float:
    m = re.search(pattern, text)
    assert m, pattern
    return float(m.group(1))


def _threshold(text: str) -> float:
    assert re.search(r"\\Trigger mode: Relative", text)
    return _header_number(text, r"\\@4:Trig [Tt]hreshold Deflection: V \[Sens\. DeflSens\] "
                                r"\([^)]*\) ([0-9.]+) V")


@pytest.mark.parametrize("path, count", [(SAPPHIRE, 1), (SINGLE32, 1), (VOLUME32, 256)])
def test_approach_rises_by_the_trigger_threshold_on_every_curve(path, count):
    threshold = _threshold(_header(path))
    curves = read_bruker(path)
    assert len(curves) == count
    ratios = []
    for c in curves:
        k, s = c.metadata["spring constant"], c.metadata["sensitivity"]
        volts = c["force"][c["segment"] == 0] / (k * s)  # the approach, in time order
        ratios.append((volts[-1] - volts[:16].mean()) / threshold)
    ratios = np.asarray(ratios)
    # measured: sapphire 1.024, 32-bit single 1.061, force volume 0.979-1.053; a wrong
    # power of two (the 16-bit scale on the force volume: 256) is far outside
    assert np.all((ratios > 0.95) & (ratios < 1.08)), (ratios.min(), ratios.max())


def test_sapphire_curve_height_sensor_spans_the_ramp_and_signs():
    text = _header(SAPPHIRE)
    ramp_v = _header_number(text, r"\\@4:Ramp size: V \[Sens\. Zsens\] \([^)]*\) ([0-9.]+) V")
    zsens = _header_number(text, r"\\@Sens\. Zsens: V ([0-9.]+) nm/V")
    (c,) = read_bruker(SAPPHIRE)
    assert c.segment_names == ("approach", "retract")
    assert np.all(np.diff(c["segment"]) >= 0)
    approach = c["segment"] == 0
    assert approach.sum() == 512 and (~approach).sum() == 512
    h = c["height (measured)"]
    span = h[approach][0] - h[approach][-1]  # heights decrease toward the sample
    assert span == pytest.approx(ramp_v * zsens * 1e-9, rel=0.03)  # 592 nm vs 600 nm
    # the turnaround: the end of the approach and the start of the retract
    assert h[approach][-1] == pytest.approx(h[~approach][0], abs=2e-9)
    t = c["time"]
    assert np.all(np.diff(t) > 0)
    # Forward vel. [V/s] = 2 · ramp · Scan rate: one segment lasts 1 / (2 · Scan rate)
    rate = _header_number(text, r"\\Scan rate: ([0-9.]+)")
    assert t[approach][-1] - t[0] == pytest.approx(0.5 / rate, rel=0.01)

    (loaded,) = fitting.load_curve(SAPPHIRE)
    assert loaded.metadata["reader"] == "jaxcontact-bruker"
    assert loaded.spring_constant == pytest.approx(90.0)
    f = loaded.force[loaded.mask("approach")]
    # compressive force positive: it rises into the sample, the baseline is near 0
    assert f[-1] > 50 * abs(np.median(f[: len(f) // 2]))
    assert f[-1] == pytest.approx(loaded.force.max())
    assert loaded.displacement[loaded.mask("approach")][-1] > 0
    # a rigid sample: contact in the last fifth of the 600 nm ramp
    assert loaded.contact.method == "detect" and loaded.contact.index > 0.8 * 512


def test_options_override_the_file_calibration():
    (c,) = fitting.load_curve(SINGLE32, baseline="none", contact_point="none")
    (k2,) = fitting.load_curve(SINGLE32, baseline="none", contact_point="none",
                               spring_constant=2 * 0.1332)
    (s2,) = fitting.load_curve(SINGLE32, baseline="none", contact_point="none",
                               sensitivity=3 * 27.39e-9)
    np.testing.assert_allclose(k2.force, 2 * c.force, rtol=1e-12)
    np.testing.assert_allclose(s2.force, 3 * c.force, rtol=1e-12)
    assert c.metadata["height column"] == "height (piezo)"  # no height sensor: the ramp
    # the ramp: Ramp size 227.2211 V × Zsens 13.203 nm/V = 3.0 µm over the approach
    (raw,) = read_bruker(SINGLE32)
    h = raw["height (piezo)"][raw["segment"] == 0]
    assert h[0] - h[-1] == pytest.approx(3.0e-6 * 1023 / 1024, rel=1e-4)


def test_force_volume_grid_and_positions():
    curves = fitting.load_curve(VOLUME32, on_error="keep")
    assert len(curves) == 256 and all(isinstance(c, fitting.Curve) for c in curves)
    cells = {(c.metadata["grid index x"], c.metadata["grid index y"]) for c in curves}
    assert cells == {(i, j) for i in range(16) for j in range(16)}
    m = curves[17].metadata
    assert (m["grid shape x"], m["grid shape y"]) == (16, 16)
    assert m["grid size x"] == pytest.approx(2e-6)  # Scan Size: 2000 nm
    assert (m["grid index x"], m["grid index y"]) == (1, 1)  # row by row, Frame direction Up
    assert m["position x"] == pytest.approx(1.5 * 2e-6 / 16)
    assert m["position y"] == pytest.approx(1.5 * 2e-6 / 16)


def _patched(tmp_path, src, old: bytes, new: bytes, name="patched.spm"):
    raw = src.read_bytes()
    assert raw.count(old) >= 1 and len(old) == len(new)
    out = tmp_path / name
    out.write_bytes(raw.replace(old, new))
    return out


def test_32bit_scale_without_evidence_is_refused(tmp_path):
    off = _patched(tmp_path, SINGLE32, b"Trigger mode: Relative", b"Trigger mode: Off     ")
    with pytest.raises(DataError, match="32-bit.*not verified") as e:
        fitting.load_curve(off)
    assert str(off) in str(e.value)
    # a threshold twice the one the instrument used: the rise no longer matches it
    doubled = _patched(tmp_path, SINGLE32, b"(0.0003750000 V/LSB) 1.200000 V",
                       b"(0.0003750000 V/LSB) 2.400000 V")
    with pytest.raises(DataError, match=r"rise 0\.5.* not about 1"):
        fitting.load_curve(doubled)


def test_unverified_layouts_are_refused(tmp_path):
    hold = _patched(tmp_path, SINGLE32, b"\\Hold Samples: 0", b"\\Hold Samples: 8")
    with pytest.raises(DataError, match="Hold Samples = 8: curves with a hold"):
        fitting.load_curve(hold)
    peakforce = _patched(tmp_path, SINGLE32, b"Operating mode: Force\r",
                         b"Operating mode: PFQNM\r")
    with pytest.raises(DataError, match="Operating mode 'PFQNM'"):
        fitting.load_curve(peakforce)


@pytest.mark.parametrize("on_error", ["raise", "keep"])
def test_truncated_file_is_a_clear_error(tmp_path, on_error):
    cut = tmp_path / "cut.spm"
    cut.write_bytes(VOLUME32.read_bytes()[:200_000])
    with pytest.raises(DataError, match="truncated") as e:
        fitting.load_curve(cut, on_error=on_error)
    assert str(cut) in str(e.value)
    header_only = tmp_path / "header.001"
    header_only.write_bytes(SAPPHIRE.read_bytes()[:20_000])
    with pytest.raises(DataError, match="no end marker") as e:
        fitting.load_curve(header_only, on_error=on_error)
    assert str(header_only) in str(e.value)


def test_other_files_with_bruker_suffixes(tmp_path):
    other = tmp_path / "table.spm"
    other.write_text("time,displacement,force\n0,0,0\n")
    with pytest.raises(DataError, match=r"not a Bruker NanoScope force file.*supported") as e:
        fitting.load_curve(other)
    assert str(other) in str(e.value)
    image = tmp_path / "image.002"
    image.write_bytes(b"\\*File list\r\n\\Version: 0x09200000\r\n")
    with pytest.raises(DataError, match="not a force file"):
        fitting.load_curve(image)
    pfc = _patched(tmp_path, SINGLE32, b"x", b"x", name="capture.pfc")
    with pytest.raises(DataError, match="PeakForce capture"):
        fitting.load_curve(pfc)
    assert "Bruker NanoScope" in fitting.supported_formats()
