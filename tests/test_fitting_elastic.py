"""Elastic fits (``rheology="elastic"``) and the choice of segments (``segments=``).

One compiled search serves the fits of this file: the same model (history, elastic,
approach only, 8 cells), the same number of starts and 64 samples per curve.
"""

import math
import pathlib
import warnings

import numpy as np
import pytest

import fitting
import jaxcontact as jc
from fitting._spec import build_rheology, make_spec, parameter_info
from jaxcontact_cli import main

DATA = pathlib.Path(__file__).parent / "data"
TABLE = pathlib.Path(__file__).parents[1] / "benchmarks" / "results" / "nanite_elastic.md"
R = 10e-6
#: fit settings shared by the compiled fits below (one shape, one compilation)
FIT = dict(radius=R, model="history", rheology="elastic", segments=("approach",),
           contact_point="none", cells=8, n_starts=2, local_rounds=0, max_samples=64,
           progress=False)


def hertz(E, d, nu=0.5):
    """Hertz, paraboloid: F = (4/3) E* sqrt(R) d^(3/2), E* = E/(1 - nu^2) (independent of
    the MDR: the textbook closed form)."""
    e_star = E / (1.0 - nu**2)
    return 4.0 / 3.0 * e_star * math.sqrt(R) * np.clip(d, 0.0, None) ** 1.5


def approach_curve(d, f, t=None):
    t = np.linspace(0.0, 1.0, d.size) if t is None else t - t[0]
    return fitting.Curve(time=t, displacement=d, force=f, segment=np.zeros(d.size, int),
                         segment_names=("approach",))


def test_elastic_rheology_vocabulary():
    spec = make_spec("relaxed", "elastic")
    assert [n for n, _, _ in parameter_info(spec)] == ["G", "work_of_adhesion"]
    rh = build_rheology(spec, np.array([2e3, 1e-3]))
    assert isinstance(rh, jc.Elastic) and float(rh.relaxed_modulus) == 2e3
    assert float(rh.glass_modulus) == 2e3  # glass = relaxed: the JKR/Griffith criterion
    for bad in ("elastic:2", "hertz", "prony", "prony:9"):
        with pytest.raises(ValueError, match="rheology"):
            make_spec("relaxed", bad)


def test_segments_choice_is_checked_by_model():
    check = fitting.check_segments
    assert check(None, "history") is None and check("all", "relaxed") is None
    assert check("retract,approach", "history") == ("approach", "retract")
    assert check(("approach",), "history") == ("approach",)
    with pytest.raises(ValueError, match="relaxed model describes the retract"):
        check("approach", "relaxed")
    with pytest.raises(ValueError, match="needs the approach.*model='relaxed'"):
        check(["retract"], "history")
    with pytest.raises(ValueError, match="segments must be names"):
        check("approach,lift", "history")


@pytest.mark.parametrize(("extra", "needle"), [
    (["--segments", "retract", "--model", "history"], "--model relaxed"),
    (["--segments", "approach"], "relaxed model describes the retract"),
    (["--rheology", "elastic:1"], "--rheology"),
])
def test_cli_segment_and_rheology_errors(tmp_path, capsys, extra, needle):
    out = tmp_path / "o"
    assert main(["fit", str(DATA / "sin-force-distance.ibw"), "--radius", "1e-5", "--out",
                 str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "argument --" in err and not out.exists()


def test_cli_hands_segments_and_the_elastic_rheology_to_the_library(monkeypatch, tmp_path):
    seen = {}

    class Stop(SystemExit):  # passes through the command line's error handling
        pass

    def fake(curves, **options):
        seen.update(curves=curves, **options)
        raise Stop

    monkeypatch.setattr(fitting, "fit", fake)
    with pytest.raises(Stop):
        main(["fit", str(DATA / "sin-force-distance.ibw"), "--radius", "1e-5", "--model",
              "history", "--rheology", "elastic", "--segments", "approach", "--out",
              str(tmp_path / "o")])
    assert seen["segments"] == ("approach",) and seen["rheology"] == "elastic"
    # the whole curves reach the library (it selects the segments, after the contact point)
    assert seen["curves"][0].segment_names == ("approach", "retract")


@pytest.fixture(scope="module")
def hertz_fit():
    E = 3e3
    d = np.linspace(-0.3e-6, 2.0e-6, 64)
    f0 = hertz(E, d)
    sigma = 0.01 * float(f0.max())
    f = f0 + sigma * np.random.default_rng(1).normal(size=d.size)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = fitting.fit(approach_curve(d, f), **FIT)
    return E, res, [str(w.message) for w in caught]


def test_elastic_fit_of_a_noisy_hertz_approach_recovers_E(hertz_fit):
    E, res, caught = hertz_fit
    e_fit = next(q for q in res.derived if q["name"] == "E")
    assert res.converged and res.rheology == "elastic"
    assert e_fit["value"] == pytest.approx(3.0 * res["G"], rel=1e-12)
    assert abs(e_fit["value"] - E) < 4.0 * e_fit["stderr"]
    assert e_fit["value"] == pytest.approx(E, rel=0.01)
    assert 0.5 < res.reduced_chi2 < 1.6  # residuals at the noise
    # the approach alone says nothing of the work of adhesion: held, and said so
    j = res.names.index("work_of_adhesion")
    assert res.status[j] == "fixed" and bool(res.fixed[j])
    assert any(m.startswith("work_of_adhesion: not fitted") for m in res.warnings)
    assert any(m.startswith("work_of_adhesion: not fitted") for m in caught)


def test_elastic_report_names_the_modulus(hertz_fit, tmp_path):
    import json

    _, res, _ = hertz_fit
    fitting.write_report(res, tmp_path)
    out = json.loads((tmp_path / "parameters.json").read_text())
    assert out["rheology"] == "elastic"
    text = (tmp_path / "parameters.json").read_text() + (tmp_path / "parameters.csv").read_text()
    assert "G_Pa" in text and "E_Pa" in text and "work_of_adhesion: not fitted" in text


def _nanite_row(curve: str) -> dict:
    """nanite's numbers for `curve` from the committed table (nanite is not a dependency)."""
    for line in TABLE.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells and cells[0] == curve:
            return dict(E=float(cells[1]), shift=float(cells[5]), offset=float(cells[6]))
    raise AssertionError(f"{curve} not in {TABLE}")


def test_elastic_approach_fit_gives_nanites_E(hertz_fit):
    # nanite 4.2.3's Hertz paraboloid fit of the approach (benchmarks/nanite_elastic.py):
    # with its contact point and baseline our elastic fit gives its E within 2 %
    row = _nanite_row("tests/data/force-map-2x2.jpk-force-map #0")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c = fitting.load_curve(DATA / "force-map-2x2.jpk-force-map", baseline="none",
                               contact_point="none")[0]
    app = c.segment == c.segment_names.index("approach")
    curve = approach_curve(c.displacement[app] - row["shift"], c.force[app] + row["offset"],
                           c.time[app])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(curve, **FIT)
    assert 3.0 * res["G"] == pytest.approx(row["E"], rel=0.02)


def jkr_retract(G, dgamma, d0, d):
    """Elastic JKR retract of a paraboloid from depth `d0` under displacement control, by
    the closed forms (E* = 4G): pinned at a0 = sqrt(R d0) while
    d > a0^2/R - sqrt(2 pi a0 dgamma/E*), then F(a) = 4E*a^3/(3R) - sqrt(8 pi dgamma E* a^3)
    on the larger root of d = a^2/R - sqrt(2 pi a dgamma/E*), jump-off at the fold
    a_c = (pi dgamma R^2/(8E*))^(1/3), 0 after."""
    e_star = 4.0 * G
    a0 = math.sqrt(R * d0)
    k = math.sqrt(2.0 * math.pi * dgamma / e_star)
    a_c = (math.pi * dgamma * R**2 / (8.0 * e_star)) ** (1.0 / 3.0)
    out = []
    for di in d:
        if di >= a0**2 / R - k * math.sqrt(a0):  # pinned: a flat punch of radius a0
            out.append(4.0 * e_star * a0**3 / (3.0 * R) - 2.0 * e_star * a0 * (d0 - di))
        elif di >= a_c**2 / R - k * math.sqrt(a_c):
            lo, hi = a_c, a0  # d(a) increases on [a_c, a0]
            for _ in range(100):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if mid**2 / R - k * math.sqrt(mid) < di else (lo, mid)
            a = 0.5 * (lo + hi)
            out.append(4.0 * e_star * a**3 / (3.0 * R)
                       - math.sqrt(8.0 * math.pi * dgamma * e_star * a**3))
        else:
            out.append(0.0)
    return np.array(out)


def test_elastic_retract_only_fit_recovers_G_and_work_of_adhesion():
    # the relaxed model is the retract-only fit; for an elastic solid it is exact
    G, dgamma, d0 = 1e3, 2e-4, 1e-6
    d = np.linspace(d0, -0.6e-6, 96)
    f0 = jkr_retract(G, dgamma, d0, d)
    sigma = 0.005 * float(np.ptp(f0))
    f = f0 + sigma * np.random.default_rng(2).normal(size=d.size)
    c = fitting.Curve(time=(d0 - d) / 1e-6, displacement=d, force=f,
                      segment=np.zeros(d.size, int), segment_names=("retract",))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fitting.fit(c, radius=R, model="relaxed", rheology="elastic",
                          segments="retract", contact_point="none", n_starts=4,
                          local_rounds=0, progress=False)
    assert res.converged
    for name, true in (("G", G), ("work_of_adhesion", dgamma)):
        j = res.names.index(name)
        assert abs(res[name] - true) < 4.0 * res.stderr[j], name
        assert res[name] == pytest.approx(true, rel=0.03), name


def test_moduli_may_be_given_as_youngs_moduli(hertz_fit):
    # E = 3G (incompressible half-space): a start and bounds given in E are those of G = E/3;
    # the same search ends at the same optimum
    E, res, _ = hertz_fit
    d, f = res.curves[0].displacement, res.curves[0].force
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = fitting.fit(approach_curve(d, f), **FIT, initial={"E": 2.5e3},
                            bounds={"E_Pa": (300.0, 3e4)})
    j = again.names.index("G")
    lo, hi = (float(np.exp(again.parameterisation.lower[j])),
              float(np.exp(again.parameterisation.upper[j])))  # G is fitted in logs
    assert (lo, hi) == pytest.approx((100.0, 1e4), rel=1e-12)
    assert again.chi2 == pytest.approx(res.chi2, rel=1e-6)
    assert again["G"] == pytest.approx(res["G"], rel=1e-5)
    with pytest.raises(ValueError, match="unknown parameter 'E_inf'.*Young's moduli"):
        fitting.fit(approach_curve(d, f), **FIT, initial={"E_inf": 1e3})
    with pytest.raises(ValueError, match="'G' is given twice"):
        fitting.fit(approach_curve(d, f), **FIT, initial={"G": 1e3, "E": 3e3})
