"""The progress lines (`jaxcontact._progress.Progress`): format, throttling, silence."""

import io
import re

from jaxcontact._progress import Progress


def test_update_lines_throttled_and_final():
    out = io.StringIO()  # not a terminal: one line per print
    bar = Progress(True, "sweep", total=10_000, log_interval=3600.0, stream=out)
    bar.update(4_000, detail="chunk 2/5")
    bar.update(6_000, detail="chunk 3/5")  # within the interval: suppressed
    bar.update(10_000, detail="chunk 5/5", final=True)  # the final line always prints
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    assert re.fullmatch(r"sweep:  40\.0% \(4,000/10,000 curves, chunk 2/5\), \d+\.\d s, ~\d+ s left",
                        lines[0])
    assert re.fullmatch(r"sweep: 100\.0% \(10,000/10,000 curves, chunk 5/5\), \d+\.\d s", lines[1])


def test_stage_and_message():
    out = io.StringIO()
    bar = Progress(True, "fit-each", total=4, stream=out)
    bar.stage("search", 0)
    bar.stage("search", 4)
    bar.message("done")
    lines = out.getvalue().splitlines()
    assert re.fullmatch(r"\[fit-each +\d+\.\d s\] search: 0/4 curves", lines[0])
    assert re.fullmatch(r"\[fit-each +\d+\.\d s\] search: 4/4 curves", lines[1])  # no estimate at the end
    assert re.fullmatch(r"\[fit-each +\d+\.\d\d s\] done", lines[2])


def test_disabled_is_silent():
    out = io.StringIO()
    bar = Progress(False, "sweep", total=3, stream=out)
    bar.update(3, final=True)
    bar.stage("x", 1)
    bar.message("y")
    assert out.getvalue() == ""
