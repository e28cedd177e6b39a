r"""What is fitted: the model choice (:class:`ModelSpec`) and its parameters.

Parameters, in vector order (natural units, SI):

* standard model (creep form, paper section 3): $G_0$ [Pa] (glass), $G_1$ [Pa] and
  $\eta_1$ [Pa s] (the Kelvin element);
* ``prony:N`` (relaxation form): $G_\infty$ [Pa], $G_1..G_N$ [Pa], $\tau_1..\tau_N$ [s];
* always the work of adhesion $\Delta\gamma$ [J/m²];
* optionally a contact-point offset $\delta$ [m] (added to the measured indentation:
  the model sees $d + \delta$; $\delta > 0$ means the true contact was *before* the
  detected one) and a force offset $F_0$ [N] (added to the model force: a baseline
  error).

The material parameters and $\Delta\gamma$ are positive and fitted in logarithms; the two
offsets take any sign and are fitted linearly (:class:`fitting._parameters.Parameterisation`).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

import jaxcontact as jc

__all__ = [
    "ModelSpec",
    "make_spec",
    "parameter_info",
    "n_material",
    "build_rheology",
    "canonical_name",
    "normalise_names",
    "rheology_name",
]

#: Units of the parameter kinds, as written in column names.
UNITS = ("Pa", "Pa_s", "s", "J_m2", "m", "N")


class ModelSpec(eqx.Module):
    """Static description of the forward model (hashable; a jit-static argument).

    **Fields:** `model` ("relaxed": :func:`jaxcontact.retract` on the retract segment;
    "history": :func:`jaxcontact.simulate` on approach, hold and retract), `rheology`
    ("standard" or "prony"), `arms` (Prony arms; 1 for the standard model), `compliant`
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
    """Parse and check the model choice (`rheology` is "standard" or "prony:N", N ≥ 1)."""
    if model not in ("relaxed", "history"):
        raise ValueError(f"model must be 'relaxed' or 'history'; got {model!r}")
    if rheology == "standard":
        kind, arms = "standard", 1
    elif isinstance(rheology, str) and rheology.startswith("prony:"):
        try:
            arms = int(rheology.split(":", 1)[1])
        except ValueError:
            arms = 0
        if not 1 <= arms <= 8:
            raise ValueError(f"rheology 'prony:N' needs an integer N in [1, 8]; got "
                             f"{rheology!r}")
        kind = "prony"
    else:
        raise ValueError(f"rheology must be 'standard', 'prony:N' (N in [1, 8]) or 'auto'; "
                         f"got {rheology!r}")
    if compliant and model != "history":
        raise ValueError("a compliant loading system (spring_constant) needs model='history'")
    if int(cells) < 2:
        raise ValueError(f"cells must be an integer >= 2; got {cells!r}")
    return ModelSpec(model=model, rheology=kind, arms=arms, compliant=bool(compliant),
                     cells=int(cells), contact_offset=bool(contact_offset),
                     force_offset=bool(force_offset))


def rheology_name(spec: ModelSpec) -> str:
    """"standard" or "prony:N"."""
    return "standard" if spec.rheology == "standard" else f"prony:{spec.arms}"


def n_material(spec: ModelSpec) -> int:
    """Number of rheology parameters (the work of adhesion follows them)."""
    return 3 if spec.rheology == "standard" else 1 + 2 * spec.arms


def parameter_info(spec: ModelSpec) -> list[tuple[str, str, str]]:
    """(short name, unit, kind) of every parameter, in vector order.

    Kinds: "modulus", "viscosity", "time", "adhesion" (all positive, fitted in logs),
    "offset_length", "offset_force" (any sign, fitted linearly).
    """
    if spec.rheology == "standard":
        out = [("G0", "Pa", "modulus"), ("G1", "Pa", "modulus"), ("eta1", "Pa_s", "viscosity")]
    else:
        out = [("G_inf", "Pa", "modulus")]
        out += [(f"G_{k + 1}", "Pa", "modulus") for k in range(spec.arms)]
        out += [(f"tau_{k + 1}", "s", "time") for k in range(spec.arms)]
    out.append(("work_of_adhesion", "J_m2", "adhesion"))
    if spec.contact_offset:
        out.append(("contact_offset", "m", "offset_length"))
    if spec.force_offset:
        out.append(("force_offset", "N", "offset_force"))
    return out


def build_rheology(spec: ModelSpec, p: Float[Array, " p"]):
    """The rheology for natural parameters `p` (vector order of :func:`parameter_info`)."""
    if spec.rheology == "standard":
        return jc.StandardModel(p[0], p[1], p[2])
    n = spec.arms
    return jc.PronySeries(p[0], p[1:1 + n], p[1 + n:1 + 2 * n])


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


def normalise_names(mapping, names, what: str) -> dict:
    """`mapping` keyed by short parameter names; `ValueError` naming `what` if unknown."""
    out = {}
    for k, v in (mapping or {}).items():
        try:
            out[canonical_name(k, names)] = v
        except KeyError:
            raise ValueError(f"{what}: unknown parameter {k!r}; the parameters are "
                             f"{list(names)}") from None
    return out
