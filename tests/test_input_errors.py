"""Errors that name what is wrong (issue 25, items 11 and 12): negative numbers on the
command line reach the range checks, a table's unit conflict is reported as such, a unit
mistake in the BEM inputs is named, constructor fields name themselves, error texts show
plain numbers, and reprs show the values."""

import math

import numpy as np
import pytest

import fitting
import jaxcontact as jc
from jaxcontact_cli import main

SIM = ["simulate", "--G0", "1e6", "--G1", "2e5", "--eta1", "1e4", "--work-of-adhesion", "0.05",
       "--radius", "1e-4", "--depth", "4e-6", "--velocity", "1e-4", "--duration", "0.1"]


def _replace(argv, option, value):
    argv = list(argv)
    argv[argv.index(option) + 1] = value
    return argv


@pytest.mark.parametrize("argv, option, shown", [
    (_replace(SIM, "--radius", "-1e-5"), "--radius", "-1e-05"),
    (_replace(SIM, "--G0", "-1E6"), "--G0", "-1000000.0"),
    (_replace(SIM, "--velocity", "-.5"), "--velocity", "-0.5"),
    (SIM + ["--hold", "-2"], "--hold", "-2.0"),
    (_replace(SIM, "--work-of-adhesion", "-inf"), "--work-of-adhesion", "-inf"),
    (["sweep", *_replace(SIM[1:], "--radius", "-1e-5")[:-2]], "--radius", "-1e-05"),
    (["fit", "x.csv", "--radius", "-1e-5"], "--radius", "-1e-05"),
    (["fit", "x.csv", "--radius", "1e-5", "--spring-constant", "-0.1"], "--spring-constant",
     "-0.1"),
])
def test_negative_numbers_reach_the_range_check(tmp_path, capsys, argv, option, shown):
    # argparse took "-1e-5" for an option: "expected one argument" (SystemExit), naming
    # neither the allowed range nor that the value was read at all
    out = tmp_path / ("o.csv" if argv[0] == "simulate" else "o.nc" if argv[0] == "sweep"
                      else "o")
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"jaxcontact {argv[0]}: error: argument {option}: must be")
    assert f"got {shown}" in err and "expected one argument" not in err
    assert "(0, inf)" in err or "[0, inf)" in err
    assert not out.exists()


def test_table_unit_conflict_is_not_called_an_instrument_file(tmp_path):
    good = tmp_path / "good.csv"
    good.write_text("time_s,displacement_m,force_N\n0,0,0\n0.1,1e-7,1e-9\n0.2,2e-7,2e-9\n")
    with pytest.raises(fitting.DataError) as info:
        fitting.load_curve(good, units="force=nN")
    msg = str(info.value)
    assert "force_N" in msg and "'N'" in msg and "nN" in msg
    assert "afmformats" not in msg and "instrument" not in msg
    with pytest.raises(fitting.DataError, match="no column 'nope'") as info:
        fitting.load_curve(good, columns={"force": "nope"})
    assert "afmformats" not in str(info.value)


def test_bem_unit_mistake_is_named():
    # a 4000 m displacement (nanometres given as metres) ran the solve and said "enlarge
    # grid.extent"
    grid = jc.BEMGrid(cells=8, extent=4e-5)
    ts = np.linspace(0.0, 1.0, 3)
    with pytest.raises(ValueError, match=r"`displacement`.*4000 m.*other units"):
        jc.bem_simulate(jc.Elastic(1e6), jc.Parabola(1e-4), 0.05, ts,
                        np.array([0.0, 2000.0, 4000.0]), grid=grid)
    with pytest.raises(ValueError, match=r"`relaxed_depth`.*other units"):
        jc.bem_simulate(jc.Elastic(1e6), jc.Parabola(1e-4), 0.05, ts, np.zeros(3), grid=grid,
                        relaxed_depth=2.0)


_FIELDS = [
    (jc.StandardModel, dict(G0=1e6, G1=2e5, eta1=1e4)),
    (jc.Elastic, dict(G=1e6)),
    (jc.PronySeries, dict(G_inf=1e5, G=[1e4, 2e4], tau=[0.5, 2.0])),
    (jc.CreepChain, dict(G0=1e6, G=[1e5], eta=[1e3])),
    (jc.Parabola, dict(R=1e-5)),
    (jc.Cone, dict(half_angle=0.5)),
    (jc.FlatPunch, dict(radius=1e-5)),
    (jc.PowerLaw, dict(c=1e3, n=2.0)),
]


@pytest.mark.parametrize("cls, kwargs", _FIELDS, ids=[c.__name__ for c, _ in _FIELDS])
def test_constructor_fields_name_themselves(cls, kwargs):
    # StandardModel("abc") raised JAX's "Value 'abc' with dtype <U3 is not a valid JAX array
    # type", naming no parameter
    for name in kwargs:
        for bad in ("abc", None, object()):
            with pytest.raises(TypeError, match=rf"^`{name}` must be a .*real number.*\["):
                cls(**{**kwargs, name: bad})
    positional = list(kwargs.values())
    positional[0] = "abc"
    with pytest.raises(TypeError, match=rf"^`{next(iter(kwargs))}`"):
        cls(*positional)


@pytest.mark.parametrize("cls, kwargs", _FIELDS, ids=[c.__name__ for c, _ in _FIELDS])
def test_repr_shows_the_values(cls, kwargs):
    # formerly StandardModel(G0=weak_f64[], ...): the repr now evaluates back to the model
    model = cls(**kwargs)
    text = repr(model)
    assert "f64" not in text and "np." not in text
    again = eval(text, {cls.__name__: cls})  # noqa: S307 - our own repr
    for name, value in kwargs.items():
        np.testing.assert_array_equal(getattr(again, name), np.asarray(value, dtype=float))
    assert repr(cls(**{k: np.float32(v) if np.ndim(v) == 0 else np.asarray(v, np.float32)
                       for k, v in kwargs.items()})).startswith(cls.__name__ + "(")


def test_error_texts_show_plain_numbers(tmp_path):
    # NumPy scalars were formatted with !r: "np.float64(0.2) s after np.float64(0.3) s"
    bad = tmp_path / "t.csv"
    bad.write_text("time_s,displacement_m,force_N\n0,0,0\n0.3,1e-7,1e-9\n0.2,2e-7,2e-9\n")
    messages = []
    for call in (
        lambda: fitting.load_curve(bad),
        lambda: fitting.Curve(time=np.array([0.0, 0.3, 0.2]), displacement=np.zeros(3),
                              force=np.zeros(3)),
        lambda: jc.sweep({"G0": np.array([-1.0]), "G1": 1e5, "eta1": 1e4,
                          "work_of_adhesion": 0.05, "radius": 1e-4, "depth": 1e-6,
                          "velocity": 1e-4}),
    ):
        with pytest.raises(ValueError) as info:
            call()
        messages.append(str(info.value))
    good = tmp_path / "g.csv"
    good.write_text("time_s,displacement_m,force_N\n0,0,0\n0.1,1e-7,1e-9\n0.2,2e-7,2e-9\n")
    curve = fitting.load_curve(good, contact_point="none")[0]
    for kw in (dict(radius=np.float64(-1.0)), dict(radius=1e-5, n_starts=np.int64(0))):
        with pytest.raises(ValueError) as info:
            fitting.fit(curve, model="relaxed", **kw)
        messages.append(str(info.value))
    from fitting._parameters import make_parameterisation

    info_g0 = [("G0", "Pa", "log")]
    for kw in (dict(bounds={"G0": (np.float64(5.0), np.float64(1.0))}),
               dict(fixed={"G0": np.float64(-1.0)})):
        with pytest.raises(ValueError) as info:
            make_parameterisation(info_g0, {"G0": 1.0}, **kw)
        messages.append(str(info.value))
    joined = "\n".join(messages)
    assert "np." not in joined and "float64(" not in joined and "int64(" not in joined
    assert "0.2 s after 0.3 s" in messages[0] and "t[2] = 0.2 s" in messages[1]
    assert "got -1.0" in messages[2] and "got -1.0" in messages[3] and "got 0" in messages[4]
    assert "got (5.0, 1.0)" in messages[5] and "got -1.0" in messages[6]


def test_plain_formats_numbers_as_numbers():
    from jaxcontact._validate import plain

    assert plain(np.float64(1.0)) == "1.0" and plain(np.float32(0.5)) == "0.5"
    assert plain(np.int64(3)) == "3" and plain(np.bool_(True)) == "True"
    assert plain((np.float64(1.0), 2)) == "(1.0, 2)" and plain([np.float64(2.0)]) == "[2.0]"
    assert plain(np.array([1.0, 2.0])) == "[1.0, 2.0]" and plain("abc") == "'abc'"
    assert plain(float("nan")) == "nan" and math.isinf(float(plain(np.float64(np.inf))))
