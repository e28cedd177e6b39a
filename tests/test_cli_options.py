"""The command line offers what the library has, in the same words (issue 25, items 6
and 7): contact-detection options, the retract baseline, a fit range in indentation, one
`contact_point` vocabulary, one model default, warnings attributed to the caller, and one
count of free parameters."""

import inspect
import pathlib
import warnings

import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting._prepare import CONTACT_POINT, contact_point_mode, prepare_curves
from fitting._spec import make_spec
from jaxcontact_cli import main
from jaxcontact_cli._main import build_parser

ROOT = pathlib.Path(__file__).resolve().parents[1]
IBW = str(ROOT / "tests" / "data" / "sin-force-distance.ibw")


def _fit_args(argv):
    parser = build_parser()
    return parser.parse_args(["fit", *argv])


def test_model_default_agrees():
    default = inspect.signature(fitting.fit).parameters["model"].default
    assert _fit_args(["x.csv", "--radius", "1e-5", "--out", "o"]).model == default
    assert inspect.signature(fitting.fit_each).parameters["model"].default == default
    text = " ".join(build_parser()._subparsers._group_actions[0].choices["fit"]
                    .format_help().split())
    assert f"{default} (default" in text
    # --max-samples said "resample each segment"; the library subsamples each curve
    from fitting._prepare import DEFAULT_MAX_SAMPLES

    assert "subsample each curve (all its segments together) to at most N samples" in text
    assert (f"default {DEFAULT_MAX_SAMPLES['relaxed']} for --model relaxed, "
            f"{DEFAULT_MAX_SAMPLES['history']} for history") in text


class _Stop(SystemExit):  # passes through the command's error handling
    pass


def _captured_fit(monkeypatch, argv):
    """What `jaxcontact fit argv` hands to `fitting.fit` (curves and options), without
    fitting."""
    seen = {}

    def fake(curves, **options):
        seen.update(curves=curves, **options)
        raise _Stop

    monkeypatch.setattr(fitting, "fit", fake)
    with pytest.raises(_Stop):
        main(["fit", *argv])
    return seen


@pytest.mark.parametrize("word", ["fit", "detect", "none", "fixed"])
def test_contact_point_one_vocabulary(monkeypatch, tmp_path, word):
    # the CLI said detect/fit/none and translated; Python took only fit/fixed/None
    seen = _captured_fit(monkeypatch, [IBW, "--radius", "40e-6", "--out",
                                       str(tmp_path / "o"), "--contact-point", word])
    assert seen["contact_point"] == word  # the same word reaches the library
    curve = seen["curves"][0]
    # ... and the library reads it: an offset parameter for "fit" only
    assert contact_point_mode(word, [curve]) == ("fit" if word == "fit" else "fixed")
    assert (curve.contact.method == "none") == (word == "none")
    assert set(CONTACT_POINT) == {"fit", "detect", "none", "fixed"}
    with pytest.raises(ValueError, match="'fit', 'detect', 'none', 'fixed' or None"):
        contact_point_mode("threshold", [curve])


def test_detection_options_reach_the_loader(monkeypatch, tmp_path):
    argv = [IBW, "--radius", "40e-6", "--out", str(tmp_path / "o"), "--threshold", "12",
            "--min-run", "9", "--retract-baseline", "separate"]
    seen = _captured_fit(monkeypatch, argv)
    ref = fitting.load_curve(IBW, threshold=12.0, min_run=9, retract_baseline="separate")[0]
    default = fitting.load_curve(IBW)[0]
    got = seen["curves"][0]
    assert got.contact == ref.contact and got.contact != default.contact
    np.testing.assert_array_equal(got.displacement, ref.displacement)
    np.testing.assert_array_equal(got.force, ref.force)


@pytest.mark.parametrize("extra, needle", [
    (["--threshold", "-3"], "--threshold"),
    (["--min-run", "0"], "--min-run"),
    (["--contact-point", "none", "--threshold", "3"], "--threshold"),
    (["--indentation-range", "2e-6:1e-6"], "--indentation-range"),
    (["--indentation-range", "abc"], "--indentation-range"),
    (["--max-samples", "3"], "--max-samples"),
])
def test_option_errors_name_the_option(tmp_path, capsys, extra, needle):
    out = tmp_path / "o"
    assert main(["fit", IBW, "--radius", "40e-6", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1 and not out.exists()


def test_detection_options_on_a_table_read_as_it_is(tmp_path, capsys):
    table = tmp_path / "t.csv"
    table.write_text("time_s,displacement_m,force_N\n0,0,0\n0.1,1e-7,1e-9\n0.2,2e-7,2e-9\n")
    with pytest.raises(ValueError, match="threshold.*preprocessed"):
        fitting.load_curve(table, threshold=3.0)
    assert main(["fit", str(table), "--radius", "1e-5", "--threshold", "3", "--out",
                 str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--threshold: apply when the table is preprocessed (give --baseline or " in err


def test_indentation_range_is_passed_and_fits_only_that_range(monkeypatch, tmp_path):
    # the library: only samples in the range are residuals; the others keep weight 0
    rheology = jc.StandardModel(G0=10e3, G1=5e3, eta1=50.0)
    ts = np.linspace(0.0, 0.3, 120)
    sol = jc.retract(rheology, jc.Parabola(10e-6), work_of_adhesion=5e-3, depth=1e-6, ts=ts,
                     velocity=8e-6)
    d = np.asarray(sol.displacement)
    curve = fitting.Curve(time=ts, displacement=d, force=np.asarray(sol.force))
    spec = make_spec("relaxed", "standard")
    full = prepare_curves(curve, spec, radius=10e-6)
    part = prepare_curves(curve, spec, radius=10e-6, indentation_range=(2e-7, 8e-7))
    inside = (d >= 2e-7) & (d <= 8e-7)
    assert full.n_measured == len(d) and part.n_measured == int(inside.sum())
    w = np.asarray(part.weight)[0][np.asarray(part.valid)[0] > 0]
    np.testing.assert_array_equal(w, inside.astype(float))
    np.testing.assert_array_equal(np.asarray(part.force), np.asarray(full.force))
    with pytest.raises(ValueError, match=r"no sample with indentation in indentation_range"):
        prepare_curves(curve, spec, radius=10e-6, indentation_range=(2e-6, 3e-6))
    with pytest.raises(ValueError, match="indentation_range"):
        fitting.fit(curve, radius=10e-6, indentation_range=(1.0, 0.0))
    assert "indentation_range" in inspect.signature(fitting.fit_each).parameters
    # the command line hands it over (a range starting below 0 is a value, not an option)
    seen = _captured_fit(monkeypatch, [IBW, "--radius", "40e-6", "--out", str(tmp_path / "o"),
                                       "--indentation-range", "-1e-7:2e-6"])
    assert seen["indentation_range"] == (-1e-7, 2e-6)


def test_library_warnings_point_to_the_caller():
    # IdentifiabilityWarning pointed into the library (_optimise.py:477), so the default
    # filter showed one location for all callers, none of them the user's line
    import types

    from fitting._caller import warn_at_caller

    inner = types.ModuleType("fitting._fake")
    exec("from fitting._caller import warn_at_caller\n"  # noqa: S102 - a module of the package
         "def deep(m):\n    return deeper(m)\n"
         "def deeper(m):\n    warn_at_caller(m, fitting.IdentifiabilityWarning)\n",
         inner.__dict__)
    inner.__dict__["fitting"] = fitting
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = inspect.currentframe().f_lineno + 1
        inner.deep("G1 is not determined")
        warn_at_caller("direct", fitting.ModelValidityWarning)
    assert [w.filename for w in caught] == [__file__, __file__]
    assert caught[0].lineno == line and caught[1].lineno == line + 1
    # no warning of the package goes around it
    for path in (ROOT / "fitting").glob("*.py"):
        text = path.read_text()
        for cat in ("IdentifiabilityWarning", "ModelValidityWarning"):
            assert f"warnings.warn(m, {cat}" not in text, path


def test_summary_counts_free_parameters_as_the_start_line():
    # the start line said "5 free parameter(s)", the summary "4" (one at a bound)
    from fitting._result import FitResult

    rheology = jc.StandardModel(G0=10e3, G1=5e3, eta1=50.0)
    ts = np.linspace(0.0, 0.3, 30)
    sol = jc.retract(rheology, jc.Parabola(10e-6), work_of_adhesion=5e-3, depth=1e-6, ts=ts,
                     velocity=8e-6)
    curve = fitting.Curve(time=ts, displacement=np.asarray(sol.displacement),
                          force=np.asarray(sol.force))
    spec = make_spec("relaxed", "standard")
    data = prepare_curves(curve, spec, radius=10e-6)
    names = ["G0", "G1", "eta1", "work_of_adhesion"]
    n = len(names)
    result = FitResult(
        names=names, units=["Pa", "Pa", "Pa_s", "J_m2"], columns=names,
        values=np.ones(n), stderr=np.ones(n),
        status=["ok", "at upper bound", "ok", "fixed"], covariance=np.eye(n),
        correlation=np.eye(n), fixed=np.array([False, False, False, True]), chi2=1.0,
        reduced_chi2=1.0, n_data=30, n_free=2, r_squared=1.0, r_squared_contact=1.0,
        aic=0.0, bic=0.0, converged=True, start_losses=np.ones(1), spec=spec, data=data,
        curves=[curve], profile=jc.Parabola(10e-6), radius=10e-6)
    head = result.summary().splitlines()[0]
    assert "3 free parameter(s) (1 at a bound, not counted in AIC/BIC)" in head


def test_force_drift_reaches_the_fit(monkeypatch, tmp_path, capsys):
    # the command line's --force-drift is the library's force_drift (offset implied there)
    seen = _captured_fit(monkeypatch, [IBW, "--radius", "40e-6", "--out", str(tmp_path / "o"),
                                       "--model", "history", "--force-drift"])
    assert seen["force_drift"] is True
    seen = _captured_fit(monkeypatch, [IBW, "--radius", "40e-6", "--out", str(tmp_path / "o")])
    assert seen["force_drift"] is False
    assert fitting.FitOptions(radius=1e-5, model="history", force_drift=True).force_offset
    # with the relaxed model: a usage error naming the option, nothing written
    monkeypatch.undo()
    out = tmp_path / "relaxed"
    assert main(["fit", IBW, "--radius", "40e-6", "--out", str(out), "--force-drift"]) == 2
    err = capsys.readouterr().err
    assert "force_drift needs model='history'" in err and "Traceback" not in err
    assert not out.exists()
