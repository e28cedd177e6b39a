r"""What is fitted: the model choice (:class:`ModelSpec`) and its parameters.

Parameters, in vector order (natural units, SI):

* standard model (creep form, paper section 3): $G_0$ [Pa] (glass), $G_1$ [Pa] and
  $\eta_1$ [Pa s] (the Kelvin element);
* ``prony:N`` (relaxation form): $G_\infty$ [Pa], $G_1..G_N$ [Pa], $\tau_1..\tau_N$ [s];
* ``elastic``: one shear modulus $G$ [Pa] (glass and relaxed moduli coincide: Hertz/MDR on
  the approach, JKR with the energetic (Griffith) criterion on the retract);
* always the work of adhesion $\Delta\gamma$ [J/m²];
* optionally a contact-point offset $\delta$ [m] (added to the measured indentation:
  the model sees $d + \delta$; $\delta > 0$ means the true contact was *before* the
  detected one) and a force offset $F_0$ [N] (added to the model force: a baseline
  error).

The material parameters and $\Delta\gamma$ are positive and fitted in logarithms; the two
offsets take any sign and are fitted linearly (:class:`fitting._parameters.Parameterisation`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

import jaxcontact as jc
from jaxcontact._vocabulary import PARAMETERS, column_unit, parameter

__all__ = [
    "ModelSpec",
    "make_spec",
    "parameter_info",
    "n_material",
    "build_rheology",
    "canonical_name",
    "normalise_names",
    "rheology_name",
    "RHEOLOGIES",
    "RheologyKind",
]

#: Units of the parameters, as written in column names (the registry's,
#: :mod:`jaxcontact._vocabulary`).
UNITS = tuple(dict.fromkeys(column_unit(p.unit) for p in PARAMETERS.values()))


def _info(name: str) -> tuple[str, str, str]:
    """(short name, unit as in column names, kind) of a parameter of the registry
    (:mod:`jaxcontact._vocabulary`); the kind of a signed parameter (an offset) is
    ``offset_<kind>``: fitted linearly, not in logarithms."""
    p = parameter(name)
    return name, column_unit(p.unit), ("offset_" if p.signed else "") + p.kind


@dataclasses.dataclass(frozen=True)
class RheologyKind:
    """One rheology the fits offer (an entry of :data:`RHEOLOGIES`).

    **Fields:** `arms` (`None`: the name takes no argument and has this many arms, given by
    `fixed_arms`; else the allowed range `(lo, hi)` of N in ``"name:N"``), `fixed_arms`,
    `parameters` (arms → `[(short name, unit, kind), ...]` of the rheology's parameters, in
    vector order), `build` ((natural parameters, arms) → a jaxcontact rheology),
    `from_moduli` ((relaxed modulus, glass modulus, relaxation times, arm shares, arms) →
    `{name: value}`: the parameters of a material with these moduli; the starts of a fit),
    `help` (the parameters, in words).
    """

    arms: tuple[int, int] | None
    fixed_arms: int
    parameters: Callable[[int], list[tuple[str, str, str]]]
    build: Callable
    from_moduli: Callable[..., dict[str, float]]
    help: str


def _standard_moduli(g_inf, g_glass, taus, weights, arms):
    g0 = g_glass
    g1 = g0 * g_inf / (g0 - g_inf)
    return {"G0": g0, "G1": g1, "eta1": float(taus[0]) * (g0 + g1)}


def _prony_moduli(g_inf, g_glass, taus, weights, arms):
    out = {"G_inf": g_inf}
    for k in range(arms):
        out[f"G_{k + 1}"] = (g_glass - g_inf) * float(weights[k])
        out[f"tau_{k + 1}"] = float(taus[k])
    return out


def _prony_parameters(arms):
    return ([_info("G_inf")] + [_info(f"G_{k + 1}") for k in range(arms)]
            + [_info(f"tau_{k + 1}") for k in range(arms)])


#: The rheologies of a fit, by name (``rheology="standard"``, ``"prony:N"``, ``"elastic"``).
RHEOLOGIES: dict[str, RheologyKind] = {
    "standard": RheologyKind(
        arms=None, fixed_arms=1,
        parameters=lambda arms: [_info("G0"), _info("G1"), _info("eta1")],
        build=lambda p, arms: jc.StandardModel(p[0], p[1], p[2]),
        from_moduli=_standard_moduli, help="G0 [Pa], G1 [Pa], eta1 [Pa s]"),
    "prony": RheologyKind(
        arms=(1, 8), fixed_arms=0, parameters=_prony_parameters,
        build=lambda p, arms: jc.PronySeries(p[0], p[1:1 + arms], p[1 + arms:1 + 2 * arms]),
        from_moduli=_prony_moduli, help="G_inf, G_1..G_N [Pa], tau_1..tau_N [s]"),
    "elastic": RheologyKind(
        arms=None, fixed_arms=0, parameters=lambda arms: [_info("G")],
        build=lambda p, arms: jc.Elastic(p[0]),
        from_moduli=lambda g_inf, g_glass, taus, weights, arms: {"G": g_inf},
        help="G [Pa]"),
}


class ModelSpec(eqx.Module):
    """Static description of the forward model (hashable; a jit-static argument).

    **Fields:** `model` ("relaxed": :func:`jaxcontact.retract` on the retract segment;
    "history": :func:`jaxcontact.simulate` on approach, hold and retract), `rheology`
    (a key of :data:`RHEOLOGIES`: "standard", "prony" or "elastic"), `arms` (Prony arms; 1
    for the standard model, 0 for the elastic one), `compliant`
    (history model under :class:`jaxcontact.CompliantLoading`), `cells` (foundation grid
    cells of the history model), `contact_offset` (fit the indentation offset $\\delta$),
    `force_offset` (fit the force offset $F_0$).
    """

    model: str = eqx.field(static=True)
    rheology: str = eqx.field(static=True)
    arms: int = eqx.field(static=True)
    compliant: bool = eqx.field(static=True)
    cells: int = eqx.field(static=True)
    contact_offset: bool = eqx.field(static=True, default=False)
    force_offset: bool = eqx.field(static=True, default=False)


def make_spec(model: str = "relaxed", rheology: str = "standard", *,
              compliant: bool = False, cells: int = 32, contact_offset: bool = False,
              force_offset: bool = False) -> ModelSpec:
    """Parse and check the model choice (`rheology` is "standard", "prony:N" with N in
    [1, 8], or "elastic"; see :data:`RHEOLOGIES`). One object per choice (made once: every
    curve of a map shares it)."""
    try:
        return _make_spec(model, rheology, compliant, cells, contact_offset, force_offset)
    except TypeError:  # unhashable arguments: checked (and refused) uncached
        return _make_spec.__wrapped__(model, rheology, compliant, cells, contact_offset,
                                      force_offset)


@functools.lru_cache(maxsize=64)
def _make_spec(model, rheology, compliant, cells, contact_offset, force_offset) -> ModelSpec:
    if model not in ("relaxed", "history"):
        raise ValueError(f"model must be 'relaxed' or 'history'; got {model!r}")
    name, colon, arg = rheology.partition(":") if isinstance(rheology, str) else ("", "", "")
    kind = RHEOLOGIES.get(name)
    if kind is None or (kind.arms is None and colon):
        raise ValueError(f"rheology must be 'standard', 'prony:N' (N in [1, 8]), 'elastic' "
                         f"or 'auto'; got {rheology!r}")
    if kind.arms is None:
        arms = kind.fixed_arms
    else:
        try:
            arms = int(arg)
        except ValueError:
            arms = kind.arms[0] - 1
        if not kind.arms[0] <= arms <= kind.arms[1]:
            raise ValueError(f"rheology '{name}:N' needs an integer N in "
                             f"[{kind.arms[0]}, {kind.arms[1]}]; got {rheology!r}")
    if compliant and model != "history":
        raise ValueError("a compliant loading system (spring_constant) needs model='history'")
    if int(cells) < 2:
        raise ValueError(f"cells must be an integer >= 2; got {cells!r}")
    return ModelSpec(model=model, rheology=name, arms=arms, compliant=bool(compliant),
                     cells=int(cells), contact_offset=bool(contact_offset),
                     force_offset=bool(force_offset))


def rheology_name(spec: ModelSpec) -> str:
    """The rheology's name as given: "standard", "elastic" or "prony:N"."""
    return spec.rheology if RHEOLOGIES[spec.rheology].arms is None else \
        f"{spec.rheology}:{spec.arms}"


def n_material(spec: ModelSpec) -> int:
    """Number of rheology parameters (the work of adhesion follows them)."""
    return len(RHEOLOGIES[spec.rheology].parameters(spec.arms))


def parameter_info(spec: ModelSpec) -> list[tuple[str, str, str]]:
    """(short name, unit, kind) of every parameter, in vector order.

    Kinds: "modulus", "viscosity", "time", "adhesion" (all positive, fitted in logs),
    "offset_length", "offset_force" (any sign, fitted linearly).
    """
    out = list(RHEOLOGIES[spec.rheology].parameters(spec.arms))
    out.append(_info("work_of_adhesion"))
    if spec.contact_offset:
        out.append(_info("contact_offset"))
    if spec.force_offset:
        out.append(_info("force_offset"))
    return out


def build_rheology(spec: ModelSpec, p: Float[Array, " p"]):
    """The rheology for natural parameters `p` (vector order of :func:`parameter_info`)."""
    return RHEOLOGIES[spec.rheology].build(p, spec.arms)


def offsets(spec: ModelSpec, p: Float[Array, " p"]):
    """`(contact_offset, force_offset)` of natural parameters `p` (0 when not fitted)."""
    k = n_material(spec) + 1
    delta = p[k] if spec.contact_offset else jnp.zeros((), p.dtype)
    f0 = p[k + int(spec.contact_offset)] if spec.force_offset else jnp.zeros((), p.dtype)
    return delta, f0


def canonical_name(name: str, names: Sequence[str]) -> str:
    """The short parameter name of `name` (``"G0"`` or ``"G0_Pa"``); `KeyError` if unknown."""
    if name in names:
        return name
    for n in names:
        if name.startswith(n + "_") and name[len(n) + 1:] in UNITS:
            return n
    raise KeyError(f"unknown parameter {name!r}; the parameters are {list(names)}")


def _as_shear(name: str, value, names: Sequence[str]):
    """`(shear name, value / 3)` for a Young's modulus (``"E0"``, ``"E1"``, ``"E"``,
    ``"E_inf"``, ``"E_k"``, with or without ``"_Pa"``) of a shear modulus among `names`
    ($E = 2(1+\nu)G = 3G$, $\nu = 1/2$: the model's incompressible half-space); a pair of
    bounds converted alike, None kept; `KeyError` if `name` is no such modulus."""
    base = name[:-3] if name.endswith("_Pa") else name
    if not base.startswith("E"):
        raise KeyError(name)
    shear = "G" + base[1:]
    if shear not in names or _info(shear)[2] != "modulus":
        raise KeyError(name)

    def third(x):
        return None if x is None else float(x) / 3.0

    if isinstance(value, tuple | list):
        return shear, type(value)(third(x) for x in value)
    return shear, third(value)


def normalise_names(mapping, names, what: str) -> dict:
    """`mapping` keyed by short parameter names (a Young's modulus ``E0``, ``E1``, ``E``,
    ``E_inf``, ``E_k`` is taken as the shear modulus ``G...`` of a third of its value, its
    bounds alike); `ValueError` naming `what` if unknown or given twice."""
    out = {}
    for k, v in (mapping or {}).items():
        try:
            key, val = canonical_name(k, names), v
        except KeyError:
            try:
                key, val = _as_shear(k, v, names)
            except KeyError:
                raise ValueError(f"{what}: unknown parameter {k!r}; the parameters are "
                                 f"{list(names)} (moduli may be given as Young's moduli "
                                 "E = 3G: E0, E1, E, E_inf, E_k)") from None
        if key in out:
            raise ValueError(f"{what}: {key!r} is given twice ({k!r} and its shear or "
                             "Young's form)")
        out[key] = val
    return out
