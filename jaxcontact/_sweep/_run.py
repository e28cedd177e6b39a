"""Running a sweep: chunks sized to memory, a 1-D device mesh, several processes, progress.

**Devices.** The points of a chunk are split over a one-dimensional mesh of all devices
(`jax.sharding.Mesh(jax.devices(), ("points",))`): the chunk's parameters, one array of
shape `(chunk, parameters)` (one transfer), are created with `NamedSharding(mesh,
PartitionSpec("points", None))` and the vmapped model is `jax.jit`-ed with sharded inputs
and outputs, so every device computes its slice and nothing is communicated during the
computation (the points are independent).

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
"""

from __future__ import annotations

import math
import sys
import time
from functools import lru_cache

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._validate import plausibility_checks, unchecked
from ._models import PointResult

__all__ = ["run_points", "default_precision", "chunk_size_for"]

_MAX_CHUNK = 2**17


def default_precision() -> str:
    """float32 on accelerators (GPU, TPU), float64 on the CPU."""
    return "float64" if jax.default_backend() == "cpu" else "float32"


@lru_cache(maxsize=8)
def _memory_limit(device) -> int | None:
    """The device's memory limit [bytes], None where the backend reports none (the CPU);
    asked once per device (the query costs 0.2 ms, a tenth of a small sweep)."""
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001 - backends without memory statistics
        return None
    return int(stats["bytes_limit"]) if stats and stats.get("bytes_limit") else None


def _device_budget(devices, model, curves) -> int:
    limit = _memory_limit(devices[0])
    if limit is not None:
        return limit // 2
    return int(model.cpu_chunk_budget(curves))


def chunk_size_for(model, arms, itemsize, curves, n_points, n_devices, memory_limit=None,
                   devices=None) -> int:
    """Curves per chunk: the memory budget per device over the estimated bytes per curve,
    a multiple of `n_devices`."""
    per_curve = model.floats_per_curve(arms, curves) * itemsize + 256
    budget = (memory_limit if memory_limit is not None
              else _device_budget(devices, model, curves))
    per_device = max(1, min(int(budget) // per_curve, _MAX_CHUNK))
    # the points in as few chunks as the budget allows, of equal size (1,000 points under a
    # budget of 760 run as two chunks of 500, not 760 + 240 padded to 760), rounded up to
    # 1/8 of an octave (at most 12.5 % padding; sweeps of similar sizes share one program)
    need = math.ceil(n_points / n_devices)
    size = math.ceil(need / math.ceil(need / per_device))
    step = 1 << max(0, (size - 1).bit_length() - 3)
    size = step * math.ceil(size / step)
    return n_devices * max(1, size)


@lru_cache(maxsize=32)
def _compiled(model, material, profile, names, curves, devices, dtype_name):
    """The vmapped model on a chunk `(chunk, len(names))` of parameter columns (one array:
    one host-to-device transfer per chunk), sharded by rows; and that input sharding."""
    mesh = Mesh(np.asarray(devices), ("points",))
    sharding = NamedSharding(mesh, PartitionSpec("points", None))
    out_sharding = NamedSharding(mesh, PartitionSpec("points"))

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

    fn = jax.jit(jax.vmap(one), in_shardings=(sharding,), out_shardings=out_sharding)
    return fn, sharding


class _Progress:
    """A progress line on stderr: percent, curves, elapsed and remaining time."""

    def __init__(self, total, chunks, enabled, label="sweep"):
        self.total, self.chunks, self.label = total, chunks, label
        self.enabled = enabled
        self.tty = enabled and hasattr(sys.stderr, "isatty") and sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self.last = -math.inf

    def update(self, done_chunks, done_points):
        if not self.enabled:
            return
        now = time.perf_counter()
        final = done_chunks == self.chunks
        if not final and now - self.last < (0.2 if self.tty else 5.0):
            return
        self.last = now
        elapsed = now - self.t0
        frac = done_points / self.total
        left = elapsed * (1 - frac) / frac if frac > 0 else math.nan
        text = (f"{self.label}: {100 * frac:5.1f}% ({done_points:,}/{self.total:,} curves, "
                f"chunk {done_chunks}/{self.chunks}), {elapsed:.1f} s"
                + ("" if final else f", ~{left:.0f} s left"))
        if self.tty:
            print("\r" + text, end="\n" if final else "", file=sys.stderr, flush=True)
        else:
            print(text, file=sys.stderr, flush=True)


def _fetch(out):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        out = multihost_utils.process_allgather(out, tiled=True)
    return jax.tree_util.tree_map(np.asarray, out)


def run_points(model, material, profile, scaled, *, dtype, curves, chunk_size=None,
               memory_limit=None, progress=True) -> dict:
    """Run the model at every point; `scaled` maps names to float64 arrays `(P,)` in the
    points' own units. Returns name -> numpy array `(P,)` (curves: `(P, samples)`) and the
    chunking used."""
    devices = tuple(jax.devices())
    n_dev = len(devices)
    names = tuple(sorted(scaled))
    n_points = next(iter(scaled.values())).shape[0]
    arms = getattr(material, "arms", 1)
    itemsize = np.dtype(dtype).itemsize
    if chunk_size is None:
        chunk = chunk_size_for(model, arms, itemsize, curves, n_points, n_dev, memory_limit,
                               jax.local_devices())
    else:
        chunk = n_dev * max(1, math.ceil(int(chunk_size) / n_dev))
    n_chunks = math.ceil(n_points / chunk)
    dtype_name = np.dtype(dtype).name
    with jax.enable_x64(dtype_name == "float64"):
        fn, sharding = _compiled(model, material, profile, names, curves, devices, dtype_name)
        bar = _Progress(n_points, n_chunks, progress and jax.process_index() == 0)
        results: dict = {}

        def launch(i):
            lo = i * chunk
            hi = min(lo + chunk, n_points)
            idx = np.arange(lo, lo + chunk)
            idx = np.where(idx < hi, idx, lo)  # pad with copies of the chunk's first point
            host = np.stack([scaled[n][idx] for n in names], axis=1).astype(dtype)
            if jax.process_count() == 1:
                return fn(jax.device_put(host, sharding)), lo, hi
            cols = jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])
            return fn(cols), lo, hi

        def collect(pending):
            out, lo, hi = pending
            host = _fetch(out)
            for field, value in _fields(host):
                if field not in results:
                    shape = (n_points,) + value.shape[1:]
                    results[field] = np.empty(shape, dtype=value.dtype)
                results[field][lo:hi] = value[: hi - lo]

        pending = None
        for i in range(n_chunks):
            nxt = launch(i)  # dispatched asynchronously: overlaps the copy of the previous one
            if pending is not None:
                collect(pending)
                bar.update(i, pending[2])
            pending = nxt
        collect(pending)
        bar.update(n_chunks, n_points)
    return results, dict(chunk_size=chunk, chunks=n_chunks, devices=n_dev,
                         processes=jax.process_count())


def _fields(result: PointResult):
    for name in PointResult.__dataclass_fields__:
        value = getattr(result, name)
        if value is not None:
            yield name, value
