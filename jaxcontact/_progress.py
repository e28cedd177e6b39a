"""Progress lines on stderr: the one home for the library's progress output.

`Progress` prints three kinds of line, all prefixed by its `label` and all silent when it is
disabled:

- `update(done, detail=..., final=...)`: a throttled progress line with the percentage, the
  count of `unit` done, the elapsed time and an estimate of the time left (the sweep:
  `sweep:  40.0% (4,000/10,000 curves, chunk 2/5), 1.2 s, ~2 s left`). On a terminal the
  line is rewritten in place (`\\r`) at most every `tty_interval` seconds; elsewhere (a log
  file) a new line at most every `log_interval` seconds. The final update always prints.
- `stage(name, done)`: one line per stage of a batch
  (`[fit-each    3.2 s] search: 4/10 curves, about 5 s left`).
- `message(text)`: one timestamped line (`[fit    0.12 s] text`).

Time is measured from the object's creation (`time.perf_counter`). The library prints
nothing else to the terminal; the command line passes `progress=True`.
"""

from __future__ import annotations

import math
import sys
import time

__all__ = ["Progress"]


class Progress:
    """Progress output on stderr (module docstring).

    **Arguments:** `enabled` (False: every method does nothing); `label` (the prefix,
    e.g. "sweep", "fit-each"); `total` (the count that `update` and `stage` measure
    against; needed by those two); `unit` (what is counted, plural: "curves");
    `tty_interval`, `log_interval`: the least seconds between two `update` lines on a
    terminal and elsewhere; `stream`: where to print (default: `sys.stderr` at the time of
    each print).
    """

    def __init__(self, enabled: bool, label: str, *, total: int | None = None,
                 unit: str = "curves", tty_interval: float = 0.2, log_interval: float = 5.0,
                 stream=None):
        self.enabled, self.label, self.total, self.unit = bool(enabled), label, total, unit
        self.tty_interval, self.log_interval = tty_interval, log_interval
        self._stream = stream
        out = self.stream
        self.tty = self.enabled and hasattr(out, "isatty") and out.isatty()
        self.t0 = time.perf_counter()
        self.last = -math.inf

    @property
    def stream(self):
        return sys.stderr if self._stream is None else self._stream

    def elapsed(self) -> float:
        """Seconds since the object was created."""
        return time.perf_counter() - self.t0

    def _print(self, text: str, **kwargs) -> None:
        print(text, file=self.stream, flush=True, **kwargs)

    def update(self, done: int, *, detail: str = "", final: bool = False) -> None:
        """A progress line (throttled, module docstring) after `done` of `total` units;
        `detail` is added inside the parentheses (e.g. "chunk 2/5")."""
        if not self.enabled:
            return
        now = time.perf_counter()
        if not final and now - self.last < (self.tty_interval if self.tty else self.log_interval):
            return
        self.last = now
        elapsed = now - self.t0
        frac = done / self.total
        left = elapsed * (1 - frac) / frac if frac > 0 else math.nan
        text = (f"{self.label}: {100 * frac:5.1f}% ({done:,}/{self.total:,} {self.unit}"
                + (f", {detail}" if detail else "") + f"), {elapsed:.1f} s"
                + ("" if final else f", ~{left:.0f} s left"))
        if self.tty:
            self._print("\r" + text, end="\n" if final else "")
        else:
            self._print(text)

    def stage(self, name: str, done: int) -> None:
        """One line: the stage `name` has reached `done` of `total` units, with the time
        left estimated from the rate so far (omitted at 0 and at the end)."""
        if not self.enabled:
            return
        dt = self.elapsed()
        eta = dt / done * (self.total - done) if 0 < done < self.total else 0.0
        self._print(f"[{self.label} {dt:7.1f} s] {name}: {done}/{self.total} {self.unit}"
                    + (f", about {eta:.0f} s left" if eta else ""))

    def message(self, text: str) -> None:
        """One timestamped line, `[label  elapsed s] text`."""
        if self.enabled:
            self._print(f"[{self.label} {self.elapsed():7.2f} s] {text}")
