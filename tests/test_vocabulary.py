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
