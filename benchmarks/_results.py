"""Shared by the benchmark scripts: the machine line of a results table and writing the
table into place (written beside it and renamed, so an interrupted run leaves no
half-written file)."""

from __future__ import annotations

import datetime
import os
import pathlib
import platform

import jax


def machine() -> str:
    """Date, host, processor, CPU cores and the jax version, for a results header."""
    proc = platform.processor()
    return (f"{datetime.date.today().isoformat()}, {platform.node()}, "
            f"{proc + ', ' if proc else ''}{os.cpu_count()} CPU cores, jax {jax.__version__}")


def write_table(path, lines: list[str]) -> str:
    """Write `lines` (header and table rows) to `path` and print them; returns the text."""
    text = "\n".join(lines) + "\n"
    out = pathlib.Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(out)
    print(text)
    return text
