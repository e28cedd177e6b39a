"""Units of measured columns: :func:`unit_factor` and :func:`parse_units` (SI inside)."""

from __future__ import annotations

from collections.abc import Mapping

__all__ = ["unit_factor", "parse_units"]

BASE_UNITS: dict[str, tuple[str, float]] = {
    # time
    "s": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6),
    "\u00b5s": ("time", 1e-6), "\u03bcs": ("time", 1e-6), "ns": ("time", 1e-9),
    "min": ("time", 60.0),
    # length
    "m": ("length", 1.0), "mm": ("length", 1e-3), "um": ("length", 1e-6),
    "\u00b5m": ("length", 1e-6), "\u03bcm": ("length", 1e-6), "nm": ("length", 1e-9),
    "pm": ("length", 1e-12),
    # force
    "N": ("force", 1.0), "mN": ("force", 1e-3), "uN": ("force", 1e-6),
    "\u00b5N": ("force", 1e-6), "\u03bcN": ("force", 1e-6), "nN": ("force", 1e-9),
    "pN": ("force", 1e-12),
}


def unit_factor(unit: str) -> tuple[str, float]:
    """``(dimension, factor to SI)`` of a unit string.

    Known: s, ms, us/µs, ns, min; m, mm, um/µm, nm, pm; N, mN, uN/µN, nN, pN; and
    quotients of them such as ``µm/s`` (dimension ``"length/time"``) or ``N/m``.
    Units are case-sensitive. Raises `ValueError` for an unknown unit.
    """
    u = unit.strip()
    if u in BASE_UNITS:
        return BASE_UNITS[u]
    if u.count("/") == 1:
        num, den = (p.strip() for p in u.split("/"))
        if num in BASE_UNITS and den in BASE_UNITS:
            dn, fn = BASE_UNITS[num]
            dd, fd = BASE_UNITS[den]
            return f"{dn}/{dd}", fn / fd
    raise ValueError(
        f"unknown unit {unit!r}; known units: {', '.join(BASE_UNITS)} and quotients "
        "such as 'um/s'"
    )


ROLE_DIMENSION = {"time": "time", "displacement": "length", "height": "length",
                   "force": "force"}
def parse_units(spec: str | Mapping[str, str] | None) -> dict[str, str]:
    """Unit choices per column role, e.g. ``"displacement=nm,force=nN"`` → dict.

    Roles: time, displacement, height, force. Accepts a mapping (returned as a checked
    dict) or ``None`` (empty dict). Raises `ValueError` for an unknown role, an unknown
    unit, or a unit of the wrong dimension.
    """
    if spec is None:
        return {}
    if isinstance(spec, str):
        out: dict[str, str] = {}
        for part in spec.split(","):
            part = part.strip()
            if not part:
                continue
            if "=" not in part:
                raise ValueError(
                    f"units: cannot read {part!r}; write role=unit pairs such as "
                    "'displacement=nm,force=nN'"
                )
            role, unit = (p.strip() for p in part.split("=", 1))
            out[role] = unit
        spec = out
    checked: dict[str, str] = {}
    for role, unit in spec.items():
        if role not in ROLE_DIMENSION:
            raise ValueError(
                f"units: unknown column role {role!r}; use one of {tuple(ROLE_DIMENSION)}"
            )
        dim, _ = unit_factor(unit)
        if dim != ROLE_DIMENSION[role]:
            raise ValueError(
                f"units: {role} needs a {ROLE_DIMENSION[role]} unit, got {unit!r} ({dim})"
            )
        checked[role] = unit
    return checked
