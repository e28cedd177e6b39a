"""Contact and baseline of real curves under a constant and a linear baseline.

Run from the repository root:
``python benchmarks/data/measure_preprocessing.py tests/data/*.jpk-force benchmarks/data/*.ibw``
Prints, per curve: baseline region, contact time, largest indentation, largest force,
noise, mean of the free-retract tail in units of the noise, baseline slope.
"""

import pathlib
import sys

import numpy as np

import fitting


def main(files):
    for f in files:
        name = pathlib.Path(f).name[:34]
        for bl in ("constant", "linear"):
            try:
                curves = fitting.load_curve(f, baseline=bl)
            except ValueError as exc:
                print(name, bl, "ERROR", str(exc)[:120])
                continue
            for n, c in enumerate(curves[:4]):
                cp = c.contact
                r = c.mask("retract") if "retract" in c.segment_names else None
                tail = c.force[r][-max(10, int(0.2 * r.sum())) :] if r is not None else [0.0]
                print(
                    f"{name:34s}#{n} {bl:8s} region={cp.baseline_region:17s} "
                    f"t_c={cp.time:8.3f}s dmax={c.displacement.max() * 1e6:7.3f}um "
                    f"Fmax={c.force.max() * 1e9:8.3f}nN noise={cp.noise * 1e12:7.1f}pN "
                    f"ret_tail_mean={np.mean(tail) / cp.noise:6.1f}sigma "
                    f"slope={cp.force_slope * 1e12:8.2f}pN/s"
                )


if __name__ == "__main__":
    main(sys.argv[1:])
