"""Several processes (after `jax.distributed.initialize`): the one home of gathering
results from every process.

The sweeps (`_sweep/_run.py`) and the force-map fits (`fitting.fit_each`) split their
independent work between the processes of a multi-process JAX program (every process calls
them with the same arguments, SPMD) and return the whole result on every process:

- `allgather(tree)`: arrays whose leading axis is each process's share, concatenated over
  the processes in process order (`multihost_utils.process_allgather`, tiled);
- `gather_objects(obj)`: any picklable Python object of each process (the fits' result
  objects), as a list in process order: pickled to bytes, the lengths gathered first, the
  bytes padded to the longest and gathered as one `uint8` array.

With one process both return their input unchanged (`[obj]`), without touching the
distributed runtime.
"""

from __future__ import annotations

import pickle

import jax
import numpy as np

__all__ = ["allgather", "gather_objects"]


def allgather(tree):
    """The leaves of `tree` concatenated over the processes along their leading axis (each
    process's share in process order); one process: `tree` itself."""
    if jax.process_count() == 1:
        return tree
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


def gather_objects(obj) -> list:
    """Every process's `obj` (picklable), as a list in process order, on every process; one
    process: ``[obj]``."""
    n = jax.process_count()
    if n == 1:
        return [obj]
    from jax.experimental import multihost_utils

    data = np.frombuffer(pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL), np.uint8)
    sizes = np.asarray(multihost_utils.process_allgather(np.array([data.size], np.int64)))
    sizes = sizes.reshape(n)
    buf = np.zeros(int(sizes.max()), np.uint8)
    buf[: data.size] = data
    every = np.asarray(multihost_utils.process_allgather(buf)).reshape(n, -1)
    return [pickle.loads(every[p, : int(sizes[p])].tobytes()) for p in range(n)]
