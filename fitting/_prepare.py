r"""From measured curves to the arrays of a fit: :func:`prepare_curves` → :class:`CurveBatch`.

Which samples
-------------
* ``model="relaxed"``: the retract, from its deepest sample on (time counted from the
  start of the lift; the relaxed depth is the first indentation; samples above it are
  clipped to it, so noise cannot make the contact "advance").
* ``model="history"``: the approach, hold and retract segments (a ``rest`` segment is
  dropped), the free part of the approach included: it carries the contact point.
* ``segments=`` of :func:`fitting.fit` (:func:`check_segments`) narrows this choice before
  (e.g. the approach alone); the history model needs the approach.

Every selected sample is a residual. Long curves are *subsampled* — never averaged or
interpolated, which biases a curved signal — to at most `max_samples` per curve
(:func:`select_samples`): the first and last sample of every segment, the samples around
the measured jump-off (the largest force rise of the retract) and around the contact
point are always kept; the rest are spread evenly in a coordinate that is half sample
index and half arc length of the (smoothed, normalised) force, so fast changes (the start
of a hold, a detachment step) get more samples than a flat baseline. Each kept sample
stands for the measured samples nearest to it and carries their number as its weight
$w_i$ (:attr:`CurveBatch.weight`), so $\sum_i w_i r_i^2$ approximates the $\chi^2$ of all
measured samples: the fit aims at the optimum of the whole curve, every measured sample
counting once, whatever the subsampling. The estimator stays unbiased (no averaging); its
variance is larger than with all samples and the standard errors account for the weights
(:mod:`fitting._uncertainty`).

Curves of different lengths are padded to a common length by repeating the last sample
(weight 0), so all curves are evaluated in one ``vmap``.

Noise
-----
$\sigma$ of a curve: the baseline noise found by the loader when there is one (with a fitted
force drift, ``force_drift``, the free force's scatter about its straight line:
:func:`curve_noise`), else a
robust estimate from the data ($1.4826\,\mathrm{median}|\Delta^2 F|/\sqrt 6$), floored at
$10^{-6}$ of the force range (noiseless data).

The two samples on either side of the measured jump-off (the last attached and the first
detached) get $\sigma_j = \sqrt{\sigma^2 + \Delta F^2/12}$, $\Delta F$ the jump between
them: point samples say only that the contact was lost somewhere between them, a time
known to the sampling interval (a uniform distribution over it has variance
$\Delta t^2/12$), and the model resolves its own jump-off inside the interval
(:mod:`fitting._objective`). Without this the fit would claim the jump-off time, and
with it $\Delta\gamma$ when the contact jumps off from the pinned phase, to a precision
the samples do not have.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float, Int

import jaxcontact as jc
from jaxcontact._validate import plain

from ._curve import Curve, select_segments
from ._host import rebuild
from ._spec import ModelSpec

__all__ = ["CurveBatch", "prepare_curves", "stack_batches", "select_samples", "sample_weights",
           "noise_level",
           "SEGMENTS",
           "DEFAULT_MAX_SAMPLES", "CONTACT_POINT", "contact_point_mode",
           "check_indentation_range", "check_segments", "select_fit_segments"]

#: Segment codes of :attr:`CurveBatch.segment`.
SEGMENTS = ("approach", "hold", "retract")

#: Default largest number of samples per curve, by model.
DEFAULT_MAX_SAMPLES = {"relaxed": 1000, "history": 600}

#: The `contact_point` of :func:`fitting.fit` and :func:`fitting.fit_each` (and of
#: ``jaxcontact fit --contact-point``), one vocabulary: what the fit does with the
#: curves' contact point.
CONTACT_POINT = {
    "fit": "fit the indentation offset delta [m], started at the curve's contact point",
    "detect": "use the contact point as the loader detected it (indentation as it is)",
    "none": "the data are indentation already, 0 at contact (used as it is)",
    "fixed": "older spelling of 'detect' (the indentation as it is)",
}


def contact_point_mode(contact_point: str | None, curves: Sequence[Curve]) -> str:
    """The fit's handling of the contact point: ``"fit"`` (an indentation offset is a
    parameter) or ``"fixed"`` (the indentation as it is), from the public vocabulary
    :data:`CONTACT_POINT` (`None`: ``"fit"`` when a loader detected a curve's contact
    point, else as it is). Raises `ValueError` naming the allowed values."""
    if contact_point is None:
        detected = any(c.contact is not None and c.contact.method != "none" for c in curves)
        return "fit" if detected else "fixed"
    if contact_point not in CONTACT_POINT:
        raise ValueError(f"contact_point must be one of {', '.join(map(repr, CONTACT_POINT))} "
                         f"or None; got {plain(contact_point)}")
    return "fit" if contact_point == "fit" else "fixed"


def check_indentation_range(indentation_range) -> tuple[float, float] | None:
    """`indentation_range` as ``(low, high)`` floats [m] (None: no range), or a
    `ValueError` naming it: two finite numbers, low < high."""
    if indentation_range is None:
        return None
    try:
        lo, hi = (float(x) for x in indentation_range)
    except (TypeError, ValueError):
        raise ValueError("indentation_range must be a pair (low, high) [m]; got "
                         f"{plain(indentation_range)}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError("indentation_range must be finite with low < high [m]; got "
                         f"{plain((lo, hi))}")
    return lo, hi


def check_segments(segments, model: str) -> tuple[str, ...] | None:
    """`segments` of a fit as a tuple of names (None or ``"all"``: every segment the model
    uses), or a `ValueError` naming it.

    Names: ``"approach"``, ``"hold"``, ``"retract"`` (a string is split at commas). The
    relaxed model describes the retract only, so its selection must contain
    ``"retract"``; the history model needs the approach (the contact's history; a
    viscoelastic retract depends on it), so its selection must contain ``"approach"``. A
    retract-only fit is the relaxed model (exact for ``rheology="elastic"``: an elastic
    retract depends on the largest depth only).
    """
    if segments is None:
        return None
    if isinstance(segments, str):
        segments = [s.strip() for s in segments.split(",") if s.strip()]
    try:
        names = tuple(str(s) for s in segments)
    except TypeError:
        raise ValueError(f"segments must be names from {SEGMENTS} or 'all'; got "
                         f"{plain(segments)}") from None
    if names == ("all",):
        return None
    bad = [s for s in names if s not in SEGMENTS]
    if bad or not names:
        raise ValueError(f"segments must be names from {SEGMENTS} or 'all'; got "
                         f"{plain(segments)}")
    if model == "relaxed" and "retract" not in names:
        raise ValueError(f"segments {names}: the relaxed model describes the retract; "
                         "include 'retract', or fit the approach with model='history'")
    if model == "history" and "approach" not in names:
        raise ValueError(f"segments {names}: the history model needs the approach (the "
                         "contact's history); for a retract alone use model='relaxed' (a "
                         "retract after a hold long enough to relax, or any retract with "
                         "rheology='elastic')")
    return tuple(s for s in SEGMENTS if s in names)


def select_fit_segments(curves: Sequence[Curve], segments: tuple[str, ...] | None):
    """The curves restricted to `segments` (:func:`check_segments`; None: unchanged) by
    :func:`fitting.select_segments`; a segment a curve lacks is skipped, a curve with none
    of them is a `ValueError` naming it."""
    if segments is None:
        return list(curves)
    out = []
    for n, c in enumerate(curves):
        present = [s for s in segments if s in c.segment_names]
        if not present:
            raise ValueError(f"segments: curve {n} ({c.source or 'no source'}) has none of "
                             f"{segments}; its segments are {c.segment_names}")
        out.append(select_segments(c, *present))
    return out


class CurveBatch(eqx.Module):
    r"""All curves of a fit, padded to one length `n` (shapes `(C, n)` / `(C,)`).

    **Fields:** `ts` [s] (from the first selected sample), `drive` (model input [m]: the
    indentation, or the base position $z = d + F/k$ under compliant loading), `indentation`
    [m], `force` [N], `valid` (1: a sample, 0: padding), `weight` (number of measured
    samples a kept sample stands for; 0 for padding), `lower`, `upper` [s] (the interval a
    sample stands for: halfway to its neighbours, the first and last ending at the first and
    last sample; the model's jump-off is resolved inside it), `segment` (index into
    :data:`SEGMENTS`), `index` (sample index in the curve as
    given), `contact` (1 where the data are in contact: indentation > 0 before the measured
    jump-off, or $|F| > 3\sigma$), `noise` [N] (per sample: the curve's noise, larger at the
    measured jump-off), `sigma` [N] (the curve's noise), `depth` [m] (relaxed depth, or
    largest indentation), `detaches` (1: the force jumps back to the baseline after its most
    tensile value), `stiffness` [N/m] (compliant loading; 1 otherwise), `profile`.
    """

    ts: Float[Array, "C n"]
    drive: Float[Array, "C n"]
    indentation: Float[Array, "C n"]
    force: Float[Array, "C n"]
    valid: Float[Array, "C n"]
    weight: Float[Array, "C n"]
    lower: Float[Array, "C n"]
    upper: Float[Array, "C n"]
    segment: Int[Array, "C n"]
    index: Int[Array, "C n"]
    contact: Float[Array, "C n"]
    noise: Float[Array, "C n"]
    sigma: Float[Array, " C"]
    depth: Float[Array, " C"]
    detaches: Float[Array, " C"]
    stiffness: Float[Array, " C"]
    profile: jc.AbstractProfile

    @property
    def n_curves(self) -> int:
        return self.ts.shape[0]

    @property
    def n_samples(self) -> int:
        """Number of kept samples (all curves)."""
        return int(np.sum(np.asarray(self.valid) > 0))

    @property
    def n_measured(self) -> int:
        """Number of measured samples the kept ones stand for (all curves)."""
        return int(round(float(np.sum(np.asarray(self.weight)))))

    @property
    def n_effective(self) -> float:
        r"""Kish's effective number of samples, $(\sum_i w_i)^2 / \sum_i w_i^2$ over the kept
        samples' weights: `n_measured` when every sample is kept, about the kept samples'
        number when each stands for many. A weighted $\chi^2 = \sum_i w_i r_i^2$ varies as
        much as a $\chi^2$ of that many samples, scaled by $\sum w^2/\sum w$: what model
        selection must count (:class:`fitting.ModelChoice`)."""
        w = np.asarray(self.weight, dtype=float).ravel()
        s2 = float(np.sum(w * w))
        return float(np.sum(w)) ** 2 / s2 if s2 > 0 else 0.0


def curve_noise(curve: Curve, spec) -> float | None:
    """The noise the preprocessing found for `curve` [N] (`None`: none found): the free
    force's scatter about its baseline (``ContactPoint.noise``), or, for a fit with a
    fitted force drift (``spec.force_drift``), its scatter about its straight line
    (``ContactPoint.trend_noise``: what is left once a line is fitted; a constant baseline's
    scatter counts the trend as noise)."""
    cp = curve.contact
    if cp is None:
        return None
    if spec.force_drift and math.isfinite(cp.trend_noise) and cp.trend_noise > 0:
        return float(cp.trend_noise)
    return cp.noise


def noise_level(force: np.ndarray, baseline_noise: float | None) -> float:
    """$\\sigma$ [N] of a curve (see the module docstring)."""
    # (the array methods and differences by slicing: the same numbers as np.ptp and
    # np.diff, without their per-call overhead: this runs twice per curve of a map)
    frange = float(force.max() - force.min()) if force.size > 1 else abs(float(force[0]))
    floor = 1e-6 * max(frange, 1e-300)
    if baseline_noise is not None and baseline_noise > 0:
        return max(float(baseline_noise), floor)
    est = 0.0
    if force.size >= 5:
        step = force[1:] - force[:-1]
        est = 1.4826 * _median(np.abs(step[1:] - step[:-1])) / math.sqrt(6.0)
    return max(est, floor)


def _median(x: np.ndarray) -> float:
    """`np.median` of a non-empty 1-D array, the same number (the middle sample, or the mean
    of the two middle ones computed as `np.mean` does: their sum halved; NaN if any), in a
    sort instead of `np.median`'s general machinery (per curve, twice: ~5x faster)."""
    s = np.sort(x)
    m = s.size // 2
    if s.size and s[-1] != s[-1]:  # NaN (sorted last)
        return math.nan
    return float(s[m]) if s.size % 2 else float((s[m - 1] + s[m]) / 2.0)


#: A retract force below ``-TENSILE_SIGMA`` noise levels is tensile: adhesion the data show
#: (:func:`_jump_index`, :func:`retract_end`).
TENSILE_SIGMA = 3.0


def _jump_index(f: np.ndarray, sigma: float) -> int | None:
    """Index of the first sample after the measured jump-off in `f` (a retract), or None.

    The jump-off is the largest rise of the force between two samples after its most
    tensile value, when that rise exceeds $5\\sigma$ and brings the force at least half way
    back to 0.
    """
    if f.size < 3:
        return None
    i_min = int(f.argmin())
    if f[i_min] > -TENSILE_SIGMA * sigma or i_min >= f.size - 1:
        return None
    rise = f[i_min + 1:] - f[i_min:-1]
    j = int(rise.argmax())
    if rise[j] < 5.0 * sigma or f[i_min + j + 1] < 0.5 * f[i_min]:
        return None
    return i_min + j + 1


def retract_end(f: np.ndarray, sigma: float, weight=None, *, jumps: bool | None = None
                ) -> str:
    r"""How the retract forces `f` (baselined, in order; `weight`: the measured samples each
    stands for, default 1) end: ``"jump-off"`` (a sharp return to the baseline after the
    most tensile value: :func:`_jump_index`, or `jumps` when given), ``"no adhesion"``
    (never below $-3\sigma$), ``"held"`` (no jump-off, and the last tenth of the retract,
    at least 3 samples, still below $-3\sigma$ on average: the lift ended before the
    contact let go) or ``"gradual"`` (no jump-off, back to the baseline by the end: a slow
    peel, tethers); ``"no retract"`` when `f` is empty."""
    f = np.asarray(f, dtype=float)
    if f.size == 0:
        return "no retract"
    if jumps if jumps is not None else _jump_index(f, sigma) is not None:
        return "jump-off"
    if float(f.min()) > -TENSILE_SIGMA * sigma:
        return "no adhesion"
    k = max(3, f.size // 10)
    w = np.ones(f.size) if weight is None else np.asarray(weight, dtype=float)
    tail = float(np.sum(w[-k:] * f[-k:]) / max(float(np.sum(w[-k:])), 1e-300))
    return "held" if tail < -TENSILE_SIGMA * sigma else "gradual"


def retract_ends(data: CurveBatch) -> list[str]:
    """:func:`retract_end` of every curve of `data` over its kept retract samples, each
    weighted by the measured samples it stands for; whether it jumps off is the
    preparation's (`detaches`, found on all measured samples)."""
    f, seg, valid, w, sig, jumps = (np.asarray(x) for x in (
        data.force, data.segment, data.valid, data.weight, data.sigma, data.detaches))
    out = []
    for c in range(f.shape[0]):
        m = (valid[c] > 0) & (seg[c] == SEGMENTS.index("retract")) & (w[c] > 0)
        out.append(retract_end(f[c, m], float(sig[c]), w[c, m], jumps=bool(jumps[c] > 0)))
    return out


def select_samples(f, segment, budget: int, keep=()) -> np.ndarray:
    """Indices of at most about `budget` samples of a curve with forces `f` (sorted; see
    the module docstring).

    `keep`: indices that must be kept (plus the first and last sample of every segment).
    Returns all indices when the curve has no more than `budget` samples.
    """
    n = len(f)
    if n <= budget:
        return np.arange(n)
    seg = np.asarray(segment)
    starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    ends = np.r_[starts[1:] - 1, n - 1]
    required = np.unique(np.clip(np.r_[starts, ends, np.asarray(keep, dtype=int)], 0, n - 1))
    rest = max(budget - required.size, 2)
    # smoothed, normalised force: a moving average over the samples one kept sample stands for
    w = max(1, n // rest)
    c = np.cumsum(np.r_[0.0, f])
    lo = np.clip(np.arange(n) - w // 2, 0, n)
    hi = np.clip(lo + w, 0, n)
    fs = (c[hi] - c[lo]) / (hi - lo)
    frange = float(np.ptp(fs)) or 1.0
    arc = np.r_[0.0, np.cumsum(np.abs(np.diff(fs)))] / frange
    arc = arc / arc[-1] if arc[-1] > 0 else np.zeros(n)
    coord = 0.5 * np.arange(n) / max(n - 1, 1) + 0.5 * arc
    picks = np.searchsorted(coord, np.linspace(0.0, coord[-1], rest))
    return np.unique(np.r_[required, np.clip(picks, 0, n - 1)])


def sample_weights(pick: np.ndarray, n: int) -> np.ndarray:
    """Number of the `n` measured samples nearest (by index) to each kept index `pick`."""
    pick = np.asarray(pick)
    if pick.size == 1:
        return np.array([float(n)])
    if pick.size == n:  # every sample kept (`select_samples` within its budget): one each
        return np.ones(n)
    edges = np.concatenate(([0], (pick[:-1] + pick[1:]) // 2 + 1, [n]))
    return np.diff(edges).astype(float)


def _intervals(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Halfway points to the neighbours; the first interval starts at the first sample and
    the last ends at the last sample.

    The forward models are simulated on $[t_0, t_\mathrm{end}]$ only, so a jump-off can be
    resolved there only: with the last interval ending at $t_\mathrm{end}$ the effective
    force of the last sample tends to the attached force as the model's jump-off time tends
    to $t_\mathrm{end}$, i.e. the loss is continuous where the jump-off leaves the simulated
    range (a last interval mirrored beyond $t_\mathrm{end}$ made it jump there by half of the
    last sample's force: a spurious minimum of the loss at that edge)."""
    if t.size == 1:
        return t - 0.5, t + 0.5
    mid = 0.5 * (t[1:] + t[:-1])
    lower = np.concatenate((t[:1], mid))
    upper = np.concatenate((mid, t[-1:]))
    return lower, upper


def _select(curve: Curve, spec: ModelSpec, n: int) -> tuple[Curve, np.ndarray]:
    """The samples the model uses (see the module docstring) and their indices in `curve`."""
    names = curve.segment_names
    if spec.model == "relaxed":
        if "retract" in names:
            # the lift starts at the deepest sample up to the first retract sample (an
            # inferred one-sample "approach" at the top of a pure lift is kept); the
            # segment indices never decrease (`Curve`): the first retract sample by bisection
            first = int(np.searchsorted(curve.segment, names.index("retract")))
            head = curve.displacement[: first + 1]
            i0 = int(len(head) - 1 - np.argmax(head[::-1]))
        else:
            i0 = 0
        index = np.arange(i0, len(curve))
        return np.full(index.size, SEGMENTS.index("retract")), index
    if "approach" not in names:
        raise ValueError(f"curve {n} ({curve.source or 'no source'}): the history model "
                         f"needs an approach segment (the contact's history); its "
                         f"segments are {names}; for a retract alone use "
                         "model='relaxed'")
    # each segment's code in SEGMENTS (-1: not used, a rest)
    code = np.array([SEGMENTS.index(s) if s in SEGMENTS else -1 for s in names])[curve.segment]
    index = np.flatnonzero(code >= 0)
    return code[index], index


def prepare_curves(
    curves: Curve | Sequence[Curve],
    spec: ModelSpec,
    *,
    radius: float | None = None,
    profile: jc.AbstractProfile | None = None,
    spring_constant: float | Sequence[float] | None = None,
    max_samples: int | None = None,
    indentation_range: tuple[float, float] | None = None,
    host: bool = False,
) -> CurveBatch:
    """Select and subsample the samples, estimate the noise, pad into a `CurveBatch`.

    `max_samples`: largest number of samples per curve (default
    :data:`DEFAULT_MAX_SAMPLES` of the model; see :func:`select_samples`).
    `spring_constant`: one value or one per curve, for ``spec.compliant`` (default: the
    curves' own). `indentation_range`: ``(low, high)`` [m] (like nanite's ``range_x``):
    only samples whose indentation lies in it are residuals (the others keep weight 0:
    the model still runs through the whole history, and they are shown, not fitted);
    None: every selected sample. `host`: keep the arrays in numpy (for batches stacked
    later, e.g. by :func:`fitting.fit_each`: one transfer to the device per chunk).
    """
    rng = check_indentation_range(indentation_range)
    if isinstance(curves, Curve):
        curves = [curves]
    curves = list(curves)
    if not curves:
        raise ValueError("curves: give at least one curve")
    if profile is None:
        if radius is None or not (math.isfinite(float(radius)) and float(radius) > 0):
            raise ValueError(f"radius must be finite and > 0 [m]; got {plain(radius)}")
        profile = jc.Parabola(float(radius))
    _check_profile(profile)
    budget = DEFAULT_MAX_SAMPLES[spec.model] if max_samples is None else int(max_samples)
    if budget < 4:
        raise ValueError(f"max_samples must be an integer >= 4; got {plain(max_samples)}")
    if spring_constant is None or np.ndim(spring_constant) == 0:
        ks = [spring_constant] * len(curves)
    else:
        ks = list(spring_constant)
        if len(ks) != len(curves):
            raise ValueError("spring_constant: give one value or one per curve")
    model, compliant = spec.model, spec.compliant
    retract = SEGMENTS.index("retract")
    rows = []
    for n, c in enumerate(curves):
        seg, idx = _select(c, spec, n)
        t_all, d_all, f_all = c.time[idx], c.displacement[idx], c.force[idx]
        idx_all = idx
        if len(idx) < 2:
            raise ValueError(f"curve {n} ({c.source or 'no source'}): fewer than 2 samples "
                             f"in the segments the {model} model uses")
        noise = curve_noise(c, spec)
        # the retract samples (the relaxed model's are all retract)
        ret = None if model == "relaxed" else seg == retract
        f_ret = f_all if ret is None else (f_all[ret] if ret.any() else None)
        sigma = noise_level(f_all if f_ret is None else f_ret, noise)
        j_ret = None if f_ret is None else _jump_index(f_ret, sigma)
        keep = []
        if j_ret is not None:
            j = j_ret if ret is None else int(np.flatnonzero(ret)[j_ret])
            keep += list(range(j - 3, j + 3))
        if model == "history":
            app = np.flatnonzero(seg == SEGMENTS.index("approach"))
            if app.size:
                c0 = app[int(np.argmax(d_all[app] > 0))]
                keep += list(range(c0 - 2, c0 + 3))
        pick = select_samples(f_all, seg, budget, keep)
        weight = sample_weights(pick, len(t_all))
        subsampled = len(pick) < len(t_all)  # else every sample, as selected
        if subsampled:
            t, d, f, seg, idx = t_all[pick], d_all[pick], f_all[pick], seg[pick], idx[pick]
        else:
            t, d, f = t_all, d_all, f_all
        t = t - t[0]
        label = f"curve {n} ({c.source or 'no source'})"
        if rng is not None:
            inside = (d >= rng[0]) & (d <= rng[1])
            if not inside.any():
                raise ValueError(
                    f"{label}: no sample with indentation in indentation_range "
                    f"[{rng[0]:g}, {rng[1]:g}] m (its indentation spans [{float(d_all.min()):g}, "
                    f"{float(d_all.max()):g}] m)")
            weight = np.where(inside, weight, 0.0)
        jc.check_plausible(f"{label}: displacement", d_all, "length", magnitude=True)
        jc.check_plausible(f"{label}: duration", t_all[-1] - t_all[0], "time")
        k = ks[n]
        if compliant:
            k = k if k is not None else c.spring_constant
            if k is None or not (math.isfinite(float(k)) and float(k) > 0):
                raise ValueError(f"curve {n}: compliant loading needs a spring constant "
                                 f"> 0 [N/m]; got {plain(k)}")
            jc.check_plausible(f"{label}: spring_constant", float(k), "stiffness")
        if model == "relaxed":
            depth = float(d[0])
            if depth <= 0:
                raise ValueError(f"curve {n}: the retract starts at indentation {depth:g} m "
                                 "<= 0; the relaxed model needs a positive start depth")
            drive = np.minimum(d, depth)
        else:
            depth = float(d.max())
            if depth <= 0:
                raise ValueError(f"curve {n} ({c.source or 'no source'}): the indentation "
                                 "never becomes positive; no contact to fit")
            drive = d + f / float(k) if compliant else d
        lower, upper = _intervals(t)
        noise_s = np.full(len(t), sigma)
        in_contact = d > 0  # before the measured jump-off, or |F| > 3 sigma
        if j_ret is not None:
            if subsampled:
                j = int(np.searchsorted(idx, idx_all[j]))  # first detached, after subsampling
            jump = float(f[j] - f[j - 1])
            noise_s[j - 1:j + 1] = math.sqrt(sigma**2 + jump**2 / 12.0)
            in_contact[j:] = False
        contact = in_contact | (np.abs(f) > 3.0 * sigma)
        rows.append(dict(
            ts=t, drive=drive, indentation=d, force=f, lower=lower, upper=upper,
            segment=seg, index=idx, contact=contact.astype(float), noise=noise_s,
            weight=weight, sigma=sigma, depth=depth,
            detaches=float(j_ret is not None),
            stiffness=float(k) if compliant else 1.0,
        ))
    n_max = max(len(r["ts"]) for r in rows)
    if any(len(c) > budget for c in curves):
        # subsampled: pad to the budget, so curves of any length share one shape (and one
        # compilation of the fit)
        n_max = max(n_max, budget)
    return _stack_rows(rows, n_max, profile, host)


_CHECKED: dict[int, jc.AbstractProfile] = {}


def _check_profile(profile) -> None:
    """The probe's parameters against the forward model's domain and unit plausibility
    (eager `ValueError` naming the parameter; the traced model does not check them). A few
    ms of eager operations: done once per profile object (a map shares one)."""
    if _CHECKED.get(id(profile)) is profile:
        return
    jc.profile_radius(profile, 1e-9)
    if len(_CHECKED) > 16:
        _CHECKED.clear()
    _CHECKED[id(profile)] = profile  # held, so that its id is not reused


_ROW_KEYS = ("ts", "drive", "indentation", "force", "lower", "upper", "segment", "index",
             "contact", "noise", "weight")
_CURVE_KEYS = ("sigma", "depth", "detaches", "stiffness")
_FLOAT_KEYS = tuple(k for k in _ROW_KEYS if k not in ("segment", "index"))


def _stack_rows(rows, n_max: int, profile, host: bool = False) -> CurveBatch:
    """A `CurveBatch` of per-curve rows (dicts of sample arrays and scalars), every curve
    padded to `n_max` samples: the last sample repeated with weight 0, not valid, not in
    contact, with a zero-width interval. `host`: numpy arrays, else on the device."""
    lengths = [len(r["ts"]) for r in rows]
    row = rows[0]
    if len(rows) == 1 and lengths[0] == n_max and all(
            getattr(row[key], "dtype", None) == np.float64 for key in _FLOAT_KEYS):
        # one curve (a map's), nothing to pad: the float rows copied in one call, each field
        # a row of that block (fewer numpy calls per curve; the same arrays)
        block = np.array([row[key] for key in _FLOAT_KEYS])
        arrays = {key: block[i:i + 1] for i, key in enumerate(_FLOAT_KEYS)}
        arrays.update({key: np.array(row[key])[None] for key in ("segment", "index")})
        valid = np.ones((1, n_max))
    else:
        arrays = {}
        for key in _ROW_KEYS:  # each row written into its place (no padded copy, no stack)
            parts = [np.asarray(r[key]) for r in rows]
            out = np.empty((len(rows), n_max), dtype=np.result_type(*[a.dtype for a in parts]))
            for i, (a, m) in enumerate(zip(parts, lengths, strict=True)):
                out[i, :m] = a
                out[i, m:] = a[-1]
            arrays[key] = out
        valid = np.zeros((len(rows), n_max))
        for i, m in enumerate(lengths):
            valid[i, :m] = 1.0
            if m < n_max:
                arrays["weight"][i, m:] = 0.0
                arrays["contact"][i, m:] = 0.0
                arrays["lower"][i, m:] = arrays["ts"][i, m:]
                arrays["upper"][i, m:] = arrays["ts"][i, m:]
    scal = {key: np.array([r[key] for r in rows], dtype=float) for key in _CURVE_KEYS}
    arrays = dict(arrays, valid=valid, **scal)
    if not host:  # one transfer of all arrays (not one `jnp.asarray` dispatch each)
        arrays = jax.device_put(arrays)
    arrays["profile"] = profile
    # built without equinox's `__init__` (per curve of a map; `fitting._host`)
    return rebuild(lambda v: CurveBatch(**v), arrays, key="CurveBatch")


def stack_batches(batches: Sequence[CurveBatch], length: int | None = None, *,
                  host: bool = False) -> CurveBatch:
    """One `CurveBatch` of the curves of `batches` (same profile), padded to a common
    number of samples: the longest one, or `length` if that is larger (the shape of a
    compiled fit). `host`: numpy arrays, else on the device."""
    batches = list(batches)
    if not batches:
        raise ValueError("batches: give at least one CurveBatch")
    rows = []
    for b in batches:
        arr = jax.device_get({k: getattr(b, k) for k in _ROW_KEYS + _CURVE_KEYS + ("valid",)})
        for c in range(b.n_curves):
            m = int(np.sum(arr["valid"][c] > 0))
            rows.append({**{k: arr[k][c, :m] for k in _ROW_KEYS},
                         **{k: float(arr[k][c]) for k in _CURVE_KEYS}})
    n_max = max([len(r["ts"]) for r in rows] + [int(length or 0)])
    return _stack_rows(rows, n_max, batches[0].profile, host)
