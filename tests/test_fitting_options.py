"""The options of `fitting.fit` and `fitting.fit_each` as one checked, frozen object
(`fitting.FitOptions`, and `fitting.BatchOptions` for the scheduling only `fit_each` has):
bad values are named when the object is made, keywords and objects are one way in, and a
keyword that contradicts the object is refused. No fit runs here (the fits through
options are compared in tests/test_fitting_each.py, with its compiled shapes)."""

import dataclasses
import inspect
import os

import jax
import numpy as np
import pytest

import fitting
import jaxcontact as jc

R = 12e-6


@pytest.mark.parametrize("bad, needle", [
    (dict(n_starts=0), "n_starts must be an integer >= 1; got 0"),
    (dict(n_starts=2.5), "n_starts must be an integer >= 1"),
    (dict(max_steps=0), "max_steps must be an integer >= 1"),
    (dict(optimiser="newton"), "optimiser must be one of ('lm', 'lbfgs')"),
    (dict(rtol=1.0), r"rtol must be a number in (0, 1); got 1.0"),
    (dict(local_rounds=-1), "local_rounds must be an integer >= 0; got -1"),
    (dict(seed=-3), "seed must be an integer >= 0"),
    (dict(max_samples=3), "max_samples must be an integer >= 4; got 3"),
    (dict(cells=1), "cells must be an integer >= 2"),
    (dict(search_cells=1), "search_cells must be an integer >= 2; got 1"),
    (dict(search_cells=33), "search_cells must be an integer in [2, cells = 32]; got 33"),
    (dict(cells=8, search_cells=16), "search_cells must be an integer in [2, cells = 8]"),
    (dict(model="creep"), "model must be 'relaxed' or 'history'"),
    (dict(rheology="maxwell"), "rheology must be 'standard', 'prony:N'"),
    (dict(rheology="prony:9"), "needs an integer N in [1, 8]"),
    (dict(contact_point="guess"), "contact_point must be one of 'fit', 'detect'"),
    (dict(indentation_range=(2e-7, 1e-7)), "indentation_range must be finite with low < high"),
    (dict(segments="hold"), "segments"),
    (dict(radius=-1.0), r"radius must be finite and > 0 [m]; got -1.0"),
    (dict(radius=None), "radius must be finite and > 0"),
    (dict(profile=jc.Parabola(R)), "give either radius or profile, not both"),
    (dict(spring_constant=-0.1, model="history"), "spring_constant must be finite and > 0"),
    (dict(spring_constant=0.1), "needs model='history'"),
    (dict(initial=[("G0", 1e4)]), "initial must be a mapping"),
    (dict(force_offset="yes"), "force_offset must be True or False"),
])
def test_bad_options_are_named_when_made(bad, needle):
    kw = dict(radius=R) | bad
    with pytest.raises(ValueError) as info:
        fitting.FitOptions(**kw)
    assert needle in str(info.value)
    # the same check, and the same words, through the keywords of fit and fit_each
    curve = fitting.Curve(time=np.linspace(0, 1, 8), displacement=np.linspace(1e-6, 0, 8),
                          force=np.zeros(8))
    for fn in (fitting.fit, fitting.fit_each):
        with pytest.raises(ValueError) as info:
            fn([curve], **kw)
        assert needle in str(info.value)


@pytest.mark.parametrize("bad, needle", [
    (dict(chunk=0), "chunk must be an integer >= 1; got 0"),
    (dict(workers=0), "workers must be an integer >= 1"),
    (dict(streams=0), "streams must be an integer >= 1; got 0"),
    (dict(streams=1.5), "streams must be an integer >= 1"),
    (dict(devices=[]), "devices: give at least one device"),
])
def test_bad_batch_options_are_named_when_made(bad, needle):
    with pytest.raises(ValueError, match=needle):
        fitting.BatchOptions(**bad)


def test_options_are_frozen_keyword_only_and_normalised():
    o = fitting.FitOptions(radius=R, n_starts=None, segments="retract",
                           indentation_range=[0, 1e-6], initial={"G0": 1e4})
    assert o.n_starts == fitting.DEFAULT_STARTS and o.segments == ("retract",)
    assert o.indentation_range == (0.0, 1e-6) and o.probe == jc.Parabola(R)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.n_starts = 3
    with pytest.raises(TypeError):
        o.initial["G0"] = 2e4  # a read-only copy: the caller's dict cannot change it
    with pytest.raises(TypeError):
        fitting.FitOptions(R)  # keywords only
    assert o.replace(n_starts=4).n_starts == 4 and o.n_starts == fitting.DEFAULT_STARTS
    with pytest.raises(ValueError, match="n_starts"):
        o.replace(n_starts=0)  # a copy is checked like a new object
    # the nested chain of models and the solver are the options' own
    assert fitting.FitOptions(radius=R, rheology="prony:3").chain() == \
        ["standard", "prony:2", "prony:3"]
    assert fitting.FitOptions(radius=R, rheology="auto").chain() == \
        ["standard", "prony:2", "prony:3"]
    assert fitting.FitOptions(radius=R, rheology="elastic").chain() == ["elastic"]
    assert isinstance(o.replace(optimiser="lbfgs").solver(), fitting.LBFGS)
    assert o.solver().max_steps == 200 and o.solver().rtol == 1e-8
    # the search's grid: the fit's own by default; a coarser one for the history model only
    assert o.search_cells == o.cells == 32
    spec = fitting.make_spec("history", "standard", cells=32)
    assert o.search_spec(spec) is spec
    coarse = o.replace(search_cells=16).search_spec(spec)
    assert coarse.cells == 16 and coarse.model == "history"
    assert dataclasses.replace(coarse, cells=32) == spec
    relaxed = fitting.make_spec("relaxed", "standard")
    assert o.replace(search_cells=16).search_spec(relaxed) is relaxed


def test_keywords_and_options_are_one_way_in():
    curve = fitting.Curve(time=np.linspace(0, 1, 8), displacement=np.linspace(1e-6, 0, 8),
                          force=np.zeros(8))
    o = fitting.FitOptions(radius=R, n_starts=4)
    # a keyword that contradicts the object: refused, both values named
    for fn in (fitting.fit, fitting.fit_each):
        with pytest.raises(ValueError, match=r"n_starts given both in options \(n_starts=4\) "
                                             r"and as keywords \(n_starts=5\)"):
            fn([curve], options=o, n_starts=5)
    with pytest.raises(ValueError, match="chunk given both"):
        fitting.fit_each([curve], options=o, batch=fitting.BatchOptions(chunk=2), chunk=3)
    # the batch's options are not fit's; unknown keywords are a TypeError naming them
    with pytest.raises(TypeError, match="unexpected keyword argument 'chunk'"):
        fitting.fit(curve, options=o, chunk=2)
    with pytest.raises(TypeError, match="unexpected keyword argument 'n_start'"):
        fitting.fit_each([curve], radius=R, n_start=2)
    with pytest.raises(TypeError, match="options must be a fitting.FitOptions"):
        fitting.fit(curve, options={"radius": R})
    # fit_each's restrictions belong to its use of the options: one model, one spring
    with pytest.raises(ValueError, match="rheology: 'auto' is not offered by fit_each"):
        fitting.fit_each([curve], options=o.replace(rheology="auto"))
    with pytest.raises(ValueError, match="spring_constant: give one value"):
        fitting.fit_each([curve], options=o.replace(model="history",
                                                    spring_constant=[0.1, 0.2]))
    # an agreeing keyword is accepted (merged without change)
    assert fitting.FitOptions.merge(o, {"n_starts": 4, "radius": R}, where="fit") == o


def test_signatures_show_the_options_with_their_defaults():
    fields = {f.name: f.default for f in dataclasses.fields(fitting.FitOptions)}
    batch = {f.name: f.default for f in dataclasses.fields(fitting.BatchOptions)}
    for fn, want in ((fitting.fit, fields), (fitting.fit_each, fields | batch)):
        params = inspect.signature(fn).parameters
        assert {k: params[k].default for k in want} == want
        assert params["options"].default is None
    assert "batch" in inspect.signature(fitting.fit_each).parameters
    assert "chunk" not in inspect.signature(fitting.fit).parameters


def test_schedule_by_platform():
    # a CPU runs few lanes that refill (one per 8 starts, 8 to 64); an accelerator gives
    # every start of a large chunk its own lane; explicit values win on both
    class Gpu:
        platform = "gpu"

    cpu = fitting.BatchOptions(devices=jax.devices("cpu")[:1])
    gpu = fitting.BatchOptions(devices=[Gpu()])
    assert not cpu.accelerated and gpu.accelerated
    # a CPU's chunk: 64, or, where that would leave a stream (one per usable core) without
    # a chunk, the problems over the streams
    from jaxcontact._devices import usable_cores

    cores = usable_cores()
    assert [cpu.chunk_for(n) for n in (1, 5, 64 * cores, 64 * cores + 1)] == [
        1, -(-5 // cores), 64, 64]
    one, four = (fitting.BatchOptions(streams=k, devices=jax.devices("cpu")[:1]) for k in (1, 4))
    assert [one.chunk_for(n) for n in (5, 100)] == [5, 64]
    assert [four.chunk_for(n) for n in (100, 192, 193, 256)] == [25, 48, 64, 64]
    assert [gpu.chunk_for(n) for n in (1, 300, 20_000)] == [1, 300, 4096]
    assert [cpu.lanes(p, 16) for p in (1, 4, 8, 16, 100)] == [8, 8, 16, 32, 64]
    assert [cpu.lanes(p, 16, model="history") for p in (1, 16, 100)] == [8, 32, 32]
    assert gpu.lanes(4096, 16, model="history") == 65_536
    assert cpu.lanes(1, 4) == 4  # never more lanes than starts
    assert [gpu.lanes(p, 16) for p in (1, 4096)] == [16, 65_536]
    assert fitting.BatchOptions(chunk=3, workers=5, devices=[Gpu()]).chunk_for(100) == 3
    # an accelerator's chunk keeps the search within half of its memory (a 16 GiB card:
    # 8 GiB over 16 starts of 600 residuals at 1 KiB each: 873 problems); a CPU's does not
    # depend on it

    class SmallGpu(Gpu):
        def memory_stats(self):
            return {"bytes_limit": 16 * 2**30}

    per = fitting._options.SEARCH_BYTES_PER_RESIDUAL * 16 * 600
    small = fitting.BatchOptions(devices=[SmallGpu()])
    assert small.chunk_for(20_000, problem_bytes=per) == (8 * 2**30) // per == 873
    assert small.chunk_for(20_000, problem_bytes=per // 100) == 4096
    assert cpu.chunk_for(1000, problem_bytes=per * 10**6) == 64
    assert fitting.BatchOptions(workers=5, devices=[Gpu()]).lanes(100, 16) == 5
    # chunks searched at once: one per usable core and device on a CPU (JAX's CPU devices
    # share the cores), one on an accelerator; never more than the chunks
    assert cores == len(os.sched_getaffinity(0))
    assert [cpu.streams_for(n) for n in (1, 1000)] == [1, cores]
    two = fitting.BatchOptions(devices=jax.devices("cpu")[:1] * 2)
    assert two.streams_for(1000) == max(1, cores // 2)
    assert [gpu.streams_for(n) for n in (1, 1000)] == [1, 1]
    assert fitting.BatchOptions(streams=3, devices=[Gpu()]).streams_for(1000) == 3
    assert fitting.BatchOptions(streams=3).streams_for(2) == 2


def test_chunk_padding_repeats_the_last_item():
    # the one padding rule of a chunk: the items in order, then the last repeated
    from fitting._options import padded_indices

    assert padded_indices(3, 5).tolist() == [0, 1, 2, 2, 2]
    assert padded_indices(4, 4).tolist() == [0, 1, 2, 3]
    assert padded_indices(1, 3).tolist() == [0, 0, 0]
