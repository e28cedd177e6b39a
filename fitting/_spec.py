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
from collections.abc import Callable, Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

import jaxcontact as jc
from jaxcontact._vocabulary import PARAMETERS, STRESS_KINDS, column_unit, parameter

from ._host import once_per_object

__all__ = [
    "ModelSpec",
    "make_spec",
    "parameter_info",
    "n_material",
    "n_model_inputs",
    "stress_scaled",
    "build_rheology",
    "canonical_name",
    "normalise_names",
    "rheology_kind",
    "rheology_name",
    "work_of_adhesion",
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
    """One rheology the fits offer (an entry of :data:`RHEOLOGIES`): everything the fits do
    differently for it, so that a new rheology is one entry.

    **Fields:**

    - `arms`: `None` (the name takes no argument and has `fixed_arms` arms) or the allowed
      range `(lo, hi)` of N in ``"name:N"``; `fixed_arms`.
    - `parameters`: arms → `[(short name, unit, kind), ...]`, the rheology's parameters in
      vector order (a parameter of kind ``"time"``, a relaxation time, is bounded by the
      times the curve resolves and started inside them: :func:`fitting._start.initial_guess`).
    - `build`: (natural parameters, arms) → a jaxcontact rheology.
    - `from_moduli`: (relaxed modulus, glass modulus, relaxation times, arm shares, arms) →
      `{name: value}`, the parameters of a material with these moduli (the starts of a fit);
      elementwise: the moduli may be arrays of shape `(n,)` and the times and shares
      `(arms, n)` (`n` materials at once, :func:`fitting._start.search_points`).
    - `derived`: arms → `(rows, fn)`: the derived quantities reported with a fit, rows
      `(name, unit, definition)`, and `fn` of the natural parameters of the rheology (the
      vector's first :func:`n_material` entries and beyond) returning their values (JAX,
      differentiable: their standard errors by the delta method).
    - `help`: the parameters, in words.
    - `relaxation`: (`{name: value}`, arms) → `(G_inf, [G_k], [tau_k])` [Pa, Pa, s], the
      relaxation (Prony) form of the parameters (a simpler model's optimum read by a nested
      fit); `None`: none offered.
    - `from_relaxation`: (`G_inf`, `[G_k]`, `[tau_k]`) → `{name: value}`, the parameters of
      that relaxation form with any number of arms: the rheology takes the nested starts
      from a simpler model with arms added (:func:`fitting._start.nested_starts`); `None`:
      it does not.
    - `nested`: arms → the simpler rheologies fitted before this one, each started also
      from the previous optimum (:meth:`fitting.FitOptions.chain`; also the advice of a
      fit that did not converge); empty: fitted alone.
    - `arm_indices`: arms → the vector indices of each per-arm parameter, one list per
      parameter, the last the relaxation times: a fit reports the arms in increasing order
      of it (the model does not depend on their order); `None`: no interchangeable arms.
    """

    arms: tuple[int, int] | None
    fixed_arms: int
    parameters: Callable[[int], list[tuple[str, str, str]]]
    build: Callable
    from_moduli: Callable[..., dict[str, float]]
    derived: Callable[[int], tuple[list[tuple[str, str, str]], Callable]]
    help: str
    relaxation: Callable[[Mapping[str, float], int], tuple[float, list, list]] | None = None
    from_relaxation: Callable[[float, Sequence, Sequence], dict[str, float]] | None = None
    nested: Callable[[int], list[str]] = lambda arms: []
    arm_indices: Callable[[int], tuple[list[int], ...]] | None = None


def _standard_moduli(g_inf, g_glass, taus, weights, arms):
    g0 = g_glass
    g1 = g0 * g_inf / (g0 - g_inf)
    return {"G0": g0, "G1": g1, "eta1": taus[0] * (g0 + g1)}


def _standard_relaxation(p, arms):
    g0, g1, eta = p["G0"], p["G1"], p["eta1"]
    g_inf = g0 * g1 / (g0 + g1)
    return g_inf, [g0 - g_inf], [eta / (g0 + g1)]


def _standard_derived(arms):
    rows = [("E0", "Pa", "3 G0"), ("E1", "Pa", "3 G1"),
            ("G_inf", "Pa", "G0 G1 / (G0 + G1), relaxed shear modulus"),
            ("E_inf", "Pa", "3 G_inf"), ("tau", "s", "eta1 / (G0 + G1)")]

    def fn(q):
        g_inf = jc.StandardModel(q[0], q[1], q[2]).relaxed_modulus
        return jnp.stack([3 * q[0], 3 * q[1], g_inf, 3 * g_inf, q[2] / (q[0] + q[1])])

    return rows, fn


def _prony_moduli(g_inf, g_glass, taus, weights, arms):
    out = {"G_inf": g_inf}
    for k in range(arms):
        out[f"G_{k + 1}"] = (g_glass - g_inf) * weights[k]
        out[f"tau_{k + 1}"] = taus[k]
    return out


def _prony_parameters(arms):
    return ([_info("G_inf")] + [_info(f"G_{k + 1}") for k in range(arms)]
            + [_info(f"tau_{k + 1}") for k in range(arms)])


def _prony_build(p, arms):
    return jc.PronySeries(p[0], p[1:1 + arms], p[1 + arms:1 + 2 * arms])


def _prony_relaxation(p, arms):
    return (p["G_inf"], [p[f"G_{k + 1}"] for k in range(arms)],
            [p[f"tau_{k + 1}"] for k in range(arms)])


def _prony_from_relaxation(g_inf, gs, taus):
    out = {"G_inf": g_inf}
    for k, (g, tau) in enumerate(zip(gs, taus, strict=True)):
        out[f"G_{k + 1}"] = float(g)
        out[f"tau_{k + 1}"] = float(tau)
    return out


def _prony_derived(arms):
    rows = [("G_0", "Pa", "G_inf + sum G_k, glass shear modulus"),
            ("E_0", "Pa", "3 G_0"), ("E_inf", "Pa", "3 G_inf")]
    rows += [(f"E_{k + 1}", "Pa", f"3 G_{k + 1}") for k in range(arms)]

    def fn(q):
        r = _prony_build(q, arms)
        return jnp.concatenate([jnp.stack([r.glass_modulus, 3 * r.glass_modulus,
                                           3 * r.relaxed_modulus]), 3 * q[1:1 + arms]])

    return rows, fn


def _prony_nested(arms):
    # prony:N after the standard model (prony:1), prony:2, ..., prony:N-1
    return ["standard"] + [f"prony:{k}" for k in range(2, arms)] if arms > 1 else []


def _prony_arm_indices(arms):
    return list(range(1, 1 + arms)), list(range(1 + arms, 1 + 2 * arms))


def _elastic_derived(arms):
    return [("E", "Pa", "3 G")], lambda q: 3 * q[:1]


#: The rheologies of a fit, by name (``rheology="standard"``, ``"prony:N"``, ``"elastic"``).
RHEOLOGIES: dict[str, RheologyKind] = {
    "standard": RheologyKind(
        arms=None, fixed_arms=1,
        parameters=lambda arms: [_info("G0"), _info("G1"), _info("eta1")],
        build=lambda p, arms: jc.StandardModel(p[0], p[1], p[2]),
        from_moduli=_standard_moduli, derived=_standard_derived,
        help="G0 [Pa], G1 [Pa], eta1 [Pa s]", relaxation=_standard_relaxation),
    "prony": RheologyKind(
        arms=(1, 8), fixed_arms=0, parameters=_prony_parameters, build=_prony_build,
        from_moduli=_prony_moduli, derived=_prony_derived,
        help="G_inf, G_1..G_N [Pa], tau_1..tau_N [s]", relaxation=_prony_relaxation,
        from_relaxation=_prony_from_relaxation, nested=_prony_nested,
        arm_indices=_prony_arm_indices),
    "elastic": RheologyKind(
        arms=None, fixed_arms=0, parameters=lambda arms: [_info("G")],
        build=lambda p, arms: jc.Elastic(p[0]),
        from_moduli=lambda g_inf, g_glass, taus, weights, arms: {"G": g_inf},
        derived=_elastic_derived, help="G [Pa]"),
}


class ModelSpec(eqx.Module):
    """Static description of the forward model (hashable; a jit-static argument).

    **Fields:** `model` ("relaxed": :func:`jaxcontact.retract` on the retract segment;
    "history": :func:`jaxcontact.simulate` on approach, hold and retract), `rheology`
    (a key of :data:`RHEOLOGIES`: "standard", "prony" or "elastic"), `arms` (Prony arms; 1
    for the standard model, 0 for the elastic one), `compliant`
    (history model under :class:`jaxcontact.CompliantLoading`), `cells` (foundation grid
    cells of the history model), `contact_offset` (fit the indentation offset $\\delta$),
    `force_offset` (fit the force offset $F_0$), `force_drift` (fit a force drift $s$ as
    well: the model force plus the line $F_0 + s t$, $t$ from the first fitted sample;
    implies `force_offset`; the history model only).
    """

    model: str = eqx.field(static=True)
    rheology: str = eqx.field(static=True)
    arms: int = eqx.field(static=True)
    compliant: bool = eqx.field(static=True)
    cells: int = eqx.field(static=True)
    contact_offset: bool = eqx.field(static=True, default=False)
    force_offset: bool = eqx.field(static=True, default=False)
    force_drift: bool = eqx.field(static=True, default=False)


def make_spec(model: str = "relaxed", rheology: str = "standard", *,
              compliant: bool = False, cells: int = 32, contact_offset: bool = False,
              force_offset: bool = False, force_drift: bool = False) -> ModelSpec:
    """Parse and check the model choice (`rheology` is "standard", "prony:N" with N in
    [1, 8], or "elastic"; see :data:`RHEOLOGIES`). One object per choice (made once: every
    curve of a map shares it)."""
    try:
        return _make_spec(model, rheology, compliant, cells, contact_offset, force_offset,
                          force_drift)
    except TypeError:  # unhashable arguments: checked (and refused) uncached
        return _make_spec.__wrapped__(model, rheology, compliant, cells, contact_offset,
                                      force_offset, force_drift)


@functools.lru_cache(maxsize=64)
def _make_spec(model, rheology, compliant, cells, contact_offset, force_offset,
               force_drift=False) -> ModelSpec:
    if model not in ("relaxed", "history"):
        raise ValueError(f"model must be 'relaxed' or 'history'; got {model!r}")
    name, colon, arg = rheology.partition(":") if isinstance(rheology, str) else ("", "", "")
    kind = RHEOLOGIES.get(name)
    if kind is None or (kind.arms is None and colon):
        allowed = ", ".join(f"'{n}'" if k.arms is None else
                            f"'{n}:N' (N in [{k.arms[0]}, {k.arms[1]}])"
                            for n, k in RHEOLOGIES.items())
        raise ValueError(f"rheology must be {allowed} or 'auto'; got {rheology!r}")
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
    if force_drift and model != "history":
        # the relaxed model fits the retract alone, in contact from its deepest sample: a
        # line and the relaxation trade off there (benchmarks/results/force_drift_relaxed.md)
        raise ValueError("force_drift needs model='history' (its fitted data include the "
                         "free approach, which carries a drift; the relaxed model's retract "
                         "cannot tell a line from the relaxation)")
    if int(cells) < 2:
        raise ValueError(f"cells must be an integer >= 2; got {cells!r}")
    return ModelSpec(model=model, rheology=name, arms=arms, compliant=bool(compliant),
                     cells=int(cells), contact_offset=bool(contact_offset),
                     force_offset=bool(force_offset) or bool(force_drift),
                     force_drift=bool(force_drift))


def rheology_kind(spec: ModelSpec) -> RheologyKind:
    """The entry of :data:`RHEOLOGIES` of `spec`'s rheology."""
    return RHEOLOGIES[spec.rheology]


def rheology_name(spec: ModelSpec) -> str:
    """The rheology's name as given: "standard", "elastic" or "prony:N"."""
    return spec.rheology if RHEOLOGIES[spec.rheology].arms is None else \
        f"{spec.rheology}:{spec.arms}"


def n_material(spec: ModelSpec) -> int:
    """Number of rheology parameters (the work of adhesion follows them)."""
    return len(RHEOLOGIES[spec.rheology].parameters(spec.arms))


def n_model_inputs(spec: ModelSpec) -> int:
    """Number of leading parameters that are inputs of the forward model (the rheology's,
    the work of adhesion, the contact offset when fitted); the force baseline's (offset,
    drift) follow them."""
    return n_material(spec) + 1 + int(spec.contact_offset)


def parameter_info(spec: ModelSpec) -> list[tuple[str, str, str]]:
    """(short name, unit, kind) of every parameter, in vector order.

    Kinds: "modulus", "viscosity", "time", "adhesion" (all positive, fitted in logs),
    "offset_length", "offset_force", "offset_force_rate" (any sign, fitted linearly).
    """
    return list(_parameter_info(spec))


@once_per_object  # (a spec's fields read once: per curve of a map, twice)
def _parameter_info(spec: ModelSpec) -> tuple:
    out = list(RHEOLOGIES[spec.rheology].parameters(spec.arms))
    out.append(_info("work_of_adhesion"))
    if spec.contact_offset:
        out.append(_info("contact_offset"))
    if spec.force_offset:
        out.append(_info("force_offset"))
    if spec.force_drift:
        out.append(_info("force_drift"))
    return tuple(out)


def stress_scaled(spec: ModelSpec) -> tuple[int, ...]:
    r"""Vector indices of the parameters that carry the stress scale (moduli, viscosities,
    $\Delta\gamma$: :data:`jaxcontact._vocabulary.STRESS_KINDS`), in which the model force
    is homogeneous of degree one,
    $$F(\lambda p_H;\,p_{\bar H}) = \lambda F(p_H;\,p_{\bar H}),\qquad
    \sum_{i\in H} p_i\,\frac{\partial F}{\partial p_i} = F$$
    (Euler), for both models under displacement control; empty under compliant loading
    (the cantilever's fixed stiffness is a stress scale of its own). The force offset and
    drift are not among them: they are added to the model force, not inputs of it."""
    if spec.compliant:
        return ()
    return tuple(i for i, (_, _, kind) in enumerate(parameter_info(spec)[:n_model_inputs(spec)])
                 if kind in STRESS_KINDS)


def build_rheology(spec: ModelSpec, p: Float[Array, " p"]):
    """The rheology for natural parameters `p` (vector order of :func:`parameter_info`)."""
    return RHEOLOGIES[spec.rheology].build(p, spec.arms)


def work_of_adhesion(spec: ModelSpec, p: Float[Array, " p"]):
    """The work of adhesion $\\Delta\\gamma$ [J/m²] of natural parameters `p`."""
    return p[n_material(spec)]


def offsets(spec: ModelSpec, p: Float[Array, " p"]):
    """`(contact_offset, force_offset)` of natural parameters `p` (0 when not fitted)."""
    k = n_material(spec) + 1
    delta = p[k] if spec.contact_offset else jnp.zeros((), p.dtype)
    f0 = p[n_model_inputs(spec)] if spec.force_offset else jnp.zeros((), p.dtype)
    return delta, f0


def force_baseline(spec: ModelSpec, p: Float[Array, " p"], ts):
    r"""The fitted force baseline [N] added to the model force at the times `ts` [s] (the
    batch's, from each curve's first fitted sample): $F_0 + s\,t$, with the force offset
    $F_0$ and the drift $s$ [N/s] of natural parameters `p` (0 when not fitted); the one
    place where the fits add them."""
    _, f0 = offsets(spec, p)
    if not spec.force_drift:
        return f0
    return f0 + p[n_model_inputs(spec) + int(spec.force_offset)] * ts


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
