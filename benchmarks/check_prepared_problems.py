"""Every leaf of the prepared problems (`fitting._optimise._problem`) of a set of cases,
written by one version of the code and compared with another's: the check that a change
of the preparation leaves every prepared problem the same to the bit.

    git archive main fitting jaxcontact | tar -x -C /tmp/prep_base   # the old code
    (cd /tmp/prep_base && PYTHONPATH=/tmp/prep_base \\
        python $REPO/benchmarks/check_prepared_problems.py dump /tmp/old.pkl)
    PYTHONPATH=$REPO python benchmarks/check_prepared_problems.py dump /tmp/new.pkl
    python benchmarks/check_prepared_problems.py compare /tmp/old.pkl /tmp/new.pkl

Cases: the 64 curves of `bench_fit_each.make_map(64, 60)` (relaxed), 16 of them with
``screen=256`` (the pool), 5 fitted jointly, prony:2 with and without nested starts (a
stand-in for the previous result), elastic, the options fixed/initial/bounds/force
offset/max_samples; 16 history-model curves of `make_history_map(16, 200)` (4 with the
screen); the real curves of `tests/data` and `benchmarks/data` (the 2x2 JPK force map, the
oocyte, Asylum, Chiaro, JPK creep, Bruker, JPK QI 2026, a held-out JPK curve, an Asylum
curve, the QI 2x2 without contact detection), each with the relaxed and the history model,
with the screen, with the contact point as detected and 300 samples, jointly, with an
indentation range, the approach alone; a sphere. Compared per problem: the spec, parameter
info and names, notes, the warnings issued (in order), the starts `zs`, the screened pool,
every field of the parameterisation and of the `CurveBatch` (type, dtype, shape, values,
signs of zeros), the tree structures, the selected curves; or the error's type and message.
"""

from __future__ import annotations

import pathlib
import pickle
import sys
import types
import warnings

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
DATA, HELD_OUT = HERE.parent / "tests" / "data", HERE / "data"


def _leaves(pb) -> dict:
    import jax

    out = {"spec": repr(pb.spec), "info": repr(pb.info), "names": repr(pb.names),
           "notes": repr(pb.notes), "zs": np.asarray(pb.zs),
           "pool": None if pb.pool is None else np.asarray(pb.pool)}
    for f in ("free", "log", "reference", "scale", "lower", "upper"):
        v = getattr(pb.param, f)
        out["param." + f] = v if isinstance(v, tuple) else (type(v).__name__, np.asarray(v))
    for f in ("ts", "drive", "indentation", "force", "valid", "weight", "lower", "upper",
              "segment", "index", "contact", "noise", "sigma", "depth", "detaches", "stiffness"):
        v = getattr(pb.data, f)
        out["data." + f] = (type(v).__name__, np.asarray(v).dtype.str, np.asarray(v))
    out["data.profile"] = repr(pb.data.profile)
    out["treedef.param"] = repr(jax.tree.structure(pb.param))
    out["treedef.data"] = repr(jax.tree.structure(pb.data))
    for i, c in enumerate(pb.curves):
        for f in ("time", "displacement", "force", "segment"):
            out[f"curve{i}.{f}"] = np.asarray(getattr(c, f))
        out[f"curve{i}.names"] = repr(c.segment_names)
    return out


def dump(path: str) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    from bench_fit_each import make_history_map, make_map

    import fitting
    import fitting._optimise as optimise
    import jaxcontact as jc
    from fitting import FitOptions
    from fitting._spec import make_spec

    print("fitting from", fitting.__file__, file=sys.stderr)

    def problem(curves, opts, rheology="standard", previous=None):
        cp = fitting._prepare.contact_point_mode(opts.contact_point, curves)
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            try:
                r = _leaves(optimise._problem(curves, opts, rheology=rheology,
                                              contact_point=cp, previous=previous))
            except Exception as exc:  # noqa: BLE001 - the error is a result to compare
                r = {"error": f"{type(exc).__name__}: {exc}"}
        r["warnings"] = [f"{x.category.__name__}: {x.message}" for x in w]
        return r

    cases = {}
    synth = make_map(64, 60)
    o = FitOptions(radius=12e-6, model="relaxed", progress=False)
    cases["synth64"] = [problem([c], o) for c in synth]
    cases["synth64_screen"] = [problem([c], o.replace(screen=256)) for c in synth[:16]]
    cases["synth_joint"] = [problem(synth[:5], o)]
    cases["synth_prony2"] = [problem([c], o.replace(rheology="prony:2"), "prony:2")
                             for c in synth[:4]]
    prev = types.SimpleNamespace(
        spec=make_spec("relaxed", "standard", contact_offset=False),
        as_dict=lambda: {"G0": 1e4, "G1": 5e3, "eta1": 7e3, "work_of_adhesion": 1e-3})
    cases["synth_nested"] = [problem([c], o.replace(rheology="prony:2"), "prony:2", prev)
                             for c in synth[:4]]
    cases["synth_elastic"] = [problem([c], o.replace(rheology="elastic"), "elastic")
                              for c in synth[:4]]
    cases["synth_opts"] = [problem([c], o.replace(
        fixed={"G1": 4e3}, initial={"G0": 2e4}, bounds={"eta1": (1.0, 1e6)},
        force_offset=True, max_samples=40, n_starts=5)) for c in synth[:4]]
    hist = make_history_map(16, 200)
    oh = FitOptions(radius=12e-6, model="history", progress=False)
    cases["hist16"] = [problem([c], oh) for c in hist]
    cases["hist16_screen"] = [problem([c], oh.replace(screen=256)) for c in hist[:4]]
    real = {}
    for folder, name, kw in [
            (DATA, "force-map-2x2.jpk-force-map", {}),
            (DATA, "oocyte-stress-relaxation-cell1-0008.jpk-force", {}),
            (DATA, "sin-force-distance.ibw", {}),
            (DATA, "creep-compliance-polymergel.jpk-force", {}),
            (DATA, "chiaro-indentation-AEBP1-002.txt", {}),
            (DATA, "bruker-sapphire-force-TAP525.001", {}),
            (DATA, "qi-10px-2026-jpk8.jpk-qi-data", {}),
            (HELD_OUT, "force-distance-spot3-0192.jpk-force", {}),
            (HELD_OUT, "asylum-U3_3_p10004.ibw", {}),
            (DATA, "qi-2x2-2020.02.07.jpk-qi-data", {"contact_point": "none"})]:
        try:
            loaded = fitting.load_curve(folder / name, on_error="keep", **kw)
            real[name] = [c for c in loaded if isinstance(c, fitting.Curve)]
        except Exception as exc:  # noqa: BLE001 - a file this version cannot read
            print("load", name, exc, file=sys.stderr)
    for name, cs in real.items():
        for model in ("relaxed", "history"):
            oo = FitOptions(radius=5e-6, model=model, progress=False)
            cases[f"{name}:{model}"] = [problem([c], oo) for c in cs]
            cases[f"{name}:{model}:screen"] = [problem([c], oo.replace(screen=256))
                                               for c in cs[:2]]
            cases[f"{name}:{model}:detected"] = [
                problem([c], oo.replace(contact_point="detect", max_samples=300))
                for c in cs[:2]]
        relaxed = FitOptions(radius=5e-6, model="relaxed", progress=False)
        cases[f"{name}:joint"] = [problem(cs, relaxed)]
        cases[f"{name}:range"] = [problem([c], relaxed.replace(indentation_range=(1e-7, 1e-6)))
                                  for c in cs[:2]]
        cases[f"{name}:approach"] = [problem([c], FitOptions(
            radius=5e-6, model="history", progress=False, segments="approach"))
            for c in cs[:2]]
    if "oocyte-stress-relaxation-cell1-0008.jpk-force" in real:
        sphere = FitOptions(profile=jc.Sphere(5e-6), model="relaxed", progress=False)
        cases["oocyte:sphere"] = [problem(real["oocyte-stress-relaxation-cell1-0008.jpk-force"],
                                          sphere)]
    with open(path, "wb") as fh:
        pickle.dump(cases, fh)
    print(f"{sum(map(len, cases.values()))} problems in {len(cases)} cases, "
          f"{sum('error' in p for v in cases.values() for p in v)} errors", file=sys.stderr)


def _same(x, y) -> bool:
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype != y.dtype or x.shape != y.shape:
            return False
        if x.dtype.kind == "f":
            return bool(np.array_equal(x, y, equal_nan=True)
                        and np.array_equal(np.signbit(x), np.signbit(y)))
        return bool(np.array_equal(x, y))
    if isinstance(x, tuple | list) and isinstance(y, tuple | list):
        return (type(x) is type(y) and len(x) == len(y)
                and all(_same(p, q) for p, q in zip(x, y, strict=True)))
    return x == y


def compare(path_a: str, path_b: str) -> int:
    with open(path_a, "rb") as fh:
        a = pickle.load(fh)
    with open(path_b, "rb") as fh:
        b = pickle.load(fh)
    if a.keys() != b.keys():
        print("cases differ:", sorted(a.keys() ^ b.keys()))
        return 1
    bad = n = 0
    for k in a:
        if len(a[k]) != len(b[k]):
            print(k, "number of problems differs")
            bad += 1
            continue
        for i, (p, q) in enumerate(zip(a[k], b[k], strict=True)):
            n += 1
            if p.keys() != q.keys():
                print(k, i, "fields differ", sorted(p.keys() ^ q.keys()), p.get("error"),
                      q.get("error"))
                bad += 1
                continue
            for f in p:
                if not _same(p[f], q[f]):
                    bad += 1
                    print(k, i, f, "differs:", str(p[f])[:300], "|", str(q[f])[:300])
    errors = sum("error" in p for v in a.values() for p in v)
    print(f"{n} problems compared ({errors} of them errors), {bad} differences")
    return int(bad > 0)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "dump":
        dump(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    else:
        sys.exit(__doc__)
