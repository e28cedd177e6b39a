"""Facts about the devices that size the work sent to them (the one home of the device
memory query, used by the sweeps' chunks and the fits' chunks)."""

from __future__ import annotations

from functools import lru_cache

__all__ = ["memory_limit"]


@lru_cache(maxsize=8)
def memory_limit(device) -> int | None:
    """The device's memory limit [bytes], None where the backend reports none (the CPU);
    asked once per device (the query costs a noticeable part of a small sweep)."""
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001 - backends without memory statistics
        return None
    return int(stats["bytes_limit"]) if stats and stats.get("bytes_limit") else None
