"""The elastic Hertz fit of the approach against nanite's, on the same preprocessed data.

nanite (PyPI, the field's fitting tool) is not a dependency: install it beside the project,
e.g. ``pip install --target /tmp/nanite nanite``; the afmformats test curves come with its
source distribution (``pip download --no-deps --no-binary :all: afmformats -d /tmp/afmsd``,
unpacked; MIT licence). Run

    python benchmarks/nanite_elastic.py --nanite /tmp/nanite \\
        --afmformats-data /tmp/afmsd/afmformats-0.18.7/tests/data

For every curve nanite loads it, preprocesses it (``compute_tip_position``,
``correct_force_offset``, ``correct_tip_offset``) and fits its paraboloid Hertz model
``hertz_para`` to the approach (E, contact point and baseline free; radius R, Poisson's
ratio 0.5; no contact-point weighting, ``weight_cp=False``: plain least squares, as ours).
Our fit takes the same approach samples with nanite's contact point and baseline
(indentation $\\delta = $ contact point $-$ tip position, force minus the baseline) and fits
``fitting.fit(..., model="history", rheology="elastic", segments=("approach",),
contact_point="none", n_starts=4, local_rounds=0)`` (one free parameter) with the same
paraboloid (`jaxcontact.Parabola(R)`): one shear
modulus G, $E = 3G$ ($E^* = E/(1-\\nu^2) = 4G$). The ratio of the two E is the check
(issue 27: within 2 %). R only scales both E alike ($E \\propto R^{-1/2}$); the table uses
10 µm for every curve (the probes' radii are not in the files). The folder of nanite is
appended to the end of ``sys.path`` (the project's numpy/scipy win). Writes
``benchmarks/results/nanite_elastic.md``.
"""

from __future__ import annotations

import argparse
import importlib
import pathlib
import sys
import time
import warnings

import numpy as np
from _results import machine, write_table

R = 10e-6  # paraboloid radius [m], the same for nanite and for us
NU = 0.5

#: The shipped curves (tests/data) and the afmformats test curves nanite reads
SHIPPED = ["oocyte-stress-relaxation-cell1-0008.jpk-force", "sin-force-distance.ibw",
           "chiaro-indentation-AEBP1-002.txt", "creep-compliance-polymergel.jpk-force",
           "force-map-2x2.jpk-force-map"]
AFMFORMATS = ["fmt-igor-fd_U3_3_p10004.ibw", "fmt-jpk-fd_spot3-0192.jpk-force",
              "fmt-jpk-fd_flipsign_2015.05.22-15.31.49.352.jpk-force",
              "fmt-jpk-fd_single-modified_2023.jpk-force",
              "fmt-jpk-cc_pr14-brain-2021.06.30.jpk-force",
              "fmt-jpk-fd_map0d_extracted.jpk-force-map",
              "fmt-hdf5-fd_version_0.13.3.h5", "fmt-tab-fd_version_0.13.3.tab",
              "fmt-afm-workshop-fd_single_2021-10-22_14.16.csv"]


def nanite_fit(idnt):
    """nanite's Hertz paraboloid fit of the approach: (E, contact point, baseline, the
    approach's time, tip position and force)."""
    idnt.apply_preprocessing(["compute_tip_position", "correct_force_offset",
                              "correct_tip_offset"])
    params = idnt.get_initial_fit_parameters(model_key="hertz_para")
    params["R"].set(value=R, vary=False)
    params["nu"].set(value=NU, vary=False)
    idnt.fit_model(model_key="hertz_para", params_initial=params, weight_cp=False,
                   segment=0, x_axis="tip position", y_axis="force")
    pf = idnt.fit_properties["params_fitted"]
    app = ~np.asarray(idnt.data["segment"], dtype=bool)
    tip = np.asarray(idnt.data["tip position"])[app]
    force = np.asarray(idnt.data["force"])[app]
    if "time" in idnt.data.columns:
        t = np.asarray(idnt.data["time"])[app]
    else:
        t = np.arange(tip.size, dtype=float)
    ok = np.isfinite(tip) & np.isfinite(force) & np.isfinite(t)
    return (float(pf["E"].value), float(pf["contact_point"].value),
            float(pf["baseline"].value), t[ok], tip[ok], force[ok])


def our_fit(t, tip, force, cp, baseline, max_samples):
    """Our elastic fit of the approach with nanite's contact point and baseline: E [Pa]."""
    import fitting

    t = t - t[0]
    keep = np.r_[True, np.diff(t) > 0]  # strictly increasing time
    c = fitting.Curve(time=t[keep], displacement=(cp - tip)[keep],
                      force=(force - baseline)[keep], segment=np.zeros(int(keep.sum()), int),
                      segment_names=("approach",), limits=None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(c, radius=R, model="history", rheology="elastic",
                          segments=("approach",), contact_point="none",
                          max_samples=max_samples, n_starts=4, local_rounds=0,
                          progress=False)
    return 3.0 * float(res["G"]), res.converged


def _brief(exc) -> str:
    return " ".join(str(exc).split())[:100].replace("|", "/")


def _our_coordinates(path, k, tip, force, cp, baseline) -> tuple[str, str]:
    """nanite's contact point and baseline as a shift of our raw loader's displacement and
    an offset of its force on the approach (`"-"` where the approaches differ)."""
    import fitting

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c = fitting.load_curve(path, baseline="none", contact_point="none")[k]
        app = c.segment == c.segment_names.index("approach")
        d, f = c.displacement[app], c.force[app]
    except (ValueError, IndexError, AttributeError, OSError):
        return "-", "-"
    if d.size != tip.size or np.ptp(d + tip) > 1e-9 * np.ptp(tip) or \
            np.ptp(force - f) > 1e-9 * np.ptp(force):
        return "-", "-"
    shift = float(np.mean(d + tip)) - cp  # indentation cp - tip = d - shift
    offset = float(np.mean(force - f)) - baseline  # force - baseline = f + offset
    return f"{shift:.10e}", f"{offset:.10e}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nanite", default="/tmp/nanite", help="folder with nanite installed")
    ap.add_argument("--afmformats-data", default="/tmp/afmsd/afmformats-0.18.7/tests/data",
                    help="afmformats' tests/data folder")
    ap.add_argument("--max-samples", type=int, default=1000)
    ap.add_argument("--out", default="benchmarks/results/nanite_elastic.md")
    args = ap.parse_args(argv)
    sys.path.append(args.nanite)
    import nanite

    import fitting

    fitting.tune_xla_cpu()
    root = pathlib.Path(__file__).resolve().parents[1]
    files = [("tests/data", root / "tests" / "data" / f) for f in SHIPPED]
    files += [("afmformats", pathlib.Path(args.afmformats_data) / f) for f in AFMFORMATS]
    rows = []
    for where, path in files:
        if rows:
            print(rows[-1], flush=True)
        try:
            group = nanite.load_group(path)
        except BaseException as exc:  # noqa: BLE001 - a file nanite cannot read is a row
            # (afmformats' MissingMetaDataError derives from BaseException)
            if isinstance(exc, KeyboardInterrupt | SystemExit):
                raise
            rows.append(f"| {where}/{path.name} | - | nanite cannot load it: "
                        f"{type(exc).__name__}: {_brief(exc)} | | | | | |")
            continue
        if len(group) == 0:
            rows.append(f"| {where}/{path.name} | - | nanite reads no curve from it | | | | "
                        "| |")
        for k, idnt in enumerate(group):
            name = f"{where}/{path.name}" + (f" #{k}" if len(group) > 1 else "")
            try:
                e_n, cp, base, t, tip, force = nanite_fit(idnt)
            except BaseException as exc:  # noqa: BLE001
                if isinstance(exc, KeyboardInterrupt | SystemExit):
                    raise
                rows.append(f"| {name} | - | nanite's fit failed: {type(exc).__name__}: "
                            f"{_brief(exc)} | | | | | |")
                continue
            shift, offset = _our_coordinates(path, k, tip, force, cp, base)
            t0 = time.perf_counter()
            try:
                e_o, conv = our_fit(t, tip, force, cp, base, args.max_samples)
            except ValueError as exc:
                rows.append(f"| {name} | {e_n:.6g} | ours failed: "
                            f"{_brief(exc)} | | | | | |")
                continue
            dt = time.perf_counter() - t0
            ratio = e_o / e_n
            rows.append(f"| {name} | {e_n:.6g} | {e_o:.6g} | {ratio:.5f} | "
                        f"{'yes' if abs(ratio - 1) <= 0.02 else 'NO'} | {shift} | {offset} | "
                        f"{tip.size} samples, depth {np.max(cp - tip) * 1e6:.3g} µm, "
                        f"ours {dt:.1f} s{'' if conv else ', not converged'} |")
    lines = [
        "# Elastic Hertz fit of the approach: nanite vs jaxcontact",
        "",
        f"Machine, date: {machine()}; nanite {nanite.__version__}.",
        "",
        "Generated by `python benchmarks/nanite_elastic.py` (see its docstring). nanite fits "
        "its paraboloid Hertz model (`hertz_para`, R = 10 µm, ν = 0.5, E, contact point and "
        "baseline free, `weight_cp=False`) to the approach after its preprocessing; "
        "jaxcontact fits `rheology=\"elastic\"`, `segments=(\"approach\",)` (history model, "
        "`Parabola(10 µm)`, E = 3G) to the same samples with nanite's contact point and "
        "baseline. Acceptance: E within 2 %. Shift and offset: nanite's contact point and "
        "baseline in the coordinates of `fitting.load_curve(file, baseline=\"none\", "
        "contact_point=\"none\")` (its approach: indentation = displacement − shift, force = "
        "force + offset; `tests/test_fitting_elastic.py` uses them).",
        "",
        "| curve | nanite E [Pa] | ours E [Pa] | ours / nanite | within 2 % | shift [m] | "
        "offset [N] | notes |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
        *rows,
    ]
    write_table(root / args.out if not pathlib.Path(args.out).is_absolute() else args.out,
                lines)


if __name__ == "__main__":
    importlib.invalidate_caches()
    main()
