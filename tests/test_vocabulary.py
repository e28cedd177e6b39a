"""One vocabulary of parameters (`jaxcontact._vocabulary`) for the sweep, the fits and the CLI."""

import pytest

import fitting
from jaxcontact._sweep._parameters import parameter_info as sweep_info
from jaxcontact._vocabulary import PARAMETERS, column_unit, parameter
from jaxcontact_cli._sweep import _OPTIONS


def test_fits_and_sweep_spell_every_shared_parameter_alike():
    for rheology in ("standard", "prony:3", "elastic"):
        spec = fitting.make_spec("relaxed", rheology, contact_offset=True, force_offset=True)
        for name, unit, kind in fitting.parameter_info(spec):
            p = parameter(name)
            assert unit == column_unit(p.unit)
            assert kind == ("offset_" + p.kind if p.signed else p.kind)
            if not p.signed and name != "G":  # the sweep varies every material parameter
                assert sweep_info(name) == p


def test_column_units_and_names():
    # the outputs' column names: no "/" or spaces
    assert PARAMETERS["work_of_adhesion"].column == "work_of_adhesion_J_m2"
    assert parameter("eta1").column == "eta1_Pa_s"
    assert parameter("tau_12").column == "tau_12_s" and parameter("G_3").kind == "modulus"
    assert all("/" not in column_unit(p.unit) and " " not in column_unit(p.unit)
               for p in PARAMETERS.values())


def test_command_line_options_are_registered_sweep_parameters():
    for name in _OPTIONS.values():
        assert sweep_info(name) is parameter(name)


def test_unknown_names_are_named():
    with pytest.raises(ValueError, match="unknown parameter 'G2'"):
        parameter("G2")
    with pytest.raises(ValueError, match="unknown sweep parameter 'contact_offset'"):
        sweep_info("contact_offset")  # a fit's parameter, not a sweep's


@pytest.fixture
def zener(monkeypatch):
    """A rheology registered as one entry of `fitting._spec.RHEOLOGIES` (for the test only):
    the standard linear solid in its relaxation (Zener) form, G_inf beside one Maxwell arm
    (G_1, tau_1); the caches keyed by the spec are emptied before and after."""
    import jax.numpy as jnp

    import jaxcontact as jc
    from fitting import _spec, _uncertainty

    kind = _spec.RheologyKind(
        arms=None, fixed_arms=1,
        parameters=lambda arms: [_spec._info("G_inf"), _spec._info("G_1"),
                                 _spec._info("tau_1")],
        build=lambda p, arms: jc.PronySeries(p[0], p[1:2], p[2:3]),
        from_moduli=lambda g_inf, g_glass, taus, weights, arms: {
            "G_inf": g_inf, "G_1": g_glass - g_inf, "tau_1": taus[0]},
        derived=lambda arms: ([("G_0", "Pa", "G_inf + G_1")], lambda q: jnp.stack([q[0] + q[1]])),
        help="G_inf, G_1 [Pa], tau_1 [s]",
        relaxation=lambda p, arms: (p["G_inf"], [p["G_1"]], [p["tau_1"]]))
    caches = (_spec._make_spec, _uncertainty.derived_fn)
    for c in caches:
        c.cache_clear()
    monkeypatch.setitem(_spec.RHEOLOGIES, "zener", kind)
    yield kind
    for c in caches:
        c.cache_clear()


def test_a_rheology_registered_once_drives_starts_bounds_and_nesting(zener):
    # everything the fits do for a rheology follows from its one entry; expected: the
    # registered prony:1, the same material with the same parameters, and the jaxcontact
    # PronySeries' own glass modulus
    import jax.numpy as jnp
    import numpy as np

    from fitting import _optimise, _quality, _spec, _start, _uncertainty

    spec, prony1 = (fitting.make_spec("relaxed", r, contact_offset=True)
                    for r in ("zener", "prony:1"))
    names = [n for n, _, _ in fitting.parameter_info(spec)]
    assert names == ["G_inf", "G_1", "tau_1", "work_of_adhesion", "contact_offset"]
    with pytest.raises(ValueError, match="rheology must be"):
        fitting.make_spec("relaxed", "zener:2")  # a fixed number of arms takes no argument
    # a data-based relaxation time (50 s) beyond the curve (8 s): started inside the bounds
    s = fitting.DataScales(g_relaxed=1e3, g_glass=4e3, tau=50.0, tau_min=1e-3, tau_max=80.0,
                           duration=8.0, work_of_adhesion=1e-3, depth=1e-6,
                           force_range=1e-8)
    guess = fitting.initial_guess([], spec, None, s)
    assert guess == fitting.initial_guess([], prony1, None, s)
    assert guess["G_inf"] == 1e3 and guess["G_1"] == 3e3 and 1e-3 < guess["tau_1"] < 8.0
    bounds = fitting.default_bounds(spec, s)
    assert bounds == fitting.default_bounds(prony1, s) and bounds["tau_1"] == (1e-3, 8.0)
    assert _start.search_starts(spec, s, 5, seed=1) == _start.search_starts(prony1, s, 5,
                                                                           seed=1)
    # fitted alone (nothing nested in it), but a Prony series nests from its optimum
    assert fitting.FitOptions(radius=1e-6, rheology="zener").chain() == ["zener"]
    prony2 = fitting.make_spec("relaxed", "prony:2", contact_offset=True)
    assert (_start.nested_starts(prony2, spec, guess, s)
            == _start.nested_starts(prony2, prony1, guess, s))
    with pytest.raises(ValueError, match="takes added arms.*'zener'"):
        _start.nested_starts(spec, prony1, guess, s)
    # its derived quantities, with their Jacobian
    q = jnp.array([guess[n] for n in names])
    rows, fn = _uncertainty.derived_fn(spec)
    value, jac = fn(q)
    assert rows == [("G_0", "Pa", "G_inf + G_1")]
    np.testing.assert_allclose(value, [_spec.build_rheology(spec, q).glass_modulus],
                               rtol=1e-15)
    np.testing.assert_array_equal(jac, [[1, 1, 0, 0, 0]])
    # no interchangeable arms to sort, no simpler rheology to advise
    u, J = np.arange(5.0), np.ones((3, 5))
    u2, J2 = _optimise._sort_arms(spec, None, u, J)
    assert u2 is u and J2 is J
    advice = _quality.convergence(False, 10, 10, simpler=zener.nested(1))["advice"]
    assert not any("simpler rheology" in a for a in advice)
    prony3 = _spec.rheology_kind(fitting.make_spec("relaxed", "prony:3"))
    advice = _quality.convergence(False, 10, 10, simpler=prony3.nested(3))["advice"]
    assert "a simpler rheology, with fewer arms (rheology='prony:2' or 'standard')" in advice
