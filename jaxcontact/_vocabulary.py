r"""The parameter vocabulary: one registry of the model parameters' names, units, kinds and
bounds, shared by `jaxcontact.sweep` (`_sweep/_parameters.py`), the fits (`fitting._spec`)
and the command line (`jaxcontact_cli._sweep`).

Each `Parameter` has a `name` (as the sweep, the fits and the outputs spell it), a `unit`
(SI, written one way: ``Pa``, ``Pa s``, ``s``, ``J/m^2``, ``m``, ``m/s``, ``rad``, ``N``,
``N/s``), a
`kind` (the physical dimension: ``modulus``, ``viscosity``, ``time``, ``adhesion``,
``length``, ``velocity``, ``angle``, ``force``, ``force_rate``; the sweep scales by it, the
fits choose
their parameterisation and default bounds by it), its bounds (`allow_zero`: the lower
bound is $\ge 0$ instead of $> 0$; `upper`: an open upper bound; `signed`: any sign, no
lower bound — the fits' offsets) and a `long_name` (a sentence for the outputs' metadata).

Column names in tables carry the unit where characters such as ``/`` and spaces do not fit
(``work_of_adhesion_J_m2``, ``eta1_Pa_s``): `column_unit` writes a unit that way, and
`Parameter.column` the whole name. The Prony arms ``G_k``, ``tau_k`` ($k \ge 1$) follow a
pattern (`parameter`).

Adding a parameter (a new rheology's or profile's) means adding it here: the sweep, the fits
and the command line then agree on its unit and range.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

__all__ = ["Parameter", "PARAMETERS", "ARM_PATTERN", "parameter", "column_unit",
           "STRESS_KINDS"]

#: The kinds whose unit carries the stress scale to the first power (Pa, Pa s, J/m^2 = Pa m):
#: the models have no other stress scale, so with every parameter of these kinds multiplied
#: by $\lambda$ (lengths and times kept) the displacements and the contact radius stay and
#: every stress and force is multiplied by $\lambda$ (the energetic criterion compares
#: $\Delta\gamma$ with an energy release rate $\propto$ stress$^2$/modulus, both
#: $\propto\lambda$). A cantilever's stiffness [N/m] is such a scale too: under compliant
#: loading the force is homogeneous only with it scaled.
STRESS_KINDS = frozenset({"modulus", "viscosity", "adhesion"})

#: Units as written in column names (no ``/``, no spaces).
_COLUMN_UNITS = {"Pa s": "Pa_s", "J/m^2": "J_m2", "m/s": "m_s", "N/s": "N_s"}


def column_unit(unit: str) -> str:
    """`unit` as written in a column name: ``"J/m^2"`` → ``"J_m2"``, ``"Pa s"`` →
    ``"Pa_s"``, ``"m/s"`` → ``"m_s"``; the others unchanged."""
    return _COLUMN_UNITS.get(unit, unit)


@dataclass(frozen=True)
class Parameter:
    """One model parameter: name, SI unit, kind (physical dimension), bounds, meaning
    (module docstring)."""

    name: str
    unit: str
    kind: str
    long_name: str
    allow_zero: bool = False
    upper: float | None = None
    signed: bool = False

    @property
    def column(self) -> str:
        """The column name with its unit, e.g. ``work_of_adhesion_J_m2``."""
        return f"{self.name}_{column_unit(self.unit)}"


def _p(*args, **kwargs) -> tuple[str, Parameter]:
    p = Parameter(*args, **kwargs)
    return p.name, p


#: The registry: every named parameter of the models, the sweep and the fits.
PARAMETERS: dict[str, Parameter] = dict([
    # rheology
    _p("G0", "Pa", "modulus", "glass shear modulus G0 (standard model)"),
    _p("G1", "Pa", "modulus", "Kelvin-element shear modulus G1 (standard model)"),
    _p("eta1", "Pa s", "viscosity", "Kelvin-element viscosity eta1"),
    _p("G_inf", "Pa", "modulus", "relaxed shear modulus G_inf (Prony series)"),
    _p("G", "Pa", "modulus", "shear modulus G (elastic solid)"),
    # indenter
    _p("R", "m", "length", "indenter radius of curvature R (paraboloid)"),
    _p("sphere_radius", "m", "length", "exact sphere radius R"),
    _p("half_angle", "rad", "angle", "cone half-opening angle", upper=math.pi / 2),
    _p("punch_radius", "m", "length", "flat punch radius"),
    # adhesion
    _p("work_of_adhesion", "J/m^2", "adhesion", "work of adhesion (delta gamma)"),
    # protocol
    _p("depth", "m", "length", "indentation depth before the lift d0"),
    _p("velocity", "m/s", "velocity", "lift speed v"),
    _p("hold", "s", "time", "hold time at the depth", allow_zero=True),
    _p("approach_velocity", "m/s", "velocity", "approach speed"),
    # the fits' offsets (any sign)
    _p("contact_offset", "m", "length", "contact-point offset delta (added to the measured "
       "indentation)", signed=True),
    _p("force_offset", "N", "force", "force offset F0 (added to the model force)",
       signed=True),
    _p("force_drift", "N/s", "force_rate", "force drift s (a line F0 + s t added to the model "
       "force, t from the first fitted sample)", signed=True),
])

ARM_PATTERN = re.compile(r"^(G|tau)_([1-9][0-9]*)$")


def parameter(name: str) -> Parameter:
    """The `Parameter` of `name` (the registry, or a Prony arm ``G_k``/``tau_k``);
    `ValueError` naming the known ones for an unknown name."""
    if name in PARAMETERS:
        return PARAMETERS[name]
    m = ARM_PATTERN.match(name)
    if m:
        k = m.group(2)
        if m.group(1) == "G":
            return Parameter(name, "Pa", "modulus", f"Prony arm {k} shear modulus G_{k}")
        return Parameter(name, "s", "time", f"Prony arm {k} relaxation time tau_{k}")
    known = ", ".join([*PARAMETERS, "G_k", "tau_k"])
    raise ValueError(f"unknown parameter {name!r}; known: {known}.")
