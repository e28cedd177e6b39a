"""Facts about the devices that size the work sent to them (the one home of the device
memory query, used by the sweeps' chunks and the fits' chunks, and of the count of CPU
cores this process may use, which sizes the host threads of both)."""

from __future__ import annotations

import os
from functools import lru_cache

__all__ = ["memory_limit", "usable_cores"]


@lru_cache(maxsize=8)
def memory_limit(device) -> int | None:
    """The device's memory limit [bytes], None where the backend reports none (the CPU);
    asked once per device (the query costs a noticeable part of a small sweep)."""
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001 - backends without memory statistics
        return None
    return int(stats["bytes_limit"]) if stats and stats.get("bytes_limit") else None


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the platform has one,
    else every core of the machine), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - platforms without affinity
        return max(1, os.cpu_count() or 1)
