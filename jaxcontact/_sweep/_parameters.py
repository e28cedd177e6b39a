r"""The parameters a sweep may vary: names, units, validation, the objects they build and the
units in which a point is computed.

**Vocabulary** (SI units; every value a scalar (fixed) or a 1-D array (swept); names, units,
kinds and bounds from the registry `jaxcontact._vocabulary`, which the fits and the command
line share):

- material (one family): `G0`, `G1`, `eta1`, the standard model in creep form
  (`StandardModel`); or `G_inf` with arms `G_1`, `tau_1`, ..., `G_N`, `tau_N`, a Prony series
  (`PronySeries`; `G_inf` alone is an elastic solid);
- indenter (one): `R`, paraboloid (`Parabola`); `sphere_radius`, the exact sphere
  (`Sphere`, contact radii up to 0.95 of it: a deeper point is flagged); `half_angle`
  [rad], cone (`Cone`; a pyramid as its equivalent cone: `pyramid_cone_angle`);
  `punch_radius`, flat punch (`FlatPunch`);
- adhesion: `work_of_adhesion` $\Delta\gamma$;
- protocol: `depth` $d_0$, `velocity` $v$ (lift speed); with `ApproachHoldLift` also `hold`
  and `approach_velocity` (default: `velocity`, point by point).

**Units of the computation (nondimensionalisation).** Every point is computed in its own
units: lengths in $\ell = d_0$, moduli in the relaxed modulus $G_\infty$, times in
$t_\mathrm{ref} = d_0/v$ (so that the scaled depth and lift speed are both 1). Forces are then
in $G_\infty d_0^2$, works in $G_\infty d_0^3$. The scaling is done in float64 on the host
before the values are cast to the compute precision, and undone in float64 afterwards, so that
a float32 computation sees numbers of order one whatever the physical scales (nN and nm for an
AFM cell measurement or mN and mm for a gel): no underflow of e.g. $a^3$ or $\Delta\gamma$,
and the same relative resolution everywhere.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .._probes import Sphere
from .._profiles import Cone, FlatPunch, Parabola
from .._rheology import PronySeries, StandardModel
from .._validate import plain
from .._vocabulary import ARM_PATTERN, Parameter, parameter

__all__ = ["Parameter", "ParameterSpec", "parameter_info", "parse_spec", "INVALID_REASONS"]


#: The parameters a sweep may vary (their units, kinds and bounds: the registry,
#: `jaxcontact._vocabulary`), besides the Prony arms `G_k`, `tau_k`.
SWEEPABLE = ("G0", "G1", "eta1", "G_inf", "R", "sphere_radius", "half_angle", "punch_radius",
             "work_of_adhesion", "depth", "velocity", "hold", "approach_velocity")


def parameter_info(name: str) -> Parameter:
    """The `Parameter` of a sweep parameter name (`ValueError` for an unknown name)."""
    if name in SWEEPABLE or ARM_PATTERN.match(name):
        return parameter(name)
    known = ", ".join([*SWEEPABLE, "G_k", "tau_k"])
    raise ValueError(f"unknown sweep parameter {name!r}; known: {known}.")


def scale_factors(dimension: str, length, modulus, time):
    """The unit of a `dimension` in the scaled units of a point (float64 numpy arrays or
    scalars): only that one is computed (a sweep of 10^7 points spent 0.7 s building all seven
    for each parameter)."""
    if dimension == "length":
        return length
    if dimension == "modulus":
        return modulus
    if dimension == "time":
        return time
    if dimension == "viscosity":
        return modulus * time
    if dimension == "adhesion":
        return modulus * length
    if dimension == "velocity":
        return length / time
    if dimension == "angle":
        return 1.0
    raise ValueError(f"unknown dimension {dimension!r}.")


# --------------------------------------------------------------------------------------
# families: which objects the names build
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _StandardFamily:
    names: tuple = ("G0", "G1", "eta1")
    arms: int = 1

    def relaxed_modulus(self, v):
        return v["G0"] * v["G1"] / (v["G0"] + v["G1"])

    def build(self, p):
        return StandardModel(G0=p["G0"], G1=p["G1"], eta1=p["eta1"])


@dataclass(frozen=True)
class _PronyFamily:
    arms: int

    @property
    def names(self):
        arms = [(f"G_{k}", f"tau_{k}") for k in range(1, self.arms + 1)]
        return ("G_inf", *[n for pair in arms for n in pair])

    def relaxed_modulus(self, v):
        return v["G_inf"]

    def build(self, p):
        dtype = p["G_inf"].dtype
        if self.arms == 0:
            empty = jnp.zeros((0,), dtype)
            return PronySeries(G_inf=p["G_inf"], G=empty, tau=empty)
        G = jnp.stack([p[f"G_{k}"] for k in range(1, self.arms + 1)])
        tau = jnp.stack([p[f"tau_{k}"] for k in range(1, self.arms + 1)])
        return PronySeries(G_inf=p["G_inf"], G=G, tau=tau)


@dataclass(frozen=True)
class _ProfileFamily:
    name: str

    @property
    def names(self):
        return (self.name,)

    def build(self, p):
        value = p[self.name]
        if self.name == "R":
            return Parabola(R=value)
        if self.name == "sphere_radius":
            return Sphere(R=value)
        if self.name == "half_angle":
            return Cone(half_angle=value)
        return FlatPunch(radius=value)


def _material_family(names):
    standard = [n for n in _StandardFamily().names if n in names]
    prony = [n for n in names if n == "G_inf" or ARM_PATTERN.match(n)]
    if standard and prony:
        raise ValueError(
            f"sweep parameters mix two material families: {standard} (standard model) and "
            f"{prony} (Prony series); give one."
        )
    if standard:
        missing = [n for n in _StandardFamily().names if n not in names]
        if missing:
            raise ValueError(f"the standard model needs G0, G1 and eta1; missing {missing}.")
        return _StandardFamily()
    if not prony:
        raise ValueError(
            "give the material: G0, G1, eta1 (standard model) or G_inf [and G_k, tau_k] "
            "(Prony series)."
        )
    if "G_inf" not in names:
        raise ValueError("a Prony series needs G_inf (the relaxed modulus) [Pa].")
    ks = sorted({int(ARM_PATTERN.match(n).group(2)) for n in prony if n != "G_inf"})
    arms = len(ks)
    if ks != list(range(1, arms + 1)):
        raise ValueError(f"Prony arms must be numbered 1..N without gaps; got {ks}.")
    for k in ks:
        for n in (f"G_{k}", f"tau_{k}"):
            if n not in names:
                raise ValueError(f"Prony arm {k} needs both G_{k} [Pa] and tau_{k} [s]; "
                                 f"missing {n}.")
    return _PronyFamily(arms)


def _profile_family(names):
    given = [n for n in ("R", "sphere_radius", "half_angle", "punch_radius") if n in names]
    if len(given) != 1:
        raise ValueError(
            "give exactly one indenter parameter: R [m] (paraboloid), sphere_radius [m] (exact "
            "sphere), half_angle [rad] (cone) or punch_radius [m] (flat punch); got "
            f"{given or 'none'}."
        )
    return _ProfileFamily(given[0])


# --------------------------------------------------------------------------------------
# the specification of a sweep: a grid or a list of points
# --------------------------------------------------------------------------------------


@dataclass
class ParameterSpec:
    """A parsed sweep specification.

    - `dims`: the dimension names of the result (the swept parameters of a grid, in the
      order given; `("point",)` for a list of points).
    - `shape`: the shape of the result.
    - `coords`: name -> 1-D float64 array along its dimension (grid) or along `point`.
    - `fixed`: name -> float of the parameters that are not swept.
    - `values`: name -> float64 array of shape `(P,)`, every point's value (P = prod(shape)),
      or a float64 scalar for a fixed parameter.
    - `derived`: name -> (dimension, values) of a parameter that takes the value of a swept
      one by default (`approach_velocity` follows `velocity`).
    - `flags`: name -> int8 `INVALID_REASONS` codes along the parameter's coordinate, for the
      swept parameters with values outside their range (`on_error="status"` only).
    """

    dims: tuple
    shape: tuple
    coords: dict
    fixed: dict
    values: dict
    grid: bool
    material: object
    profile: object
    derived: dict
    flags: dict

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))


def _as_values(name, value):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"sweep parameter {name!r}: expected numbers; got {value!r}.") from None
    if arr.ndim > 1:
        raise ValueError(f"sweep parameter {name!r}: expected a scalar or a 1-D array; got "
                         f"shape {arr.shape}.")
    if arr.ndim == 1 and arr.size == 0:
        raise ValueError(f"sweep parameter {name!r}: empty array.")
    return arr


#: Why a point was refused (`sweep(..., on_error="status")`): code -> meaning.
INVALID_REASONS = {
    1: "not finite",
    2: "below its allowed range",
    3: "above its allowed range",
    4: "outside its plausible range (other units?)",
}


def range_text(name) -> str:
    """The allowed range of a parameter, e.g. `(0, inf) [Pa]`."""
    info = parameter_info(name)
    lo = "[0" if info.allow_zero else "(0"
    hi = f"{info.upper:g})" if info.upper is not None else "inf)"
    return f"{lo}, {hi} [{info.unit}]"


def range_flags(name, arr):
    """Per entry of `arr`: 0 inside the allowed range of `name`, else an `INVALID_REASONS`
    code (int8 array of `arr`'s shape)."""
    info = parameter_info(name)
    flags = np.zeros(arr.shape, np.int8)
    flags[(arr < 0) | ((arr == 0) & (not info.allow_zero))] = 2
    if info.upper is not None:
        flags[arr >= info.upper] = 3
    flags[~np.isfinite(arr)] = 1
    return flags


def _in_range(name, arr) -> bool:
    """Whether every entry lies in the allowed range: two reductions (min and max; NaN
    propagates through both), no temporaries."""
    if arr.size == 0:
        return True
    info = parameter_info(name)
    lo, hi = (float(arr), float(arr)) if arr.ndim == 0 else (arr.min(), arr.max())
    upper = info.upper if info.upper is not None else math.inf
    return bool((lo >= 0 if info.allow_zero else lo > 0) and hi < upper)


def _check_range(name, arr):
    if _in_range(name, arr):
        return
    flags = range_flags(name, np.atleast_1d(arr))
    i = int(np.flatnonzero(flags)[0])
    where = f" (entry {i})" if arr.ndim else ""
    raise ValueError(f"sweep parameter `{name}` must lie in {range_text(name)}; got "
                     f"{plain(np.ravel(arr)[i])}{where}.")


def parse_spec(grid, points, *, required, optional, on_error="raise") -> ParameterSpec:
    """Parse `grid=` / `points=` of `sweep` (see its docstring) into a `ParameterSpec`.

    With `on_error="status"` a swept value outside its allowed range is flagged in
    `spec.flags` instead of raising (a fixed one still raises: it would spoil every point)."""
    if (grid is None) == (points is None):
        raise ValueError("give exactly one of `grid` (a mapping) and `points` (parameter sets).")
    if points is not None and not isinstance(points, Mapping):
        if not isinstance(points, Sequence) or not points:
            raise ValueError("`points` must be a non-empty list of mappings or a mapping of "
                             "equal-length arrays.")
        keys = list(points[0])
        for i, pt in enumerate(points):
            if not isinstance(pt, Mapping) or set(pt) != set(keys):
                raise ValueError(f"`points[{i}]` must be a mapping with the names of points[0] "
                                 f"{keys}.")
        points = {k: [pt[k] for pt in points] for k in keys}
    spec = grid if grid is not None else points
    if not isinstance(spec, Mapping):
        raise ValueError("`grid` must be a mapping from parameter names to values.")
    raw, flags = {}, {}
    for name, value in spec.items():
        if not isinstance(name, str):
            raise ValueError(f"sweep parameter names must be strings; got {name!r}.")
        parameter_info(name)
        arr = _as_values(name, value)
        if on_error == "status" and arr.ndim == 1:
            if not _in_range(name, arr):
                flags[name] = range_flags(name, arr)
        else:
            _check_range(name, arr)
        raw[name] = arr
    names = set(raw)
    material = _material_family(names)
    profile = _profile_family(names)
    allowed = set(material.names) | set(profile.names) | set(required) | set(optional)
    extra = sorted(names - allowed)
    if extra:
        raise ValueError(f"sweep parameter(s) {extra} are not used by this model (it takes "
                         f"{sorted(set(required) | set(optional))} besides the material and "
                         "the indenter).")
    missing = [n for n in required if n not in names]
    if missing:
        raise ValueError(f"missing sweep parameter(s) {missing}.")
    follows = {}  # name -> the parameter whose value it takes at every point
    for name, default in optional.items():
        if name in raw or default is None:
            continue
        if isinstance(default, str):
            follows[name] = default
        else:
            raw[name] = np.asarray(default, dtype=np.float64)
    fixed = {n: float(a) for n, a in raw.items() if a.ndim == 0}
    swept = {n: a for n, a in raw.items() if a.ndim == 1}
    if grid is not None:
        dims = tuple(swept)
        shape = tuple(a.size for a in swept.values())
        mesh = np.meshgrid(*swept.values(), indexing="ij") if swept else []
        values = {n: m.ravel() for n, m in zip(swept, mesh, strict=True)}
        coords = dict(swept)
    else:
        sizes = {a.size for a in swept.values()}
        if len(sizes) > 1:
            lengths = {n: a.size for n, a in swept.items()}
            raise ValueError(f"`points`: the swept parameters must have equal lengths; got "
                             f"{lengths}.")
        count = sizes.pop() if sizes else 1
        dims, shape = ("point",), (count,)
        values = dict(swept)
        coords = dict(swept)
    for n, v in fixed.items():
        values[n] = np.float64(v)  # a scalar: broadcast, never expanded to `size` entries
    derived = {}
    for name, source in follows.items():
        values[name] = values[source]
        if source in fixed:
            fixed[name] = fixed[source]
        else:
            derived[name] = (source if grid is not None else "point", coords[source])
    return ParameterSpec(dims, shape, coords, fixed, values, grid is not None, material, profile,
                         derived, flags)
