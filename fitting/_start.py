r"""Scales of the data, the initial guess, default bounds and the starts of the global search.

Data scales (:func:`data_scales`)
---------------------------------
* $G_H$: the relaxed modulus of the force at the deepest point of the retract,
  $F = 8G(a d - \int_0^a g)$ with $g(a) = d$ (Hertz for a parabola, $F = \tfrac{16}{3}G
  \sqrt R d^{3/2}$).
* $G_g$: the glass modulus of the first unloading slope $\mathrm dF/\mathrm dd = 8G_0a$
  (least-squares line over the first 5 % of the retract, at least 4 samples), and of the
  force at the start of a hold, whichever is larger; at least $1.5\,G_H$.
* $\tau$: from the hold (time to relax by $1 - 1/e$ of the force drop) if there is one,
  else a fifth of the lift duration. Time scales of the data: $\tau_\min$ = two sampling
  intervals, $\tau_\max$ = ten times the duration $T$ (of the longest curve).
* $\Delta\gamma$: JKR with $\Delta\gamma_\mathrm{eff} = \Delta\gamma\,G_g/G_H$ (the paper's
  slow limit): $\Delta\gamma = |F_\min|\,G_H/(1.5\pi R\,G_g)$ (the profile's radius at the
  depth for other profiles), with $|F_\min|$ at least $10^{-3}$ of the force range.
* the largest indentation $d_\max$ and the force range (scales of the two offsets).

Several curves: geometric means (scales) and extremes (time ranges). An approach-only
curve (``segments=("approach",)``) is read backwards from its deepest sample in place of a
retract.

Default bounds (:func:`default_bounds`) keep a fit from running off to $10^{-168}$ Pa:
moduli in $[10^{-6}, 10^6]\,G_H$, viscosities in $[10^{-6}G_H\tau_\min,
10^6G_H\tau_\max]$, the relaxation times of a Prony series in $[\tau_\min, T]$ (what the
curve resolves, :attr:`DataScales.tau_resolved`: an arm that relaxes more slowly than the
curve lasts changes by $G_k(1 - e^{-t/\tau_k}) \approx G_k t/\tau_k$ over it, a spring
beside $G_\infty$ and a slight drift, so $G_\infty$, $G_k$ and $\tau_k$ are not
determined apart; a fit that allowed $\tau_k$ up to $10T$ crawled along the valley
$G_\infty \leftrightarrow G_k$ to its step limit, ``benchmarks/results/prony_convergence.md``;
a nested fit widens it to contain the simpler model's relaxation times, see
:func:`nested_starts`), $\Delta\gamma$ in
$[10^{-6}, 10^{6}]$ times its estimate, the contact offset in $[-d_\max, d_\max/2]$, the
force offset within ± the force range, the force drift within ± twice the force range over
the curves' duration. A parameter the data push to a bound is reported
at that bound (no standard error).

Starts (:func:`search_starts`)
------------------------------
A Latin hypercube (the best of 20 designs by the smallest distance between points, fixed
seed: the same data give the same starts) over physically bounded ranges: $G_\infty$
over $\pm 2$ decades around $G_H$, the glass-to-relaxed ratio $G_g/G_\infty$ in
$[1.02, 100]$, relaxation times from $\tau_\min$ to the duration, $\Delta\gamma$ over 3
decades around its estimate, the contact offset within $\pm d_\max/4$ of the detection,
the force offset within ±5 % of the force range, the force drift 0 (a linear nuisance the
steps find at once). Start 0 is the data-based guess
(:func:`initial_guess`) with the user's initial values.

Local rounds (:func:`local_starts`): after the global search, further rounds of as many
starts begin at the best end point (a run stopped by the step limit continues), at
*pattern moves* $z_b + k(z_b - z_j)$, $k \in \{0.5, 1, 2, 4\}$, on from each of the
next two distinct optima $z_j$ through the best one $z_b$ (free vectors), and at a Latin
hypercube around the best of $\pm 0.2$ in the logarithm of each positive parameter and
$\pm 0.02$ of the scale of each offset. Why: the loss of a real curve has ladders of
shallow local minima close together, a few per cent apart in $\chi^2$ (the model's
jump-off resolved inside one sample interval gives each interval its own optimum of the
contact offset and $\Delta\gamma$; on the shipped oocyte curve 6 distinct optima among
64 starts, $\chi^2$ falling monotonically along the ladder). Random restarts around the
best optimum rarely leave its rung; a pattern move steps along the ladder.
A round that does not lower $\chi^2$ is followed by a wider one (:class:`LocalRounds`:
hypercube half-widths 0.2, then 0.5, then 1.25 in the logarithm, no pattern moves), and
the rounds stop after the widest one brings nothing (or after `local_rounds` rounds): on
a held-out JPK force-distance curve the next rung lay 0.27 away in $\log\Delta\gamma$,
outside the first box.

Nested models (:func:`nested_starts`): ``prony:N`` starts from the ``prony:N-1`` (or
standard-model) optimum with one arm added: as each existing arm split in two equal arms
at its own relaxation time (the same relaxation function, so the same loss: a descent from
there never ends above the simpler fit; a simpler model's relaxation time outside the
default bounds of the relaxation times, beyond the curve's duration or below two sampling
intervals, widens them to contain it, ``fitting._optimise._contain``), and as an arm of
modulus $10^{-3}G_\infty$, or just inside the lower bound of the moduli, at each of several
relaxation times (between and beyond the existing ones), from which a second relaxation
time can grow.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence

import numpy as np

import jaxcontact as jc

from ._curve import Curve
from ._host import once_per_object
from ._parameters import free_to_internal, internal_to_free
from ._spec import ModelSpec, n_model_inputs, parameter_info, rheology_kind, rheology_name

__all__ = ["DataScales", "data_scales", "initial_guess", "default_bounds", "search_starts",
           "search_points",
           "nested_starts", "local_starts", "local_starts_batch", "LocalRounds",
           "latin_hypercube",
           "to_prony", "from_physical"]


@dataclasses.dataclass(frozen=True)
class DataScales:
    """Scales of the data (SI; see the module docstring)."""

    g_relaxed: float
    g_glass: float
    tau: float
    tau_min: float
    tau_max: float
    duration: float
    work_of_adhesion: float
    depth: float
    force_range: float

    @property
    def tau_resolved(self) -> float:
        r"""The longest relaxation time the curves resolve [s]: their duration $T$ (at
        least $2\tau_\min$); the upper bound of a Prony series' relaxation times."""
        return max(self.duration, 2.0 * self.tau_min)


def _hertz_modulus(force: float, depth: float, profile) -> tuple[float, float]:
    """G from F = 8 G (a d - I(a)) with g(a) = d; returns (G, a)."""
    if isinstance(profile, jc.Parabola):
        # plain floats: the general path dispatches a few eager JAX operations
        R = _radius(profile)
        a = math.sqrt(R * depth)
        integral = a**3 / (3.0 * R)
    else:
        a = float(jc.profile_radius(profile, depth))
        integral = float(profile.integral_g(a))
    lever = 8.0 * (a * depth - integral)
    return abs(force) / max(lever, 1e-300), a


@once_per_object
def _radius(profile) -> float:
    """`float(profile.R)` of a parabola or sphere, read from the device once per profile
    object (a map shares one; each read is a transfer, ~10 µs)."""
    return float(profile.R)


def probe_radius(profile) -> float | None:
    """The radius of curvature [m] of a paraboloid or sphere profile (read from the device
    once per profile object), `None` for the other profiles."""
    return _radius(profile) if isinstance(profile, jc.Parabola | jc.Sphere) else None


def _gm(x) -> float:
    return float(np.exp(np.mean(np.log(np.asarray(x, dtype=float)))))


def data_scales(curves: Sequence[Curve], spec: ModelSpec, profile) -> DataScales:
    """:class:`DataScales` of the curves (see the module docstring)."""
    gi, g0, tau, dg, tmin, tmax, dur, dmax, frng = ([] for _ in range(9))
    for c in curves:
        names = c.segment_names
        # the retract: one block of samples (segment indices never decrease, `Curve`)
        j = names.index("retract") if "retract" in names else None
        r = slice(None) if j is None else slice(*np.searchsorted(c.segment, [j, j + 1]).tolist())
        t, d, f = c.time[r], c.displacement[r], c.force[r]
        if "retract" not in names and spec.model == "history":
            # an approach-only fit: the approach read backwards from its deepest sample
            i = int(np.argmax(d))
            t, d, f = t[: i + 1], d[i::-1], f[i::-1]
        # (array methods, not the np functions: the same numbers without their per-call
        # overhead; this runs per curve of a map)
        if spec.model == "relaxed":
            depth = float(d[0])
        else:
            depth = float(d[: max(1, len(d) // 20)].max())
        if not depth > 0 or len(d) < 2:
            continue
        g_h, a0 = _hertz_modulus(float(f[: max(1, len(f) // 20)].max()), depth, profile)
        m = max(4, len(d) // 20)
        dd = d[:m] - d[0]
        slope = float(np.dot(dd, f[:m] - f[0]) / max(float(np.dot(dd, dd)), 1e-300))
        g0_est = max(slope / (8.0 * a0), 1.5 * g_h)
        tau_est = 0.2 * float(t[-1] - t[0])
        if "hold" in names:
            h = c.segment == names.index("hold")
            th, fh = c.time[h] - c.time[h][0], c.force[h]
            if len(fh) > 10 and fh[0] > fh[-1]:
                target = fh[-1] + (fh[0] - fh[-1]) / math.e
                k = int(np.argmax(fh <= target))
                tau_est = max(float(th[k]), float(th[1]))
                g0_est = max(g0_est, _hertz_modulus(float(fh[0]),
                                                    float(np.max(c.displacement[h])),
                                                    profile)[0])
        rad = probe_radius(profile)
        rad = a0 * a0 / depth if rad is None else rad
        fmin = float(f.min())
        force_range = float(c.force.max() - c.force.min())  # np.ptp
        dg.append(max(abs(fmin), 1e-3 * force_range) * g_h
                  / (1.5 * math.pi * rad * g0_est))
        gi.append(g_h)
        g0.append(g0_est)
        tau.append(max(tau_est, 1e-300))
        steps = c.time[1:] - c.time[:-1]
        steps = steps[steps > 0]
        tmin.append(2.0 * float(steps.min()) if steps.size else 1e-6)
        dur.append(float(c.time[-1] - c.time[0]))
        dmax.append(float(c.displacement.max()))
        frng.append(force_range)
    if not gi:
        raise ValueError("initial guess: no curve with a positive indentation at the start "
                         "of its retract (is the contact point right?)")
    duration = max(dur)
    if len(gi) == 1:  # one curve (a map's): the geometric means of one value, in one call
        means = [float(v) for v in np.exp(np.log(np.array([gi[0], g0[0], tau[0], dg[0]])))]
    else:
        means = [_gm(gi), _gm(g0), _gm(tau), _gm(dg)]
    return DataScales(
        g_relaxed=means[0], g_glass=means[1], tau=means[2], tau_min=min(tmin),
        tau_max=10.0 * duration, duration=duration, work_of_adhesion=means[3],
        depth=max(dmax), force_range=max(frng),
    )


def from_physical(spec: ModelSpec, g_inf: float, g_glass: float, taus, weights,
                  work: float, delta: float = 0.0, f0: float = 0.0) -> dict[str, float]:
    """Natural parameters of `spec` from relaxed and glass moduli, relaxation times and the
    share of each arm in $G_g - G_\\infty$ (`weights`, summing to 1)."""
    g_glass = np.maximum(g_glass, 1.0001 * g_inf)
    if np.ndim(g_glass) == 0:
        g_glass = float(g_glass)
    out = rheology_kind(spec).from_moduli(g_inf, g_glass, taus, weights, spec.arms)
    out["work_of_adhesion"] = work
    if spec.contact_offset:
        out["contact_offset"] = delta
    if spec.force_offset:
        out["force_offset"] = f0
    if spec.force_drift:  # a linear nuisance: every start at no drift
        out["force_drift"] = 0.0
    return out


def initial_guess(curves: Sequence[Curve], spec: ModelSpec, profile,
                  scales: DataScales | None = None) -> dict[str, float]:
    """The data-based initial guess (natural units; see the module docstring)."""
    s = data_scales(curves, spec, profile) if scales is None else scales
    n = spec.arms
    taus = s.tau * np.logspace(-1, 1, n) if n > 1 else [s.tau]
    if any(kind == "time" for _, _, kind in parameter_info(spec)):
        # relaxation times as parameters: inside their bounds (`default_bounds`), not at them
        lo, hi = math.log(s.tau_min), math.log(s.tau_resolved)
        taus = np.exp(np.clip(np.log(taus), lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo)))
    return from_physical(spec, s.g_relaxed, s.g_glass, taus, np.full(n, 1.0 / max(n, 1)),
                         s.work_of_adhesion)


def default_bounds(spec: ModelSpec, s: DataScales) -> dict[str, tuple[float, float]]:
    """Default bounds of every parameter (natural units; see the module docstring)."""
    g = s.g_relaxed
    out = {}
    for name, _, kind in parameter_info(spec):
        if kind == "modulus":
            out[name] = (1e-6 * g, 1e6 * g)
        elif kind == "viscosity":
            out[name] = (1e-6 * g * s.tau_min, 1e6 * g * s.tau_max)
        elif kind == "time":
            out[name] = (s.tau_min, s.tau_resolved)
        elif kind == "adhesion":
            out[name] = (1e-6 * s.work_of_adhesion, 1e6 * s.work_of_adhesion)
        elif kind == "offset_length":
            out[name] = (-s.depth, 0.5 * s.depth)
        elif kind == "offset_force_rate":  # at most twice the force range over the curve
            out[name] = (-2.0 * s.force_range / s.duration, 2.0 * s.force_range / s.duration)
        else:
            out[name] = (-s.force_range, s.force_range)
    return out


def latin_hypercube(n: int, dim: int, *, seed: int = 0, designs: int = 20) -> np.ndarray:
    """`n` points in $[0, 1)^\\mathrm{dim}$: the best of `designs` Latin hypercubes by the
    smallest distance between two points (deterministic for a given seed; computed once
    per arguments: every curve of a map draws the same design, a new array each call)."""
    return _latin_hypercube(int(n), int(dim), int(seed), int(designs)).copy()


@functools.lru_cache(maxsize=64)
def _latin_hypercube(n: int, dim: int, seed: int, designs: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    k = max(1, designs)
    # the random numbers in the order of one design after the other (a permutation key of
    # shape (dim, n), then a jitter of shape (n, dim)), all drawn at once
    draws = rng.random(k * 2 * dim * n).reshape(k, 2, dim * n)
    keys = draws[:, 0].reshape(k, dim, n)
    jitter = draws[:, 1].reshape(k, n, dim)
    u = (np.swapaxes(np.argsort(keys, axis=2), 1, 2) + jitter) / n
    if n < 2 or k == 1:  # nothing to choose (a screen's one design: no n^2 distances)
        return u[0]
    diff = u[:, :, None, :] - u[:, None, :, :]
    dist = np.sqrt(np.sum(diff * diff, axis=-1))
    iu = np.triu_indices(n, 1)
    d = np.min(dist[:, iu[0], iu[1]], axis=1)
    return u[int(np.argmax(d))]  # the first of equally good designs


#: Half-widths of the local rounds: in the logarithm of positive parameters, and in units
#: of the scale of the offsets.
LOCAL_LOG_WIDTH, LOCAL_LINEAR_WIDTH = 0.2, 0.02

#: A round that does not lower chi2 is followed by one whose hypercube is this many times
#: wider (no pattern moves: they were tried), up to :data:`LOCAL_MAX_WIDEN` times the
#: first: half-widths 0.2, 0.5, 1.25 in the logarithm.
LOCAL_WIDEN, LOCAL_MAX_WIDEN = 2.5, 6.25

#: Steps of the pattern moves of the local rounds (multiples of the difference between
#: the best and a next-best optimum).
PATTERN_STEPS = (0.5, 1.0, 2.0, 4.0)


@dataclasses.dataclass
class LocalRounds:
    r"""The schedule of the local rounds of one problem: after a round that does not lower
    $\chi^2$ the next is :data:`LOCAL_WIDEN` times wider; after one at
    :data:`LOCAL_MAX_WIDEN` without a decrease the rounds are `done`."""

    widen: float = 1.0
    done: bool = False

    def update(self, improved: bool) -> None:
        """Account for a round that did (not) lower the loss."""
        if improved:
            return
        if self.widen >= LOCAL_MAX_WIDEN:
            self.done = True
        else:
            self.widen *= LOCAL_WIDEN


def local_starts(param, z_end: np.ndarray, chi2: np.ndarray, n: int, *, seed: int = 0,
                 widen: float = 1.0) -> np.ndarray:
    """`n` starts (free vectors, shape `(n, k)`) of a local round around the best distinct
    end points `z_end` (rows) of a search with losses `chi2` (see the module docstring).
    `param`: the :class:`fitting.Parameterisation`; `widen`: the hypercube's half-widths
    in units of :data:`LOCAL_LOG_WIDTH` / :data:`LOCAL_LINEAR_WIDTH` (above 1: a widened
    round, without the pattern moves). The one-problem case of :func:`local_starts_batch`."""
    return local_starts_batch([param], np.asarray(z_end, dtype=float)[None],
                              np.asarray(chi2, dtype=float)[None], n, seed=seed,
                              widen=[widen])[0]


def local_starts_batch(params, z_end: np.ndarray, chi2: np.ndarray, n: int, *,
                       seed: int = 0, widen) -> np.ndarray:
    """:func:`local_starts` of `P` problems at once (the local rounds of a chunk of a force
    map: one pass of array operations instead of one per curve).

    `params`: `P` :class:`fitting.Parameterisation` of one structure (the same free
    parameters and log flags; their bounds and references may differ); `z_end`: end points,
    shape `(P, S, k)`; `chi2`: their losses, `(P, S)`; `widen`: `P` widths. Returns the
    starts, `(P, n, k)`; row `i` equals ``local_starts(params[i], z_end[i], chi2[i], n,
    seed=seed, widen=widen[i])``.
    """
    z_end = np.asarray(z_end, dtype=float)
    chi2 = np.asarray(chi2, dtype=float)
    widen = np.broadcast_to(np.asarray(widen, dtype=float), (len(params),))
    n_p, n_s, k = z_end.shape
    rows = np.arange(n_p)
    order = np.argsort(np.where(np.isfinite(chi2), chi2, np.inf), axis=1)
    # the best and the next two distinct end points (largest absolute difference of
    # free coordinates above 1e-3 from each taken), in the order of the losses
    far = np.max(np.abs(z_end[:, :, None, :] - z_end[:, None, :, :]), axis=-1) > 1e-3
    far_sorted = np.take_along_axis(far, order[:, None, :], axis=2)  # [p, j, rank]
    c0 = order[:, 0]
    ok1 = far_sorted[rows, c0]
    has1 = ok1.any(axis=1)
    c1 = order[rows, np.argmax(ok1, axis=1)]
    ok2 = ok1 & far_sorted[rows, c1] & has1[:, None]
    has2 = ok2.any(axis=1)
    c2 = order[rows, np.argmax(ok2, axis=1)]
    best = z_end[rows, c0]
    # pattern moves from the next-best optima through the best (not in a widened round)
    steps = np.asarray(PATTERN_STEPS)
    moves = [best[:, None, :] + steps[None, :, None] * (best - z_end[rows, c])[:, None, :]
             for c in (c1, c2)]
    pattern = np.where(widen == 1.0, has1.astype(int) + has2.astype(int), 0)
    # the hypercube around the best, in internal coordinates
    p0 = params[0]
    free = list(p0.free)
    lower = np.stack([np.asarray(q.lower, dtype=float) for q in params])[:, free]
    upper = np.stack([np.asarray(q.upper, dtype=float) for q in params])[:, free]
    reference = np.stack([np.asarray(q.reference, dtype=float) for q in params])[:, free]
    u0 = free_to_internal(np, best, lower, upper, reference)[-1]
    width = widen[:, None] * np.where(np.asarray(p0.log)[free], LOCAL_LOG_WIDTH,
                                      LOCAL_LINEAR_WIDTH)
    out = np.empty((n_p, n, k))
    for count in np.unique(pattern):  # problems with as many pattern moves share a design
        sel = pattern == count
        head = [best[sel][:, None]] + [moves[j][sel] for j in range(count)]
        head = np.concatenate(head, axis=1)[:, :n]
        m = n - head.shape[1]
        out[sel, :head.shape[1]] = head
        if m <= 0:
            continue
        design = latin_hypercube(m, k, seed=seed) * 2.0 - 1.0
        u = np.clip(u0[sel][:, None] + width[sel][:, None] * design[None],
                    lower[sel][:, None], upper[sel][:, None])
        out[sel, head.shape[1]:] = internal_to_free(u, lower[sel][:, None],
                                                    upper[sel][:, None],
                                                    reference[sel][:, None])
    return out


#: Up to this many points, the search's Latin hypercube is the best of 20 designs by the
#: smallest distance between points; beyond, a single design.
MAXIMIN_POINTS = 256


def search_points(spec: ModelSpec, s: DataScales, n: int, *, seed: int = 0
                  ) -> dict[str, np.ndarray]:
    """`n` points of the global search's Latin hypercube (see the module docstring), as
    arrays: `{name: values}` in natural units, each of shape `(n,)` (all at once: a
    screened search draws a thousand a curve, :func:`fitting._optimise.identify`)."""
    arms = spec.arms
    dim = 3 + arms + (arms - 1 if arms > 1 else 0) + 2
    # the best of 20 designs for a few starts; one design for a screen (the selection
    # compares all pairs of points of every design: 20 n^2 distances)
    u = (latin_hypercube(n, dim, seed=seed, designs=20 if n <= MAXIMIN_POINTS else 1)
         if n > 0 else np.zeros((0, dim)))

    # log-uniform coordinates, exp(log lo + (log hi - log lo) x), all columns in one pass:
    # G_inf, the glass-to-relaxed ratio, the work of adhesion, the relaxation times
    ranges = ([(1e-2 * s.g_relaxed, 1e2 * s.g_relaxed), (1.02, 100.0),
               (s.work_of_adhesion * 10**-1.5, s.work_of_adhesion * 10**1.5)]
              + [(s.tau_min, s.tau_resolved)] * arms)
    log_lo = np.array([math.log(lo) for lo, _ in ranges])
    log_span = np.array([math.log(hi) - math.log(lo) for lo, hi in ranges])
    logu = np.exp(log_lo + log_span * u[:, :3 + arms])
    g_inf, ratio, work = logu[:, 0], logu[:, 1], logu[:, 2]
    taus = np.sort(logu[:, 3:], axis=1).T
    if arms > 1:
        # arm shares from the remaining coordinates (sorted-uniform spacings)
        cuts = np.sort(u[:, 3 + arms:3 + 2 * arms - 1], axis=1)
        weights = np.diff(np.concatenate([np.zeros((len(u), 1)), cuts, np.ones((len(u), 1))],
                                         axis=1), axis=1)
        weights = np.maximum(weights, 1e-3)
        weights = (weights / weights.sum(axis=1, keepdims=True)).T
    else:
        weights = np.ones((max(arms, 1), len(u)))
    # the offsets' coordinates (only where the model has them: `from_physical` reads them
    # then only)
    delta = (u[:, -2] - 0.5) * 0.5 * s.depth if spec.contact_offset else 0.0
    f0 = (u[:, -1] - 0.5) * 0.1 * s.force_range if spec.force_offset else 0.0
    out = from_physical(spec, g_inf, g_inf * ratio, taus, weights, work, delta, f0)
    return {k: v if isinstance(v, np.ndarray) and v.shape == (len(u),) and v.dtype == float
            else np.broadcast_to(np.asarray(v, dtype=float), (len(u),)) for k, v in out.items()}


def search_starts(spec: ModelSpec, s: DataScales, n: int, *, seed: int = 0
                  ) -> list[dict[str, float]]:
    """`n` starts of the global search (natural units; see the module docstring): the rows
    of :func:`search_points`."""
    if n <= 0:
        return []
    points = search_points(spec, s, n, seed=seed)
    return [{k: float(v[i]) for k, v in points.items()} for i in range(n)]


def to_prony(spec: ModelSpec, p: Mapping[str, float]) -> tuple[float, list, list, float]:
    """`(G_inf, [G_k], [tau_k], work)` of natural parameters `p` of a rheology with a
    relaxation form (:attr:`fitting._spec.RheologyKind.relaxation`)."""
    relaxation = rheology_kind(spec).relaxation
    if relaxation is None:
        raise ValueError(f"rheology {rheology_name(spec)!r} has no relaxation form")
    return (*relaxation(p, spec.arms), p["work_of_adhesion"])


def nested_starts(spec: ModelSpec, simpler: ModelSpec, p: Mapping[str, float],
                  s: DataScales) -> list[dict[str, float]]:
    """Starts of `spec` (``prony:N``: a rheology that takes added arms,
    :attr:`fitting._spec.RheologyKind.from_relaxation`) from an optimum `p` of `simpler`
    (fewer arms)."""
    from_relaxation = rheology_kind(spec).from_relaxation
    if from_relaxation is None:
        raise ValueError(f"nested starts are for a rheology that takes added arms (a Prony "
                         f"series), not {rheology_name(spec)!r}")
    g_inf, gs, taus, work = to_prony(simpler, p)
    add = spec.arms - len(gs)
    if add < 0:
        raise ValueError("the simpler model has more arms")
    logt = np.sort(np.log(taus))
    lo, hi = math.log(s.tau_min), math.log(s.tau_resolved)
    cands = list(0.5 * (logt[1:] + logt[:-1]))
    cands += [0.5 * (lo + logt[0]), 0.5 * (logt[-1] + hi)]
    cands += [logt[0] - math.log(10.0), logt[-1] + math.log(10.0)]
    cands = [c for c in cands if lo < c < hi]
    # the simpler model exactly: one arm split into `add + 1` equal arms at its own time
    # (the same relaxation function), so the richer fit starts at the simpler optimum and,
    # the optimiser only descending, never ends above it
    arms = [(list(gs[:j]) + [gs[j] / (add + 1)] * (add + 1) + list(gs[j + 1:]),
             list(taus[:j]) + [taus[j]] * (add + 1) + list(taus[j + 1:]))
            for j in range(len(gs))]
    # each candidate time twice: an arm of 1e-3 G_inf (explores), and one just inside the
    # lower bound of the moduli (2e-6 of the Hertz estimate; `default_bounds`), the simpler
    # model to about that relative amount, from which a second arm can grow
    arms += [(list(gs) + [g_add] * add, list(taus) + [math.exp(c)] * add)
             for c in cands for g_add in (1e-3 * g_inf, 2e-6 * s.g_relaxed)]
    out = []
    for new_g, new_t in arms:
        order = np.argsort(new_t, kind="stable")
        q = from_relaxation(g_inf, [new_g[j] for j in order], [new_t[j] for j in order])
        q["work_of_adhesion"] = work
        for extra in ("contact_offset", "force_offset", "force_drift"):
            if extra in p:
                q[extra] = p[extra]
        for extra in ("contact_offset", "force_offset", "force_drift"):
            if getattr(spec, extra):
                q.setdefault(extra, 0.0)
        out.append(q)
    return out


def n_search_dims(spec: ModelSpec) -> int:
    """Number of free directions of a search (for sizing the default number of starts)."""
    return n_model_inputs(spec) + int(spec.force_offset) + int(spec.force_drift)
