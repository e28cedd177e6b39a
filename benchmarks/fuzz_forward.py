"""Fuzzing of the forward model: what was tried and what it gives.

The long version of `tests/test_validation.py` and `tests/test_properties.py`: random valid
parameter sets (invariants in float64 and float32, float32 against float64, finite
gradients and gradients against finite differences), bad values in one lane of a vmapped
batch (the lane's error code, the other lanes unchanged), `throw=True` under `jit` reading
one field, eager errors, every combination of float32/float64 inputs, the float32 false
`advancing_contact` rate, recompilation with Python floats.

    python benchmarks/fuzz_forward.py [--sets 4000] [--seed 0] [--out docs/reliability-forward.md]

Prints the table and writes it, with the machine and the date, to `--out`.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import subprocess
import time

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxcontact as jc

R = jc.RESULTS
ROWS: list[tuple[str, str, str, str]] = []


def row(area, tried, n, outcome):
    ROWS.append((area, tried, str(n), outcome))
    print(f"| {area} | {tried} | {n} | {outcome} |", flush=True)


def ok_codes(codes):
    codes = np.asarray(codes)
    return (codes == R.detached._value) | (codes == R.in_contact._value)


def code_name(item):
    return next(k for k, v in R._name_to_item.items() if v._value == item._value)


# --------------------------------------------------------------------------------------
# random valid parameter sets
# --------------------------------------------------------------------------------------


def retract_params(n, rng):
    """G0 1e2-1e7 Pa, G1/G0 0.03-3, tau 1e-3-3 (units of the duration), dgamma 3e-4-0.3
    J/m^2, R 1 um-1 mm, depth/R 1e-3-0.1, lift 0.5-100 depths over the duration (1 s)."""
    G0 = 10 ** rng.uniform(2, 7, n)
    G1 = G0 * 10 ** rng.uniform(-1.5, 0.5, n)
    eta1 = 10 ** rng.uniform(-3, 0.5, n) * (G0 + G1)
    dg = 10 ** rng.uniform(-3.5, -0.5, n)
    rad = 10 ** rng.uniform(-6, -3, n)
    depth = rad * 10 ** rng.uniform(-3, -1, n)
    v = depth * 10 ** rng.uniform(-0.3, 2, n)
    return [G0, G1, eta1, dg, rad, depth, v]


def retract_lane(g0, g1, eta1, dg, rad, depth, v, ts):
    return jc.retract(jc.StandardModel(g0, g1, eta1), jc.Parabola(rad), dg, ts, depth=depth,
                      velocity=v, throw=False)


def retract_fn(ts):
    def lane(*p):
        s = retract_lane(*p, ts)
        return (s.force, s.contact_radius, s.max_tensile_force, s.jumpoff_time,
                s.jumpoff_force, s.result._value)

    return jax.jit(jax.vmap(lane))


def batched(fn, params, dtype, batch=500):
    outs = []
    n = len(params[0])
    for i in range(0, n, batch):
        args = [jnp.asarray(p[i:i + batch], dtype) for p in params]
        outs.append([np.asarray(x) for x in fn(*args)])
    return [np.concatenate([o[k] for o in outs]) for k in range(len(outs[0]))]


def invariants(F, a, fmax, tj, codes, ts, tol):
    """Counts of violations: error code, non-finite, force/radius after jump-off, largest
    tensile force above a sample or positive after a jump-off."""
    bad_code = ~ok_codes(codes)
    nonfinite = ~(np.all(np.isfinite(F), 1) & np.all(np.isfinite(a), 1) & np.isfinite(fmax))
    det = np.isfinite(tj)
    after = ts[None, :] > np.where(det, tj, np.inf)[:, None]
    nonzero_after = np.any(after & ((F != 0) | (a != 0)), 1)
    scale = np.max(np.abs(F), 1)
    above = fmax > np.min(F, 1) + tol * scale
    positive = det & (fmax > 0)
    return dict(code=int(bad_code.sum()), nonfinite=int(nonfinite.sum()),
                after=int(nonzero_after.sum()), above=int(above.sum()),
                positive=int(positive.sum()), detached=int(det.sum()))


def fuzz_retract(n, rng):
    ts64 = np.linspace(0.0, 1.0, 400)
    params = retract_params(n, rng)
    out = {}
    for dtype, name in ((jnp.float64, "float64"), (jnp.float32, "float32")):
        ts = jnp.asarray(ts64, dtype)
        F, a, fmax, tj, fj, codes = batched(retract_fn(ts), params, dtype)
        inv = invariants(F, a, fmax, tj, codes, ts64, 1e-12 if name == "float64" else 1e-5)
        out[name] = (F, fmax, tj, fj)
        row("retract, valid sets", f"{name}: {inv['detached']} of {n} detach", n,
            f"error codes {inv['code']}, non-finite {inv['nonfinite']}, force or radius != 0 "
            f"after jump-off {inv['after']}, max tension above a sample {inv['above']}, "
            f"max tension > 0 after jump-off {inv['positive']}")
    F64, fmax64, tj64, fj64 = out["float64"]
    F32, fmax32, tj32, fj32 = out["float32"]
    scale = np.max(np.abs(F64), 1, keepdims=True)
    near = np.abs(ts64[None, :] - tj64[:, None]) < 1e-5
    err = np.abs(F32.astype(float) - F64) / scale
    det = np.isfinite(tj64) & np.isfinite(tj32)
    rel = lambda x, y: np.abs(x[det] / y[det] - 1)  # noqa: E731
    row("retract, float32 vs float64", "force relative to each curve's peak, away from "
        "the jump-off (1e-5 of the duration)", n,
        f"median {np.median(err[~near]):.1e}, 99th pct {np.percentile(err[~near], 99):.1e}, "
        f"max {err[~near].max():.1e}")
    row("retract, float32 vs float64", "jump-off time / jump-off force / max tension, "
        "relative", int(det.sum()),
        f"max {rel(tj32, tj64).max():.1e} / {rel(fj32, fj64).max():.1e} / "
        f"{rel(fmax32, fmax64).max():.1e}")
    return params


def fuzz_gradients(params, n, rng):
    ts = jnp.linspace(0.0, 1.0, 400)

    def events(q, rad, depth, v):
        s = retract_lane(q[0], q[1], q[2], q[3], rad, depth, v, ts)
        return jnp.stack([s.jumpoff_time, s.jumpoff_force, s.max_tensile_force])

    jac = jax.jit(jax.vmap(jax.jacfwd(events)))
    sel = [p[:n] for p in params]
    q = jnp.asarray(np.stack(sel[:4], 1))
    J = np.asarray(jac(q, *[jnp.asarray(p) for p in sel[4:]]))
    f = jax.jit(jax.vmap(events))
    E = np.asarray(f(q, *[jnp.asarray(p) for p in sel[4:]]))
    det = np.isfinite(E[:, 0])
    row("retract, gradients", "jacfwd of jump-off time, force, max tension w.r.t. G0, G1, "
        "eta1, dgamma (float64)", int(det.sum()),
        f"non-finite entries {int((~np.isfinite(J[det])).sum())} of {J[det].size}")
    # central differences on a subset, relative step 1e-6
    k_fd = min(40, int(det.sum()))
    idx = np.flatnonzero(det)[:k_fd]
    worst = 0.0
    for k in range(4):
        h = 1e-6 * np.asarray(q[idx, k])
        plus = np.asarray(f(q[idx].at[:, k].add(h), *[jnp.asarray(p[idx]) for p in sel[4:]]))
        minus = np.asarray(f(q[idx].at[:, k].add(-h), *[jnp.asarray(p[idx]) for p in sel[4:]]))
        fd = (plus - minus) / (2 * h[:, None])
        scale = np.abs(fd) + 1e-9 * np.abs(E[idx]) / np.asarray(q[idx, k])[:, None]
        worst = max(worst, float(np.max(np.abs(J[idx, :, k] - fd) / scale)))
    row("retract, gradients", "jacfwd against central differences (relative step 1e-6)",
        k_fd * 4, f"largest relative difference {worst:.1e}")


def fuzz_tie():
    # a pinned jump-off exactly on a sample (the case)
    G0, G1, eta1, rad, dg, d0, v = 1e6, 2e5, 1e4, 1e-4, 0.05, 2e-8, 1e-5

    def mt(p, ts):
        s = jc.retract(jc.StandardModel(p[0], p[1], eta1), jc.Parabola(rad), p[2], ts,
                       depth=d0, velocity=v)
        return s.max_tensile_force

    tj = float(jc.retract(jc.StandardModel(G0, G1, eta1), jc.Parabola(rad), dg,
                          jnp.linspace(0, 2, 52), depth=d0, velocity=v).jumpoff_time)
    ts = jnp.concatenate([jnp.linspace(0.0, tj, 51), jnp.array([1.2 * tj])])
    p = jnp.array([G0, G1, dg])
    g = np.asarray(jax.grad(mt)(p, ts))
    fd = np.array([(mt(p.at[k].add(1e-6 * p[k]), ts) - mt(p.at[k].add(-1e-6 * p[k]), ts))
                   / (2e-6 * float(p[k])) for k in range(3)])
    row("retract, gradients", "grad of max tension, pinned jump-off exactly on a sample "
        "(d/dG0, d/dG1, d/ddgamma)", 3,
        f"relative difference to central differences {np.max(np.abs(g / fd - 1)):.1e}")


def fuzz_diffrax_forward():
    ts = jnp.linspace(0.0, 0.06, 25)

    def events(p, method):
        s = jc.retract(jc.StandardModel(p[0], p[1], p[2]), jc.Parabola(1e-4), p[3], ts,
                       depth=4e-6, velocity=1e-4, method=method)
        return jnp.stack([s.jumpoff_time, s.jumpoff_force])

    p = jnp.array([1e6, 2e5, 1e4, 0.05])
    m = jc.DiffraxODE()
    rev = np.asarray(jax.jacrev(lambda q: events(q, m))(p))
    fwd_m = eqx.tree_at(lambda x: x.adjoint, m, diffrax.ForwardMode())
    fwd = np.asarray(jax.jacfwd(lambda q: events(q, fwd_m))(p))
    try:
        jax.jacfwd(lambda q: events(q, m))(p)
        default = "works"
    except TypeError:
        default = "TypeError (custom_vjp): pass adjoint=diffrax.ForwardMode()"
    row("retract, gradients", "jacfwd through DiffraxODE(adjoint=ForwardMode()) vs jacrev "
        "through the default adjoint", 8,
        f"largest difference relative to each output's largest derivative "
        f"{np.max(np.abs(fwd - rev) / np.max(np.abs(rev), axis=1, keepdims=True)):.1e}; "
        f"jacfwd with the default adjoint: {default}")


# --------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------


def fuzz_simulate(n, rng):
    ts64 = np.linspace(0.0, 1.0, 200)
    rad, depth = 1e-4, 2e-6
    d64 = np.interp(ts64, [0.0, 0.25, 0.5, 1.0], [0.0, depth, depth, -3 * depth])
    G0 = 10 ** rng.uniform(2, 7, n)
    G1 = G0 * 10 ** rng.uniform(-1.5, 0.5, n)
    eta1 = 10 ** rng.uniform(-2, 0.5, n) * (G0 + G1)
    dg = 10 ** rng.uniform(-3.5, -0.5, n)
    res = {}
    for dtype, name in ((jnp.float64, "float64"), (jnp.float32, "float32")):
        ts, d = jnp.asarray(ts64, dtype), jnp.asarray(d64, dtype)

        def lane(g0, g1, e1, w, ts=ts, d=d, dtype=dtype):
            s = jc.simulate(jc.StandardModel(g0, g1, e1), jc.Parabola(jnp.asarray(rad, dtype)),
                            w, ts, d, grid=16, throw=False)
            return (s.force, s.contact_radius, s.max_tensile_force, s.jumpoff_time,
                    s.jumpoff_force, s.result._value)

        F, a, fmax, tj, fj, codes = batched(jax.jit(jax.vmap(lane)), [G0, G1, eta1, dg],
                                            dtype, batch=100)
        inv = invariants(F, a, fmax, tj, codes, ts64, 1e-12 if name == "float64" else 1e-5)
        res[name] = (F, tj)
        row("simulate, valid sets", f"{name}, approach-hold-lift, 200 samples, 16 cells: "
            f"{inv['detached']} of {n} detach", n,
            f"error codes {inv['code']}, non-finite {inv['nonfinite']}, force or radius != 0 "
            f"after jump-off {inv['after']}, max tension above a sample {inv['above']}, "
            f"max tension > 0 after jump-off {inv['positive']}")
    F64, tj64 = res["float64"]
    F32, _ = res["float32"]
    scale = np.max(np.abs(F64), 1, keepdims=True)
    near = np.abs(ts64[None, :] - tj64[:, None]) < 2 * (ts64[1] - ts64[0])
    err = np.abs(F32.astype(float) - F64) / scale
    row("simulate, float32 vs float64", "force relative to each curve's peak, two samples "
        "away from the jump-off", n,
        f"median {np.median(err[~near]):.1e}, 99th pct {np.percentile(err[~near], 99):.1e}, "
        f"max {err[~near].max():.1e}")


# --------------------------------------------------------------------------------------
# invalid and implausible inputs
# --------------------------------------------------------------------------------------

BAD = [
    ("G0", 0, [-1e6, 0.0, np.nan, np.inf, -np.inf], R.invalid_rheology),
    ("G1", 1, [-1.0, 0.0, np.nan, np.inf], R.invalid_rheology),
    ("eta1", 2, [-1e4, 0.0, np.nan, np.inf], R.invalid_rheology),
    ("work_of_adhesion", 3, [-0.05, 0.0, np.nan, np.inf], R.invalid_work_of_adhesion),
    ("R", 4, [-1e-4, 0.0, np.nan, np.inf], R.invalid_profile),
    ("depth", 5, [-1e-6, 0.0, np.nan, np.inf], R.invalid_depth),
    ("velocity", 6, [-1e-4, 0.0, np.nan, np.inf], R.invalid_velocity),
    ("depth (nm as m)", 5, [4000.0, 10.0], R.implausible_input),
    ("R (tiny)", 4, [1e-300, 1e-20], R.implausible_input),
    ("G0 (huge)", 0, [1e20, 1e30], R.implausible_input),
    ("work_of_adhesion (mJ as J)", 3, [50.0, 1e3], R.implausible_input),
    ("velocity (huge)", 6, [1e5], R.implausible_input),
]


def fuzz_bad_lanes(rng, repeats=4):
    ts = jnp.linspace(0.0, 1.0, 100)
    fn = retract_fn(ts)
    for name, k, values, item in BAD:
        tried = right = others = nan_ok = 0
        for value in values:
            for _ in range(repeats):
                params = retract_params(16, rng)
                good = [np.asarray(x) for x in fn(*[jnp.asarray(p) for p in params])]
                lane = int(rng.integers(16))
                params[k] = params[k].copy()
                params[k][lane] = value
                out = [np.asarray(x) for x in fn(*[jnp.asarray(p) for p in params])]
                tried += 1
                right += int(out[5][lane] == item._value)
                keep = np.arange(16) != lane
                others += int(np.array_equal(out[0][keep], good[0][keep])
                              and np.array_equal(out[5][keep], good[5][keep]))
                nan_ok += int(np.all(np.isnan(out[0][lane])) and np.isnan(out[2][lane]))
        row("retract, one bad lane in a vmap of 16 (throw=False)",
            f"{name} in {values}", tried,
            f"code `{code_name(item)}` {right}/{tried}; other lanes unchanged {others}/{tried}; "
            f"that lane NaN {nan_ok}/{tried}")


def fuzz_throw():
    ts = jnp.linspace(0.0, 0.1, 100)
    base = dict(g0=1e6, g1=2e5, eta1=1e4, dg=0.05, rad=1e-4, depth=4e-6, v=1e-4)
    cases = [("work_of_adhesion = 0", "dg", 0.0), ("G0 = -1e6", "g0", -1e6),
             ("velocity = nan", "v", np.nan), ("depth = 4000 (nm as m)", "depth", 4000.0),
             ("eta1 = -1e4", "eta1", -1e4)]
    fields = ("force", "max_tensile_force", "jumpoff_time", "jumpoff_force")
    raised = 0
    total = 0
    for _, key, value in cases:
        for field in fields:
            def f(x, key=key, field=field):
                p = dict(base)
                p[key] = x
                s = jc.retract(jc.StandardModel(p["g0"], p["g1"], p["eta1"]),
                               jc.Parabola(p["rad"]), p["dg"], ts, depth=p["depth"],
                               velocity=p["v"])
                return getattr(s, field)

            total += 1
            try:
                jax.block_until_ready(eqx.filter_jit(f)(jnp.asarray(value)))
            except Exception:  # noqa: BLE001 - any runtime error counts as raised
                raised += 1
    row("retract under jit, throw=True, one field read", f"{len(cases)} bad inputs x "
        f"fields {', '.join(fields)}", total, f"raised {raised}/{total}")


def fuzz_eager():
    ts = jnp.linspace(0.0, 0.1, 100)
    rh, prof = jc.StandardModel(1e6, 2e5, 1e4), jc.Parabola(1e-4)
    cases = [
        ("work_of_adhesion", dict(work_of_adhesion=-1.0)),
        ("work_of_adhesion", dict(work_of_adhesion=0.0)),
        ("depth", dict(depth=0.0)), ("depth", dict(depth=np.nan)),
        ("velocity", dict(velocity=np.nan)), ("velocity", dict(velocity=-1.0)),
        ("ts", dict(ts=ts[::-1])), ("ts", dict(ts=ts.at[3].set(np.nan))),
        ("depth", dict(depth=4000.0)), ("velocity", dict(velocity=1e6)),
    ]
    named = 0
    for name, kw in cases:
        args = dict(work_of_adhesion=0.05, ts=ts, depth=4e-6, velocity=1e-4)
        args.update(kw)
        try:
            jc.retract(rh, prof, **args)
        except ValueError as err:
            named += int(f"`{name}`" in str(err))
    ctor = [("G0", lambda: jc.StandardModel(-1.0, 1.0, 1.0)), ("R", lambda: jc.Parabola(np.nan)),
            ("n", lambda: jc.PowerLaw(1.0, 0.5)), ("half_angle", lambda: jc.Cone(2.0)),
            ("radius", lambda: jc.FlatPunch(0.0)), ("stiffness", lambda: jc.CompliantLoading(-1.0))]
    for name, c in ctor:
        try:
            c()
        except ValueError as err:
            named += int(f"`{name}`" in str(err))
    el = [("a", lambda: jc.jkr_force(prof, -1e-6, effective_modulus=4e6, work_of_adhesion=0.05)),
          ("displacement", lambda: jc.jkr_contact_radius(prof, np.nan, effective_modulus=4e6,
                                                          work_of_adhesion=0.05)),
          ("effective_modulus", lambda: jc.pull_off(prof, effective_modulus=-1.0,
                                                     work_of_adhesion=0.05))]
    for name, c in el:
        try:
            c()
        except ValueError as err:
            named += int(f"`{name}`" in str(err))
    n = len(cases) + len(ctor) + len(el)
    row("eager calls", "bad values of retract, the constructors and the elastic relations",
        n, f"ValueError naming the parameter {named}/{n}")


def fuzz_elastic_lanes():
    prof = jc.Parabola(1e-4)

    def po(E, dg):
        sol = jc.pull_off(prof, effective_modulus=E, work_of_adhesion=dg, throw=False)
        return sol.result._value

    E = jnp.array([4e6, -1.0, np.nan, 4e6, 4e6, 4e6, 1e20])
    dg = jnp.array([0.05, 0.05, 0.05, 0.0, np.nan, 1e3, 0.05])
    codes = np.asarray(jax.jit(jax.vmap(po))(E, dg))
    expect = [R.successful, R.invalid_modulus, R.invalid_modulus, R.invalid_work_of_adhesion,
              R.invalid_work_of_adhesion, R.implausible_input, R.implausible_input]
    right = sum(int(c == e._value) for c, e in zip(codes, expect, strict=True))
    row("pull_off under vmap (throw=False)", "E* < 0, NaN, 1e20; dgamma = 0, NaN, 1e3", 7,
        f"expected codes {right}/7")
    a = jnp.array([1e-6, -1e-6, np.nan, 2e-6])
    f = np.asarray(jax.jit(lambda a: jc.jkr_force(prof, a, effective_modulus=4e6,
                                                  work_of_adhesion=0.05, throw=False))(a))
    d = jnp.array([1e-7, np.nan])
    r = np.asarray(jax.jit(lambda d: jc.jkr_contact_radius(prof, d, effective_modulus=4e6,
                                                           work_of_adhesion=0.05,
                                                           throw=False))(d))
    row("jkr_force / jkr_contact_radius under jit (throw=False)",
        "a = -1e-6, NaN; displacement = NaN", 3,
        f"NaN where invalid {int(np.isnan(f[1]) and np.isnan(f[2]) and np.isnan(r[1]))}/1, "
        f"valid entries finite {int(np.isfinite(f[0]) and np.isfinite(f[3]) and r[0] > 0)}/1")


def fuzz_simulate_bad():
    ts = np.linspace(0.0, 0.06, 40)
    d = np.interp(ts, [0, 0.02, 0.03, 0.06], [0, 4e-6, 4e-6, -4e-6])

    def lane(g0, dg, t, u):
        return jc.simulate(jc.StandardModel(g0, 2e5, 1e4), jc.Parabola(1e-4), dg, t, u, grid=8,
                           throw=False).result._value

    rows = [(1e6, 0.05, ts, d, R.detached), (-1e6, 0.05, ts, d, R.invalid_rheology),
            (np.nan, 0.05, ts, d, R.invalid_rheology),
            (1e6, 0.0, ts, d, R.invalid_work_of_adhesion),
            (1e6, -1.0, ts, d, R.invalid_work_of_adhesion),
            (1e6, 0.05, ts[::-1], d, R.invalid_times),
            (1e6, 0.05, np.where(np.arange(40) == 7, np.nan, ts), d, R.invalid_times),
            (1e6, 0.05, ts, np.where(np.arange(40) == 3, np.nan, d), R.invalid_displacement),
            (1e6, 0.05, ts, d * 1e9, R.implausible_input)]
    cols = [jnp.asarray(np.stack([r[k] for r in rows])) for k in range(4)]
    codes = np.asarray(jax.jit(jax.vmap(lane))(*cols))
    right = sum(int(c == r[4]._value) for c, r in zip(codes, rows, strict=True))
    row("simulate under vmap (throw=False)", "G0 < 0, NaN; dgamma = 0, < 0; ts decreasing, "
        "NaN; displacement NaN; displacement in nm as m", len(rows),
        f"expected codes {right}/{len(rows)}")


# --------------------------------------------------------------------------------------
# precision and compilation
# --------------------------------------------------------------------------------------


def fuzz_precision():
    ts64 = np.linspace(0.0, 0.1, 100)
    names = ("rheology", "profile", "work_of_adhesion", "depth", "velocity", "ts")
    crashes = wrong = 0
    combos = 0
    for mask in range(2 ** len(names)):
        dts = [jnp.float32 if mask >> i & 1 else jnp.float64 for i in range(len(names))]
        expect = jnp.float32 if mask == 2 ** len(names) - 1 else jnp.float64
        combos += 1
        try:
            s = jc.retract(
                jc.StandardModel(*(jnp.asarray(x, dts[0]) for x in (1e6, 2e5, 1e4))),
                jc.Parabola(jnp.asarray(1e-4, dts[1])), jnp.asarray(0.05, dts[2]),
                jnp.asarray(ts64, dts[5]), depth=jnp.asarray(4e-6, dts[3]),
                velocity=jnp.asarray(1e-4, dts[4]), throw=False)
            wrong += int(s.force.dtype != expect or not bool(s.ok))
        except Exception:  # noqa: BLE001 - counted
            crashes += 1
    row("retract, precision", "every combination of float32/float64 for rheology, profile, "
        "dgamma, depth, velocity, ts", combos,
        f"crashes {crashes}; result not float32 iff all float32, or an error: {wrong}")
    # sampled histories: float32 displacement with float64 ts, and the reverse
    bad = 0
    for dt_ts, dt_d in ((jnp.float64, jnp.float32), (jnp.float32, jnp.float64)):
        try:
            s = jc.retract(jc.StandardModel(1e6, 2e5, 1e4), jc.Parabola(1e-4), 0.05,
                           jnp.asarray(ts64, dt_ts), jnp.asarray(4e-6 - 1e-4 * ts64, dt_d))
            bad += int(s.force.dtype != jnp.float64)
        except Exception:  # noqa: BLE001 - counted
            bad += 1
    row("retract, precision", "sampled history: float32 displacement with float64 ts and "
        "the reverse", 2, f"crash or not float64: {bad}")


def fuzz_advancing(rng, n):
    f32 = jnp.float32
    ts = jnp.linspace(0.0, 0.1, 200, dtype=f32)

    def code(d):
        return jc.retract(jc.StandardModel(f32(1e6), f32(2e5), f32(1e4)), jc.Parabola(f32(1e-4)),
                          f32(0.05), ts, depth=d, velocity=f32(1e-4), throw=False).result._value

    depths = np.concatenate([[7.960262559627985e-06], 10 ** rng.uniform(-7, -5, n - 1)])
    codes = np.asarray(jax.jit(jax.vmap(code))(jnp.asarray(depths, f32)))
    adv = int(np.sum(codes == R.advancing_contact._value))
    row("retract, float32, README tour parameters", "random depths 1e-7-1e-5 m (and the "
        "issue's 7.960262559627985e-06)", n, f"false `advancing_contact` {adv}; other errors "
        f"{int(np.sum(~ok_codes(codes)) - adv)}")


def fuzz_recompile():
    from jaxcontact._pulloff import _retract

    ts = jnp.linspace(0.0, 0.1, 100)
    jc.retract(jc.StandardModel(1e6, 2e5, 1e4), jc.Parabola(1e-4), 0.05, ts, depth=4e-6,
               velocity=1e-4)
    size = _retract._cached._cache_size()
    rng = np.random.default_rng(3)
    t0 = time.perf_counter()
    for _ in range(20):
        g0, rad = float(10 ** rng.uniform(5, 7)), float(10 ** rng.uniform(-5, -3))
        jc.retract(jc.StandardModel(g0, 2e5, 1e4), jc.Parabola(rad), float(rng.uniform(0.01, 0.1)),
                   ts, depth=float(rad * 0.01), velocity=float(10 ** rng.uniform(-5, -3)))
    dt = (time.perf_counter() - t0) / 20
    row("retract, Python floats", "20 eager calls with new Python-float G0, R, dgamma, depth, "
        "velocity", 20, f"new compilations {_retract._cached._cache_size() - size}; "
        f"{dt * 1e3:.1f} ms per call")


def machine() -> str:
    try:
        model = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        name = next((line.split(":", 1)[1].strip() for line in model.splitlines()
                     if line.startswith("Model name")), platform.processor())
    except OSError:
        name = platform.processor()
    return f"{name}, {os.cpu_count()} cores (nproc), jax {jax.__version__}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=4000, help="random retract sets per precision")
    ap.add_argument("--simulate-sets", type=int, default=200)
    ap.add_argument("--gradient-sets", type=int, default=500)
    ap.add_argument("--depths", type=int, default=2000, help="float32 advancing check")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), os.pardir, "docs",
                                                  "reliability-forward.md"))
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    print("| area | what was tried | count | what it gives |\n| --- | --- | --- | --- |")
    params = fuzz_retract(args.sets, rng)
    fuzz_gradients(params, args.gradient_sets, rng)
    fuzz_tie()
    fuzz_diffrax_forward()
    fuzz_simulate(args.simulate_sets, rng)
    fuzz_bad_lanes(rng)
    fuzz_throw()
    fuzz_eager()
    fuzz_elastic_lanes()
    fuzz_simulate_bad()
    fuzz_precision()
    fuzz_advancing(rng, args.depths)
    fuzz_recompile()
    elapsed = time.perf_counter() - t0
    header = (
        "# Reliability of the forward model: what was tried and what it gives\n\n"
        "Produced by `python benchmarks/fuzz_forward.py "
        f"--sets {args.sets} --simulate-sets {args.simulate_sets} --gradient-sets "
        f"{args.gradient_sets} --depths {args.depths} --seed {args.seed}` on "
        f"{datetime.date.today().isoformat()}, {machine()}, in {elapsed / 60:.1f} min. "
        "The test suite runs a small, fixed version of the same checks "
        "(`tests/test_validation.py`, `tests/test_properties.py`).\n\n"
        "Ranges of the random valid sets: G0 1e2-1e7 Pa, G1/G0 0.03-3, relaxation time "
        "1e-3-3 of the duration, work of adhesion 3e-4-0.3 J/m², sphere radius 1 µm-1 mm, "
        "depth 1e-3-0.1 of the radius, lift of 0.5-100 depths over the duration (log-uniform); "
        "simulate: approach-hold-lift to -3 depths with the same material ranges.\n\n"
        "Errors are reported per lane in `.result` with `throw=False` (the lane's other "
        "fields are NaN) and raised with `throw=True` whichever field is read; the "
        "plausibility of units can be switched off with `jaxcontact.plausibility_checks(False)`."
        "\n\n| area | what was tried | count | what it gives |\n| --- | --- | --- | --- |\n"
    )
    table = "".join(f"| {a} | {b} | {c} | {d} |\n" for a, b, c, d in ROWS)
    with open(args.out, "w") as fh:
        fh.write(header + table)
    print(f"wrote {os.path.normpath(args.out)} ({elapsed / 60:.1f} min)")


if __name__ == "__main__":
    main()
