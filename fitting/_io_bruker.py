"""Bruker (NanoScope) force curves and force volumes read with numpy: :func:`read_bruker`.

afmformats does not read Bruker files. This reader was written from the files' text
headers (format facts checked on the files in ``tests/data`` and ``benchmarks/data``;
PyFMReader, MIT licence, https://github.com/jlopezalo/PyFMReader, was consulted for the
layout; no code was copied).

The structure:

* A text header of lines starting with a backslash, ended by ``\\*File list end`` and a
  0x1A byte. A force file starts with ``\\*Force file list``. Sections start with
  ``\\*Name`` and can repeat (one ``\\*Ciao force image list`` per stored channel).
  Scaled values read ``\\@4:Z scale: V [Sens. DeflSens] (0.000375 V/LSB) 2.5 V``: key
  ``@4:Z scale``, soft scale ``Sens. DeflSens`` (a ``\\@Sens. DeflSens: V 72.77 nm/V``
  line), hard scale 0.000375 V per stored integer (LSB), then the value and its unit.
* Kind: ``Start context: FOL`` (one curve, ``Operating mode: Force``) or ``FVOL`` /
  ``Operating mode: Force Volume`` (a map of ``force/line`` (``\\*Ciao force list``)
  × ``Lines`` (``\\*Ciao scan list``) curves over ``Scan Size``, stored row by row).
* Each channel section: ``Data offset``, ``Data length`` [bytes] of little-endian signed
  integers, ``Samps/line: n_ext n_ret``. Per curve the ``n_ext`` extend samples, then the
  ``n_ret`` retract samples; the extend is stored reversed in time: index 0 of both is
  the turnaround (checked: the height sensor of the sapphire curve is largest there and
  equal in both segments). The integer width is ``Data length / (curves · (n_ext +
  n_ret))`` bytes (``Bytes/pixel`` says 2 where version 9.2 stores 4).
* Deflection (the channel whose ``@4:Z scale`` has the soft scale ``Sens. DeflSens``):
  volts = LSB × V/LSB; metres = volts × ``@Sens. DeflSens`` [nm/V] (the NanoScope 9
  files write the number without a unit; it is read as nm/V); newtons = metres × the
  channel's ``Spring Constant`` [N/m]. ``Deflection Sensitivity Correction`` is not
  applied (as by other readers). **32-bit force volumes** store the deflection with 8
  more bits (values × 256 of the 16-bit LSB); see :func:`read_bruker` for the evidence
  and the check that guards it.
* Base (Z) position: a ``Height Sensor`` channel (soft scale ``Sens. ZsensSens``):
  LSB × V/LSB × ``@Sens. ZsensSens`` [nm/V]; it grows toward the sample. Without one, a
  linear ramp: ``@4:Ramp size`` [V] × ``@Sens. Zsens`` [nm/V] (the piezo sensitivity)
  over the ``n`` samples of a segment, the turnaround at the sample side.
* Time: a segment lasts ``Ramp size / Forward vel.`` (extend) and ``Ramp size /
  Reverse vel.`` (retract) [V / (V/s)], equal to ``1 / (2 · Scan rate)`` of the force list
  on every file checked; samples evenly spaced.

Columns, as :func:`fitting._io_jpk.read_jpk` names them: ``force`` [N], ``height
(measured)`` [m] (height sensor) or ``height (piezo)`` [m] (the nominal ramp), both
decreasing toward the sample as afmformats' heights do; ``segment`` (0 approach, 1
retract), ``time`` [s].
"""

from __future__ import annotations

import math
import pathlib
import re
from typing import Any

import numpy as np

from ._io_jpk import JPKCurve

__all__ = ["BRUKER_MAGIC", "BRUKER_SUFFIXES", "BrukerCurve", "is_bruker_suffix",
           "parse_header", "read_bruker", "sniff_bruker"]

BRUKER_MAGIC = b"\\*Force file list"
"""The first bytes of a NanoScope force file (curve or force volume)."""

BRUKER_SUFFIXES = (".spm", ".pfc")
"""Suffixes of Bruker force files besides the numbered ``.000``, ``.001``, ... ones."""

_NUMBERED = re.compile(r"\.\d{3}$")
_HEADER_LIMIT = 1 << 20  # a NanoScope header is 30–80 KB; a larger one is not a header


def is_bruker_suffix(path) -> bool:
    """Whether ``path`` has a suffix NanoScope force files use (``.spm``, ``.pfc``,
    ``.000``–``.999``)."""
    s = pathlib.Path(path).suffix.lower()
    return s in BRUKER_SUFFIXES or bool(_NUMBERED.fullmatch(s))


def sniff_bruker(path) -> str | None:
    """``"force"`` for a file that starts with the NanoScope force-file magic,
    ``"other"`` for another NanoScope file (an image: ``\\*File list``), else ``None``."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return None
    if head.startswith(BRUKER_MAGIC):
        return "force"
    if head.startswith(b"\\*") and b"list" in head[:40].lower():
        return "other"
    return None


class BrukerCurve(JPKCurve):
    """One curve of a Bruker force file, shaped like :class:`fitting._io_jpk.JPKCurve`
    (columns, ``metadata``, ``segment_names`` ``("approach", "retract")``)."""


# --- the header ---------------------------------------------------------------------------

_SCALED = re.compile(r"^\s*[VCS]\s*(?:\[([^\]]*)\])?\s*(?:\(([^)]*)\))?\s*(.*)$")


def parse_header(raw: bytes) -> list[tuple[str, dict[str, str]]]:
    """The header sections of a NanoScope file: ``[(name, {key: value}), ...]`` in file
    order (``name`` without ``\\*``; keys without the leading backslash, values stripped).

    Raises `ValueError` when the header has no end (``\\*File list end``)."""
    end = raw.find(b"\\*File list end")
    if end < 0:
        raise ValueError("the header has no end marker (\\*File list end): not a "
                         "complete NanoScope file")
    text = raw[:end].decode("latin-1")
    sections: list[tuple[str, dict[str, str]]] = []
    for line in re.split(r"\r\n|\r|\n", text):
        if line.startswith("\\*"):
            sections.append((line[2:].strip(), {}))
        elif line.startswith("\\") and sections:
            # the key ends at the first colon followed by a space or the line end ("@4:Z
            # scale: V ..." has the key "@4:Z scale")
            m = re.match(r"(.*?):(?:\s|$)(.*)$", line[1:])
            if m:
                sections[-1][1].setdefault(m.group(1).strip(), m.group(2).strip())
    return sections


def _get(sec: dict[str, str], key: str) -> str | None:
    """A value by key, ignoring case."""
    if key in sec:
        return sec[key]
    low = key.lower()
    return next((v for k, v in sec.items() if k.lower() == low), None)


def _number(text: str | None, what: str) -> float:
    if text is None:
        raise ValueError(f"the header has no {what}")
    m = re.match(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)", text)
    if m is None:
        raise ValueError(f"{what} = {text!r} is not a number")
    return float(m.group(1))


def _scaled(text: str | None, what: str) -> tuple[str, float | None, float, str]:
    """(soft scale name, hard scale [unit/LSB] or ``None`` if unreadable, value, unit)."""
    if text is None:
        raise ValueError(f"the header has no {what}")
    m = _SCALED.match(text)
    if m is None:
        raise ValueError(f"{what} = {text!r} is not a scaled value")
    soft, hard, rest = m.group(1) or "", m.group(2), m.group(3)
    try:
        lsb = _number(hard, what) if hard else None
    except ValueError:
        lsb = None  # e.g. "(\Data length V/LSB)" in a NanoScope 9.2 force list
    value = _number(rest, what)
    unit = rest.strip().split()[-1] if len(rest.split()) > 1 else ""
    return soft.strip(), lsb, value, unit


def _sens(sections, name: str) -> float:
    """A ``\\@Sens. <name>`` sensitivity [nm/V] from any section."""
    key = f"@Sens. {name}"
    for _, sec in sections:
        v = _get(sec, key)
        if v is not None:
            parts = v.split()
            if len(parts) < 2 or parts[0] != "V":
                raise ValueError(f"{key} = {v!r} is not a sensitivity in V")
            unit = parts[2] if len(parts) > 2 else "nm/V"
            if unit != "nm/V":
                raise ValueError(f"{key} is in {unit!r}; nm/V is read")
            val = _number(parts[1], key)
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"{key} = {val} is not a positive sensitivity")
            return val
    raise ValueError(f"the header has no {key}")


def _one(sections, name: str) -> dict[str, str]:
    found = [sec for nm, sec in sections if nm.lower() == name.lower()]
    if not found:
        raise ValueError(f"the header has no \\*{name} section")
    return found[0]


# --- reading --------------------------------------------------------------------------------

#: The 32-bit force-volume deflection: this many more bits than the 16-bit LSB of its
#: ``Z scale`` (see read_bruker).
_FVOL32_SHIFT = 256.0
#: A 32-bit channel's scale must bring the approach's rise above its start to within
#: this factor of the file's relative trigger threshold (the 90th percentile of the
#: curves; the two 32-bit files checked: 0.98–1.07 on every curve).
_TRIGGER_TOLERANCE = 1.25


def _channel_kind(sec: dict[str, str]) -> tuple[str | None, str]:
    """(``"deflection"``, ``"height sensor"`` or ``None``, the channel's name)."""
    image = _get(sec, "@4:Image Data") or ""
    m = re.search(r'"([^"]*)"', image)
    name = m.group(1) if m else image
    soft = _scaled(_get(sec, "@4:Z scale"), "@4:Z scale")[0]
    if soft == "Sens. DeflSens":
        return "deflection", name
    if soft == "Sens. ZsensSens":
        return "height sensor", name
    return None, name


def _trigger(force_list: dict[str, str]) -> tuple[str, float | None]:
    """(trigger mode, relative deflection threshold [V] or ``None``)."""
    mode = (_get(force_list, "Trigger mode") or "").strip()
    thr = _get(force_list, "@4:Trig threshold Deflection")
    if thr is None:
        return mode, None
    soft, _, value, unit = _scaled(thr, "@4:Trig threshold Deflection")
    if unit != "V" or soft != "Sens. DeflSens":
        return mode, None
    return mode, value


def read_bruker(path, *, sensitivity: float | None = None) -> list[BrukerCurve]:
    """Read every curve of a Bruker NanoScope force curve or force volume.

    **Arguments:**

    - `path`: the file (``.spm``, ``.000``, ``.001``, ...; it must start with
      ``\\*Force file list``).
    - `sensitivity` [m/V]: replaces the file's deflection sensitivity ``@Sens. DeflSens``.

    **Returns:** one :class:`BrukerCurve` per curve (a force volume: row by row, the
    first stored row at grid y index 0 when ``Frame direction`` is ``Up``, the last when
    ``Down``; metadata ``grid index x``/``y``, ``grid shape x``/``y``, ``grid size
    x``/``y`` [m] (``Scan Size``), ``position x``/``y`` [m] (cell centres, 0 at the
    scan's lower left corner, in the scan frame), ``spring constant`` [N/m],
    ``sensitivity`` [m/V], ``rate approach``/``retract`` [Hz], ``trigger threshold``
    [V], ...). The whole file is one block of integers: it reads completely or not at
    all (a `ValueError`).

    **The 32-bit deflection scale.** NanoScope 9.2 stores 4-byte integers. In the
    32-bit single curve checked (``tests/data``), LSB × V/LSB of ``@4:Z scale`` gives
    volts as in 16-bit files; in the 32-bit force volume checked (``benchmarks/data``)
    it gives 256 times too much (a 309 V peak; every stored value is a multiple of 256,
    up to rounding of negative ones). The evidence is the instrument's own trigger:
    ``Trigger mode: Relative`` stops the approach when the deflection has risen by
    ``@4:Trig threshold Deflection`` above its start, so the rise of every triggered
    approach equals the threshold up to the overshoot of a sample or two. With the
    16-bit scale for the single curve and 1/256 of it for the force volume, the rise is
    1.06 × the threshold on the single curve and 0.98–1.05 × on all 256 curves of the
    map (the 16-bit sapphire curve: 1.02 ×). The reader applies these scales to 32-bit
    files and checks each such file the same way: the 90th percentile of its curves'
    rise over the threshold must lie within a factor 1.25; a 32-bit file that fails this
    or has no relative deflection trigger to check against is a `ValueError` that says
    so (its scale is not known). 16-bit files are read as they are.

    **Raises:** `ValueError` for a file that is not a readable NanoScope force file (no
    magic, no header end, a PeakForce capture or other mode, a data block past the end
    of the file, an unverifiable 32-bit scale, hold segments); the message says why.
    """
    path = pathlib.Path(path)
    raw = path.read_bytes()
    if not raw.startswith(BRUKER_MAGIC):
        raise ValueError("not a Bruker NanoScope force file (it does not start with "
                         "\\*Force file list)")
    if path.suffix.lower() == ".pfc":
        raise ValueError("PeakForce capture (.pfc) files are not read (their layout is "
                         "not verified)")
    sections = parse_header(raw[:_HEADER_LIMIT])
    head = sections[0][1]
    scan = _one(sections, "Ciao scan list")
    flist = _one(sections, "Ciao force list")
    channels = [sec for nm, sec in sections if nm.lower() == "ciao force image list"]
    if not channels:
        raise ValueError("the header has no \\*Ciao force image list (no force data)")
    context = (_get(head, "Start context") or "").strip().upper()
    mode = (_get(scan, "Operating mode") or "").strip()
    if context == "FVOL" or mode.lower() == "force volume":
        volume = True
    elif context == "FOL" and mode.lower() == "force":
        volume = False
    else:
        raise ValueError(f"Start context {context!r}, Operating mode {mode!r}: only force "
                         "curves (FOL, Force) and force volumes (FVOL, Force Volume) are "
                         "read")
    for key in ("Hold Samples", "Hold Time"):
        v = _get(flist, key)
        if v is not None and _number(v, key) != 0:
            raise ValueError(f"{key} = {v}: curves with a hold segment are not read "
                             "(their layout is not verified)")

    if volume:
        nx = int(_number(_get(flist, "force/line"), "force/line (\\*Ciao force list)"))
        ny = int(_number(_get(scan, "Lines"), "Lines (\\*Ciao scan list)"))
    else:
        nx = ny = 1
    count = nx * ny
    if count < 1:
        raise ValueError(f"a grid of {nx} × {ny} curves")

    # the channels
    defl = height = None
    for sec in channels:
        kind, name = _channel_kind(sec)
        if kind == "deflection" and defl is None:
            defl = (sec, name)
        elif kind == "height sensor" and height is None:
            height = (sec, name)
    if defl is None:
        names = [_channel_kind(s)[1] for s in channels]
        raise ValueError(f"no deflection channel (soft scale Sens. DeflSens); the file has "
                         f"{names}")
    n_ext, n_ret = _samples(defl[0])
    n = n_ext + n_ret
    data = {}
    width = {}
    for kind, ch in (("deflection", defl), ("height sensor", height)):
        if ch is None:
            continue
        sec, name = ch
        if _samples(sec) != (n_ext, n_ret):
            raise ValueError(f"channel {name!r}: Samps/line {_samples(sec)} differ from the "
                             f"deflection's {(n_ext, n_ret)}")
        offset = int(_number(_get(sec, "Data offset"), f"Data offset of {name!r}"))
        length = int(_number(_get(sec, "Data length"), f"Data length of {name!r}"))
        if length % (count * n) or length // (count * n) not in (2, 4):
            raise ValueError(f"channel {name!r}: Data length {length} bytes is not 2 or 4 "
                             f"bytes for each of {count} curves × {n} samples")
        w = length // (count * n)
        if offset + length > len(raw):
            raise ValueError(f"channel {name!r}: its data end at byte {offset + length}, "
                             f"the file has {len(raw)} bytes (truncated?)")
        ints = np.frombuffer(raw, dtype=f"<i{w}", count=count * n, offset=offset)
        soft, lsb, _, unit = _scaled(_get(sec, "@4:Z scale"), f"@4:Z scale of {name!r}")
        if lsb is None or unit != "V":
            raise ValueError(f"channel {name!r}: @4:Z scale gives no V/LSB")
        volts = ints.astype(np.float64).reshape(count, n) * lsb
        if w == 4 and volume:
            volts = volts / _FVOL32_SHIFT
        data[kind] = volts
        width[kind] = w

    # scales
    nm_per_v = sensitivity * 1e9 if sensitivity is not None else _sens(sections, "DeflSens")
    if not (math.isfinite(nm_per_v) and nm_per_v > 0):
        raise ValueError(f"sensitivity must be finite and > 0 [m/V], got {sensitivity}")
    k = _number(_get(defl[0], "Spring Constant"),
                f"Spring Constant of the {defl[1]!r} channel")
    if not (math.isfinite(k) and k > 0):
        raise ValueError(f"Spring Constant = {k} N/m of the {defl[1]!r} channel is not "
                         "positive")
    ramp_v = _ramp_size(defl[0], flist)
    zsens = _sens(sections, "Zsens")
    ramp_m = ramp_v * zsens * 1e-9

    tmode, threshold = _trigger(flist)
    # time order: approach from its start to the turnaround, then the retract
    ext_v = data["deflection"][:, n_ext - 1::-1]
    rise = ext_v[:, -1] - ext_v[:, :max(1, min(16, n_ext // 8))].mean(axis=1)
    ratio = (float(np.percentile(rise, 90)) / threshold
             if threshold and tmode.lower() == "relative" else None)
    if width["deflection"] == 4:
        if ratio is None:
            raise ValueError(f"32-bit deflection data without a relative deflection trigger "
                             f"(Trigger mode {tmode!r}): the scale of such files is not "
                             "verified, so they are not read")
        if not (1 / _TRIGGER_TOLERANCE <= ratio <= _TRIGGER_TOLERANCE):
            raise ValueError(f"32-bit deflection data: the approaches rise {ratio:.3g} × the "
                             f"relative trigger threshold ({threshold:g} V), not about 1: "
                             "the scale of this file is not known, so it is not read")

    if "height sensor" in data:
        z_m = data["height sensor"] * _sens(sections, "ZsensSens") * 1e-9
        z_ext = z_m[:, n_ext - 1::-1]
        span = z_ext[:, -1] - z_ext[:, 0]
        if float(np.median(span)) <= 0:
            raise ValueError("the height sensor does not grow toward the sample on the "
                             "approach (unexpected orientation)")
        if width["height sensor"] == 4:
            r = float(np.percentile(span, 90)) / ramp_m
            if not (1 / _TRIGGER_TOLERANCE <= r <= _TRIGGER_TOLERANCE):
                raise ValueError(f"32-bit height sensor data span {r:.3g} × the ramp size: "
                                 "their scale is not known, so the file is not read")
        toward = np.concatenate([z_ext, z_m[:, n_ext:]], axis=1)
        hcol = "height (measured)"
    else:
        step = ramp_m / n_ext
        toward = np.broadcast_to(np.concatenate([np.arange(n_ext) * step,
                                                 (n_ext - 1 - np.arange(n_ret)) * step]),
                                 (count, n))
        hcol = "height (piezo)"

    time, rates = _time(flist, ramp_v, n_ext, n_ret)
    force = np.concatenate([ext_v, data["deflection"][:, n_ext:]], axis=1) \
        * (nm_per_v * 1e-9 * k)
    segment = np.repeat(np.array([0, 1], dtype=np.int64), [n_ext, n_ret])

    meta_all = _metadata(head, scan, flist, defl, height, volume, nx, ny, k,
                         nm_per_v * 1e-9, ramp_m, threshold, tmode, ratio, rates,
                         width["deflection"])
    frame = (_get(defl[0], "Frame direction") or "Up").strip().lower()
    curves: list[BrukerCurve] = []
    for c in range(count):
        meta = dict(meta_all, enum=c)
        if volume:
            gx, row = c % nx, c // nx
            gy = ny - 1 - row if frame == "down" else row
            meta.update({"grid index x": gx, "grid index y": gy})
            size = meta.get("grid size x")
            if size is not None:
                meta["position x"] = (gx + 0.5) * size / nx
                meta["position y"] = (gy + 0.5) * meta["grid size y"] / ny
        cols = {"force": force[c], hcol: -np.asarray(toward[c], dtype=np.float64),
                "segment": segment}
        if time is not None:
            cols["time"] = time
        curves.append(BrukerCurve(data=cols, metadata=meta,
                                  segment_names=("approach", "retract"),
                                  styles=("extend", "retract")))
    return curves


def _samples(sec) -> tuple[int, int]:
    v = _get(sec, "Samps/line")
    parts = (v or "").split()
    if len(parts) != 2:
        raise ValueError(f"Samps/line = {v!r} is not 'n_extend n_retract'")
    n_ext, n_ret = (int(_number(p, "Samps/line")) for p in parts)
    if n_ext < 2 or n_ret < 2:
        raise ValueError(f"Samps/line = {v!r}: fewer than 2 samples in a segment")
    return n_ext, n_ret


def _ramp_size(defl, flist) -> float:
    """The Z ramp [V of the piezo]."""
    for sec, key in ((defl, "@4:Ramp size"), (flist, "@4:Ramp size Zsweep"),
                     (flist, "Ramp size")):
        v = _get(sec, key)
        if v is not None:
            _, _, value, unit = _scaled(v, key)
            if unit != "V" or not (math.isfinite(value) and value > 0):
                raise ValueError(f"{key} = {v!r} is not a positive size in V")
            return value
    raise ValueError("the header has no ramp size (@4:Ramp size)")


def _time(flist, ramp_v, n_ext, n_ret):
    """(time [s] of the samples in time order or ``None``, {"approach": Hz, ...})."""
    fwd, rev = _get(flist, "Forward vel."), _get(flist, "Reverse vel.")
    durations = None
    if fwd is not None and rev is not None:
        vf, vr = _number(fwd, "Forward vel."), _number(rev, "Reverse vel.")
        if vf > 0 and vr > 0:
            durations = (ramp_v / vf, ramp_v / vr)
    if durations is None and _get(flist, "Scan rate") is not None:
        rate = _number(_get(flist, "Scan rate"), "Scan rate")
        if rate > 0:
            durations = (0.5 / rate, 0.5 / rate)
    if durations is None:
        return None, {}
    dt_e, dt_r = durations[0] / n_ext, durations[1] / n_ret
    t = np.concatenate([np.arange(n_ext) * dt_e, n_ext * dt_e + np.arange(n_ret) * dt_r])
    return t, {"approach": 1 / dt_e, "retract": 1 / dt_r,
               "durations": durations}


def _metadata(head, scan, flist, defl, height, volume, nx, ny, k, sens_m, ramp_m,
              threshold, tmode, ratio, rates, width) -> dict[str, Any]:
    meta: dict[str, Any] = {
        "software": "NanoScope", "imaging mode": "force-distance",
        "spring constant": k, "sensitivity": sens_m, "ramp size": ramp_m,
        "deflection channel": defl[1], "bytes per sample": width,
        "height channel": height[1] if height else "ramp (no height sensor)",
        "trigger mode": tmode,
    }
    if threshold is not None:
        meta["trigger threshold"] = threshold
    if ratio is not None:
        meta["trigger rise ratio"] = ratio
    for key, name in (("software version", "Version"), ("date", "Date")):
        if _get(head, name):
            meta[key] = _get(head, name)
    if rates:
        meta["rate approach"] = rates["approach"]
        meta["rate retract"] = rates["retract"]
        meta["duration"] = sum(rates["durations"])
    if volume:
        meta.update({"grid shape x": nx, "grid shape y": ny})
        size = _get(scan, "Scan Size")
        aspect = (_get(scan, "Aspect Ratio") or "1:1").replace(" ", "")
        if size is not None and aspect == "1:1":
            parts = size.split()
            unit = parts[1] if len(parts) > 1 else "nm"
            factor = {"nm": 1e-9, "~m": 1e-6, "um": 1e-6, "µm": 1e-6}.get(unit)
            if factor is not None:
                meta["grid size x"] = meta["grid size y"] = _number(size, "Scan Size") * factor
    return meta
