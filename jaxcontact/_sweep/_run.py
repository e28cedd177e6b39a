"""Running a sweep: chunks sized to memory, a 1-D device mesh, several processes, progress.

**Devices.** The points of a chunk are split over a one-dimensional mesh of all devices
(`jax.sharding.Mesh(jax.devices(), ("points",))`): the chunk's parameters, one array of
shape `(chunk, parameters)` (one transfer), are created with `NamedSharding(mesh,
PartitionSpec("points", None))` and the vmapped model is `jax.jit`-ed with sharded inputs
and outputs as a `jax.shard_map` over the mesh, so every device computes its slice as its
own program and nothing is communicated during the computation (the points are independent;
a branch of the model that no point of a device's slice takes is skipped on that device).

**Processes.** After `jax.distributed.initialize` `jax.devices()` lists the devices of every
process; the same mesh then spans the hosts. Every process builds the same chunks (the
parameter grid is cheap and deterministic) and supplies only the shards of its own devices
(`jax.make_array_from_callback`), so each process computes its share. The outputs of each
chunk are gathered to every process (`multihost_utils.process_allgather`); every process
returns the whole result and process 0 writes it. All processes must call `sweep` with the
same arguments (SPMD, as any multi-process JAX program).

**Memory.** A chunk holds `chunk_size` curves (a multiple of the number of devices; the
last chunk is padded with copies of a valid point whose results are dropped). By default
the size follows from a budget per device (`memory_limit`, default: half of the device's
memory limit where the backend reports one (GPUs), else the model's `cpu_chunk_budget`:
for `RelaxedStart` 8 MiB (summaries) or 32 MiB (with the curves), whose chunks then stay
near the CPU's caches, 512 MiB for `ApproachHoldLift`, which does much more work per byte)
divided by an upper estimate of the bytes one point needs (the model's `floats_per_curve`),
and no larger than the points need (rounded up to 1/8 of an octave per device, so that sweeps of
similar sizes share one compiled program).

**Compilation.** On the CPU the chunk's program is compiled with the host's CPU options
(`jaxcontact._xla.cpu_options`: 512-bit vectors on AMD's AVX-512, the same numbers, 11-20 %
faster there: benchmarks/results/sweep.md, section 11).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._devices import memory_limit, usable_cores
from .._processes import allgather
from .._progress import Progress
from .._validate import plausibility_checks, unchecked
from .._xla import cpu_options

__all__ = ["run_points", "default_precision", "chunk_size_for", "SUMMARY_FIELDS", "CURVE_FIELDS"]

# curves per device and compiled call at most (GPUs: the budget is half the device memory):
# smaller chunks overlap the host's preparation of the next ones with the device's work
# (benchmarks/results/device.md: 2^20 faster than 2^22 and 2^23 for relaxed summaries)
_MAX_CHUNK = 2**20

# chunks whose parameter columns are prepared ahead, in threads (numpy releases the GIL in
# its array operations, so they run side by side and alongside the device)
_HOST_THREADS = min(8, usable_cores())

# host threads only for sweeps of at least this many points: starting a pool costs 0.5-2.3
# ms on a busy 2-core CPU (more than a 10^3-point sweep's whole host path), while the work
# it spreads (the columns of a chunk, the summaries' units) takes microseconds per 10^4
# points (benchmarks/results/sweep.md, section 8)
_THREADS_MIN_POINTS = 2**17


def host_threads(n_points: int) -> int:
    """Threads for the host's work on `n_points` points (1: none, the work in the calling
    thread)."""
    return _HOST_THREADS if n_points >= _THREADS_MIN_POINTS else 1


def default_precision() -> str:
    """float32 on accelerators (GPU, TPU), float64 on the CPU."""
    return "float64" if jax.default_backend() == "cpu" else "float32"


def _device_budget(device, model, curves) -> int:
    limit = memory_limit(device)
    if limit is not None:
        return limit // 2
    return int(model.cpu_chunk_budget(curves))


def chunk_size_for(model, arms, itemsize, curves, n_points, n_devices, memory_limit=None,
                   devices=None) -> int:
    """Curves per chunk: the memory budget per device over the estimated bytes per curve,
    a multiple of `n_devices`."""
    per_device = _per_device(model, arms, itemsize, curves, memory_limit,
                             None if memory_limit is not None else devices[0])
    # the points in as few chunks as the budget allows, of equal size (1,000 points under a
    # budget of 760 run as two chunks of 500, not 760 + 240 padded to 760), rounded up to
    # 1/8 of an octave (at most 12.5 % padding; sweeps of similar sizes share one program)
    need = math.ceil(n_points / n_devices)
    size = math.ceil(need / math.ceil(need / per_device))
    step = 1 << max(0, (size - 1).bit_length() - 3)
    size = step * math.ceil(size / step)
    return n_devices * max(1, size)


@lru_cache(maxsize=64)
def _per_device(model, arms, itemsize, curves, memory_limit, device) -> int:
    # (cached: an equinox module's bound methods are built at every access, a noticeable
    # part of a small sweep's host time)
    per_curve = model.floats_per_curve(arms, curves) * itemsize + 256
    budget = (memory_limit if memory_limit is not None
              else _device_budget(device, model, curves))
    return max(1, min(int(budget) // per_curve, _MAX_CHUNK))


#: the summaries of `PointResult`, packed in this order into one output row per point
SUMMARY_FIELDS = ("max_tensile_force", "jumpoff_force", "jumpoff_displacement", "jumpoff_time",
                  "jumpoff_radius", "separation_work", "lift_duration", "status",
                  "separation_work_error")
CURVE_FIELDS = ("time", "displacement", "force", "contact_radius")


@lru_cache(maxsize=32)
def _compiled(model, material, profile, names, curves, devices, dtype_name):
    """The vmapped model on a chunk `(chunk, len(names))` of parameter columns (one array:
    one host-to-device transfer per chunk), sharded by rows; and that input sharding.

    Returns `(summaries, curves)`: the summaries packed into one array `(len(SUMMARY_FIELDS),
    chunk)` of the compute dtype (the status codes, small integers, are exact in it), so a
    chunk's summaries come back in one transfer; `curves` a dict of `(chunk, samples)` arrays
    or None."""
    mesh = Mesh(np.asarray(devices), ("points",))
    sharding = NamedSharding(mesh, PartitionSpec("points", None))
    packed_sharding = NamedSharding(mesh, PartitionSpec(None, "points"))
    curve_sharding = NamedSharding(mesh, PartitionSpec("points", None))

    def one(row):
        cols = {n: row[j] for j, n in enumerate(names)}
        rheology = material.build(cols)
        shape = profile.build(cols)
        # the models work in scaled units (depth = velocity = 1): the unit plausibility
        # checks of the entry functions do not apply there (the sweep's SI inputs are
        # checked before the run); an invalid point is reported in its status, so the
        # run-time guards of the material and shape methods stay off (`unchecked`)
        with plausibility_checks(False), unchecked():
            return model.solve(rheology, shape, cols, curves=curves)

    def chunk_fn(rows):
        out = jax.vmap(one)(rows)
        packed = jnp.stack([getattr(out, f).astype(rows.dtype) for f in SUMMARY_FIELDS])
        return packed, ({f: getattr(out, f) for f in CURVE_FIELDS} if curves else None)

    out_shardings = (packed_sharding, {f: curve_sharding for f in CURVE_FIELDS} if curves
                     else None)
    if len(devices) > 1:
        # each device its own slice as its own program: the model's branches that no point
        # of the slice takes are skipped per device (`jaxcontact._sharding.switch`), with
        # no collective between the devices
        chunk_fn = jax.shard_map(
            chunk_fn, mesh=mesh, in_specs=(sharding.spec,),
            out_specs=jax.tree.map(lambda s: s.spec, out_shardings), check_vma=False)
    # the host's CPU options (512-bit vectors on AMD's AVX-512: `jaxcontact._xla`)
    fn = jax.jit(chunk_fn, in_shardings=(sharding,), out_shardings=out_shardings,
                 compiler_options=cpu_options(platform=devices[0].platform))
    return fn, sharding


def _fetch(outs):
    """The outputs of several chunks to the host, in one call (one gather across processes).
    One process: each array copied by `np.asarray` (`jax.device_get` of a list costs ~0.5
    ms more on the CPU, a noticeable part of a small sweep)."""
    if jax.process_count() == 1:
        return jax.tree.map(np.asarray, outs)
    return jax.device_get(allgather(outs))


# summaries of at most this many bytes wait on the device and come back together
_FETCH_BYTES = 2**30


def run_points(model, material, profile, names, n_points, columns, *, dtype, curves,
               chunk_size=None, memory_limit=None, progress=True, while_running=None):
    """Run the model at `n_points` points. `columns(lo, hi)` returns the points `lo:hi` as a
    float64 array `(hi - lo, len(names))` in the points' own units (the columns in the order
    of `names`). Returns `(summaries, curves, info)`: the packed summaries `(len(SUMMARY_FIELDS),
    n_points)` in the compute dtype (rows in the order of `SUMMARY_FIELDS`), name -> `(P,
    samples)` curves (or None) and the chunking used. `while_running()`, if given, is called
    once right after the first chunk has been dispatched (the host's work that does not need
    the results, e.g. the dataset's coordinates, overlaps the device's computation).

    The chunks' summaries stay on the device and are fetched together at the end (or when
    they reach 1 GiB); the curves, large, are fetched chunk by chunk, each while the next
    chunk computes."""
    devices = tuple(jax.devices())
    n_dev = len(devices)
    names = tuple(names)
    arms = getattr(material, "arms", 1)
    itemsize = np.dtype(dtype).itemsize
    if chunk_size is None:
        chunk = chunk_size_for(model, arms, itemsize, curves, n_points, n_dev, memory_limit,
                               jax.local_devices())
    else:
        chunk = n_dev * max(1, math.ceil(int(chunk_size) / n_dev))
    n_chunks = math.ceil(n_points / chunk)
    dtype = np.dtype(dtype)
    summaries = np.empty((len(SUMMARY_FIELDS), n_points), dtype)
    curve_out: dict | None = {} if curves else None
    with jax.enable_x64(dtype.name == "float64"):
        fn, sharding = _compiled(model, material, profile, names, curves, devices, dtype.name)
        bar = Progress(progress and jax.process_index() == 0, "sweep", total=n_points)

        def prepare(i):
            lo = i * chunk
            hi = min(lo + chunk, n_points)
            host = np.empty((chunk, len(names)), dtype)
            host[: hi - lo] = columns(lo, hi)
            host[hi - lo:] = host[0]  # pad with copies of the chunk's first point
            return host

        # the columns of the next chunks are prepared ahead in threads (at most
        # `_HOST_THREADS` chunks of host memory waiting); small sweeps in this thread
        threads = host_threads(n_points)
        pool = ThreadPoolExecutor(threads) if n_chunks > 1 and threads > 1 else None
        ahead: dict = {}

        def launch(i):
            if pool is None:
                host = prepare(i)
            else:
                for k in range(i, min(i + _HOST_THREADS, n_chunks)):
                    if k not in ahead:
                        ahead[k] = pool.submit(prepare, k)
                host = ahead.pop(i).result()
            lo = i * chunk
            hi = min(lo + chunk, n_points)
            if jax.process_count() == 1:
                # the host array straight into the compiled call, which transfers it to
                # `sharding` (its input sharding) in its own dispatch
                return fn(host), lo, hi
            cols = jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])
            return fn(cols), lo, hi

        waiting: list = []  # (packed summaries on the device, lo, hi)

        def flush():
            got = _fetch([w[0] for w in waiting])
            for packed, (_, lo, hi) in zip(got, waiting, strict=True):
                summaries[:, lo:hi] = packed[:, : hi - lo]
            waiting.clear()

        try:
            pending = None
            done = 0
            for i in range(n_chunks + 1):
                nxt = launch(i) if i < n_chunks else None  # dispatched asynchronously
                if i == 0 and while_running is not None:
                    while_running()
                if pending is not None:
                    (packed, curve_dev), lo, hi = pending
                    # at most two chunks in flight (this one and the next, just dispatched):
                    # more would run side by side on the CPU and leave its caches (slower: the
                    # chunk measurements in benchmarks/results/sweep.md); the summaries stay
                    # on the device until `flush`
                    packed.block_until_ready()
                    waiting.append((packed, lo, hi))
                    if curves:
                        host_curves = _fetch(curve_dev)  # overlaps the next chunk's computation
                        for field, value in host_curves.items():
                            if field not in curve_out:
                                curve_out[field] = np.empty((n_points,) + value.shape[1:],
                                                            value.dtype)
                            curve_out[field][lo:hi] = value[: hi - lo]
                    if curves or len(waiting) * packed.nbytes >= _FETCH_BYTES:
                        flush()
                    done = hi
                    bar.update(done, detail=f"chunk {i}/{n_chunks}")  # the final line: below
                pending = nxt
            if waiting:
                flush()
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
        bar.update(n_points, detail=f"chunk {n_chunks}/{n_chunks}", final=True)
    return summaries, curve_out, dict(chunk_size=chunk, chunks=n_chunks, devices=n_dev,
                                      processes=jax.process_count())
