r"""The fitting objective: weighted residuals of a forward model against measured curves.

Model choice (:class:`ModelSpec`)
---------------------------------
* ``model="relaxed"``: the relaxed-start model :func:`jaxcontact.retract`. Only the
  ``retract`` segment of each curve is used (from the deepest sample before it; the whole
  curve if it has none); time is
  counted from the start of the lift, the relaxed depth is the first retract indentation
  and the measured indentation samples drive the model (piecewise linear; samples above
  the start depth are clipped to it, so noise cannot make the contact "advance").
* ``model="history"``: the full-history MDR foundation :func:`jaxcontact.simulate` on the
  ``approach``, ``hold`` and ``retract`` segments (a ``rest`` segment is dropped). The
  measured indentation is the input (displacement control: the tip position is measured,
  so it *is* the imposed indentation). With a ``spring_constant`` the loading is
  :class:`jaxcontact.CompliantLoading` driven by the base position $z = d + F/k$, which
  moves the jump-off to where the contact stiffness meets the cantilever's.
* Rheology: ``"standard"`` (parameters $G_0, G_1, \eta_1$) or ``"prony:N"`` (parameters
  $G_\infty, G_1..G_N, \tau_1..\tau_N$); always plus $\Delta\gamma$. Profile: parabola of
  radius ``radius`` (any :class:`jaxcontact.AbstractProfile` may be passed instead).

Curves of different lengths are padded to a common length by repeating the last sample
(zero time step, zero weight), so all curves are evaluated in one ``vmap``.

Residuals and weights
---------------------
Force residuals $r_i = \rho_i\,(F_\mathrm{model}(t_i) - F_i)/\sigma$ with $\sigma$ the
noise of the curve: the baseline noise found by the loader when there is one, else a
robust estimate from the data itself ($1.4826\,\mathrm{median}|\Delta^2 F|/\sqrt 6$),
floored at $10^{-3}$ of the force range so that noiseless data stay well scaled.

Jump-off (why the loss stays well-posed)
----------------------------------------
Under displacement control the model force drops discontinuously to exactly 0 at the model's
jump-off time $t^*(\theta)$, and the data do the same at the measured detachment. A plain
residual $F_\mathrm{model}(t_i) - F_i$ is then a step function of the parameters at every
sample that $t^*$ crosses: the loss is discontinuous and its gradient carries no
information about where the jump is. Two devices remove this:

1. **Ramp weight.** Each force residual is multiplied by
   $\rho_i = S\big((t^*(\theta) - t_i)/w\big)$ with $S$ the smoothstep clipped to
   $[0, 1]$ and $w$ two sampling intervals. $\rho_i = 0$ at and after the model's jump-off,
   so the jump of $F_\mathrm{model}$ is multiplied by 0 and every residual is a continuous
   (piecewise smooth) function of the parameters; $t^*$ itself is smooth (it is refined
   between samples by the forward models). Samples between the measured and modelled
   jump-off thus count only while the model is still attached (where they pull the model
   towards detaching earlier) and not at all after it.
2. **Event residuals.** Two residuals per curve carry the information the ramp removes:
   the largest tensile force (model ``max_tensile_force`` against the data minimum, refined
   by a parabola through three samples when it is interior; when the minimum is the last
   attached sample its weight includes the force change over one sample) and the jump-off
   indentation (model ``jumpoff_displacement``
   against the midpoint of the last attached and first detached data samples, with
   $\sigma_d$ = 1 % of the indentation range or one sampling step, whichever is larger).
   Both are smooth in the parameters. The jump-off residual is set to 0 when the model
   does not detach.
3. **Curves that do not detach.** When no detachment is found in a curve but its last
   sample is still loaded ($|F| > 3\sigma$: the lift stopped in contact), the data say
   only that the contact held at least down to the last indentation $d_\mathrm{end}$.
   The jump-off residual is then one-sided, $\max(d^*(\theta) - d_\mathrm{end}, 0)/
   \sigma_d$: it penalises a model that detaches earlier (deeper) than the data, so the
   ramp cannot hide the last samples by an early model jump-off, and is 0 otherwise. Curves
   that end unloaded without a visible jump (no adhesion) carry no jump-off residual.

Compliant loading
-----------------
Under ``CompliantLoading`` the tip jumps to the free branch at the jump-off ($d = z$), so
the first detached indentation sample says nothing about where the contact was lost. The
jump-off is then located by the drive position $z = d + F/k$, in the model
$z^* = d^* + F^*/k$ (``jumpoff_displacement``, ``jumpoff_force``; refined inside the step
by the forward model), in the data the fold of the measured equilibrium branch: the vertex
of the parabola $z(F)$ through the last three attached samples (the branch ends where
$\mathrm dz/\mathrm dF = 0$, $\mathrm dF/\mathrm dd = -k$), which also refines the
pull-off force beyond the last attached sample. Where that vertex is not usable (not a
minimum of $z$, or outside the last drive step; e.g. a pinned contact that reaches the
detachment criterion) the midpoint of the drive step is used, with the force extrapolated
to it along the last attached step. The jump-off is then known to the drive step only, and
so is $\Delta\gamma$ when the contact stays pinned until it jumps (the force in contact
does not depend on $\Delta\gamma$ there).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import jaxcontact as jc

from ._curve import Curve, resample, select_segments

__all__ = [
    "ModelSpec",
    "CurveBatch",
    "Parameterisation",
    "make_spec",
    "prepare_curves",
    "parameter_info",
    "build_rheology",
    "predict",
    "residuals",
    "residuals_natural",
    "initial_guess",
    "jacobian_fn",
    "log_jacobian",
    "canonical_name",
    "normalise_names",
]

_UNITS = {"G": "Pa", "eta": "Pa_s", "tau": "s", "work_of_adhesion": "J_m2"}


# --------------------------------------------------------------------------------------
# Model specification and parameters
# --------------------------------------------------------------------------------------


class ModelSpec(eqx.Module):
    """Static description of the forward model (hashable; used as a jit-static argument).

    **Fields:** `model` ("relaxed" or "history"), `rheology` ("standard" or "prony"),
    `arms` (number of Prony arms; 1 for the standard model), `compliant` (history model
    under `CompliantLoading`), `cells` (foundation grid cells of the history model).
    """

    model: str = eqx.field(static=True)
    rheology: str = eqx.field(static=True)
    arms: int = eqx.field(static=True)
    compliant: bool = eqx.field(static=True)
    cells: int = eqx.field(static=True)


def make_spec(model: str = "relaxed", rheology: str = "standard", *,
              compliant: bool = False, cells: int = 32) -> ModelSpec:
    """Parse and check the model choice (`rheology` is "standard" or "prony:N")."""
    if model not in ("relaxed", "history"):
        raise ValueError(f"model must be 'relaxed' or 'history'; got {model!r}")
    if rheology == "standard":
        kind, arms = "standard", 1
    elif isinstance(rheology, str) and rheology.startswith("prony:"):
        try:
            arms = int(rheology.split(":", 1)[1])
        except ValueError:
            arms = 0
        if arms < 1:
            raise ValueError(f"rheology 'prony:N' needs an integer N >= 1; got {rheology!r}")
        kind = "prony"
    else:
        raise ValueError(f"rheology must be 'standard' or 'prony:N'; got {rheology!r}")
    if compliant and model != "history":
        raise ValueError("a compliant loading system (spring_constant) needs model='history'")
    return ModelSpec(model=model, rheology=kind, arms=arms, compliant=bool(compliant),
                     cells=int(cells))


def parameter_info(spec: ModelSpec) -> list[tuple[str, str, str]]:
    """(short name, unit, column name with unit) of every parameter, in vector order."""
    if spec.rheology == "standard":
        names = [("G0", "Pa"), ("G1", "Pa"), ("eta1", "Pa_s")]
    else:
        names = [("G_inf", "Pa")]
        names += [(f"G_{k + 1}", "Pa") for k in range(spec.arms)]
        names += [(f"tau_{k + 1}", "s") for k in range(spec.arms)]
    names.append(("work_of_adhesion", "J_m2"))
    return [(n, u, f"{n}_{u}") for n, u in names]


def build_rheology(spec: ModelSpec, p: Float[Array, " p"]):
    """The rheology for natural (not log) parameters `p` (last entry: Δγ)."""
    if spec.rheology == "standard":
        return jc.StandardModel(p[0], p[1], p[2])
    n = spec.arms
    return jc.PronySeries(p[0], p[1:1 + n], p[1 + n:1 + 2 * n])


class Parameterisation(eqx.Module):
    r"""Map between the unconstrained free vector $z$ and log-parameters $\theta = \log p$.

    Free, unbounded: $\theta_i = \theta^\mathrm{ref}_i + z_i$. Free, bounded in
    $[\log lo, \log hi]$: $\theta_i = \log lo + (\log hi - \log lo)\,\sigma(z_i)$ (logistic).
    Fixed: $\theta_i = \theta^\mathrm{ref}_i$.
    """

    free: tuple[int, ...] = eqx.field(static=True)
    reference: Float[Array, " p"]
    lower: Float[Array, " p"]
    upper: Float[Array, " p"]

    def theta(self, z):
        idx = jnp.asarray(self.free, dtype=int)
        ref = self.reference[idx]
        lo, hi = self.lower[idx], self.upper[idx]
        bounded = jnp.isfinite(lo) & jnp.isfinite(hi)
        lo_s = jnp.where(bounded, lo, 0.0)
        hi_s = jnp.where(bounded, hi, 1.0)
        val = jnp.where(bounded, lo_s + (hi_s - lo_s) * jax.nn.sigmoid(z), ref + z)
        return self.reference.at[idx].set(val)

    def z_of(self, theta):
        """Inverse map (free entries of `theta`, clipped strictly inside the bounds)."""
        theta = np.asarray(theta, dtype=float)
        idx = list(self.free)
        ref = np.asarray(self.reference)[idx]
        lo, hi = np.asarray(self.lower)[idx], np.asarray(self.upper)[idx]
        th = theta[idx]
        bounded = np.isfinite(lo) & np.isfinite(hi)
        out = th - ref
        if np.any(bounded):
            span = np.where(bounded, hi - lo, 1.0)
            s = np.clip((th - np.where(bounded, lo, 0.0)) / span, 1e-6, 1 - 1e-6)
            out = np.where(bounded, np.log(s) - np.log1p(-s), out)
        return out


# --------------------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------------------


class CurveBatch(eqx.Module):
    """All curves of a fit, padded to one length `n` (shapes `(C, n)` / `(C,)`)."""

    ts: Float[Array, "C n"]
    drive: Float[Array, "C n"]  # model input: indentation (or base position if compliant)
    indentation: Float[Array, "C n"]
    force: Float[Array, "C n"]
    valid: Float[Array, "C n"]
    sigma: Float[Array, " C"]
    ramp_width: Float[Array, " C"]
    depth: Float[Array, " C"]
    pull_force: Float[Array, " C"]
    pull_sigma: Float[Array, " C"]
    jump_disp: Float[Array, " C"]  # jump-off indentation (drive position if compliant)
    jump_sigma: Float[Array, " C"]
    has_jump: Float[Array, " C"]  # 1: detachment found in the data
    attached_end: Float[Array, " C"]  # 1: no detachment, still loaded at the last sample
    stiffness: Float[Array, " C"]
    profile: jc.AbstractProfile

    @property
    def n_curves(self) -> int:
        return self.ts.shape[0]


def _noise(force: np.ndarray, baseline_noise: float | None) -> float:
    frange = float(np.ptp(force)) if force.size > 1 else abs(float(force[0]))
    floor = 1e-3 * max(frange, 1e-300)
    if baseline_noise is not None and baseline_noise > 0:
        return max(float(baseline_noise), floor)
    if force.size >= 5:
        est = 1.4826 * float(np.median(np.abs(np.diff(force, 2)))) / math.sqrt(6.0)
    else:
        est = 0.0
    return max(est, floor)


def _detachment(t, d, f, sigma):
    """(pull-off force, its sampling uncertainty, jump-off indentation, its sigma, found)."""
    i_min = int(np.argmin(f))
    fmin = float(f[i_min])
    dstep = float(np.max(np.abs(np.diff(d)))) if d.size > 1 else 0.0
    dsig = max(0.01 * float(np.ptp(d)) if d.size > 1 else 0.0, dstep, 1e-15)
    if fmin > -3.0 * sigma:
        return fmin, 0.0, float(d[-1]), dsig, False
    after = np.flatnonzero(f[i_min:] > 0.3 * fmin)
    if after.size == 0:
        return _refined_min(t, f, i_min), 0.0, float(d[-1]), dsig, False
    j = i_min + int(after[0])
    # a minimum at the last attached sample is the jump-off force, known only to the
    # change of force over one sampling step
    res = abs(float(f[i_min] - f[i_min - 1])) if (i_min == j - 1 and i_min > 0) else 0.0
    return _refined_min(t, f, i_min, j), res, 0.5 * float(d[j - 1] + d[j]), dsig, True


def _fold(z3, f3):
    """Vertex (F*, z*) of the parabola z(F) through three samples, or None if unusable.

    Along the lift the attached branch has F decreasing (more tensile) and z decreasing
    until the fold, where dz/dF = 0 (z minimal); beyond it no equilibrium remains.
    """
    f0, f1, f2 = (float(x) for x in f3)
    z0, z1, z2 = (float(x) for x in z3)
    if not (f0 > f1 > f2):
        return None
    b = (z1 - z2) / (f1 - f2)
    c = ((z0 - z2) / (f0 - f2) - b) / (f0 - f1)
    if not c > 0:
        return None
    fv = 0.5 * (f1 + f2) - b / (2.0 * c)
    if not (f2 - 3.0 * (f0 - f2) <= fv <= f2):
        return None
    zv = z2 + b * (fv - f2) + c * (fv - f2) * (fv - f1)
    return fv, zv


def _detachment_compliant(t, z, f, sigma):
    """`_detachment` for compliant loading: the jump-off by the drive position `z`."""
    fpull, fres, _, _, found = _detachment(t, z, f, sigma)
    zstep = float(np.max(np.abs(np.diff(z)))) if z.size > 1 else 0.0
    zsig = max(0.01 * float(np.ptp(z)) if z.size > 1 else 0.0, zstep, 1e-15)
    if not found:
        return fpull, fres, float(z[-1]), zsig, False
    i_min = int(np.argmin(f))
    j = i_min + int(np.flatnonzero(f[i_min:] > 0.3 * float(f[i_min]))[0])
    zjump = 0.5 * float(z[j - 1] + z[j])
    v = _fold(z[j - 3:j], f[j - 3:j]) if j >= 3 else None
    if v is not None and float(z[j]) <= v[1] <= float(z[j - 1]):
        fpull, zjump = min(fpull, v[0]), v[1]
    elif j >= 2 and z[j - 2] != z[j - 1]:
        # no fold (e.g. a pinned contact reaching the criterion): the force at the
        # midpoint of the drive step, extrapolated along the last attached step
        slope = float(f[j - 1] - f[j - 2]) / float(z[j - 1] - z[j - 2])
        if slope > 0:
            fpull = min(fpull, float(f[j - 1]) + slope * (zjump - float(z[j - 1])))
    return fpull, fres, zjump, zsig, True


def _refined_min(t, f, i, j_detached=None):
    """Minimum of `f` refined by a parabola through the three samples around sample `i`.

    Used only when the minimum is interior to the attached samples (the receding-front
    minimum, smooth in time); a minimum at the last attached sample is the jump-off force.
    """
    fmin = float(f[i])
    last = (j_detached - 1) if j_detached is not None else len(f) - 1
    if i <= 0 or i >= last:
        return fmin
    t0, t1, t2 = t[i - 1], t[i], t[i + 1]
    f0, f1, f2 = f[i - 1], f[i], f[i + 1]
    den = (t0 - t1) * (t0 - t2) * (t1 - t2)
    if den == 0:
        return fmin
    a = (t2 * (f1 - f0) + t1 * (f0 - f2) + t0 * (f2 - f1)) / den
    b = (t2 * t2 * (f0 - f1) + t1 * t1 * (f2 - f0) + t0 * t0 * (f1 - f2)) / den
    c = f1 - a * t1 * t1 - b * t1
    if a <= 0:
        return fmin
    tv = -b / (2 * a)
    if not (t0 <= tv <= t2):
        return fmin
    return float(min(fmin, c - b * b / (4 * a)))


def prepare_curves(
    curves: Sequence[Curve],
    spec: ModelSpec,
    *,
    radius: float | None = None,
    profile: jc.AbstractProfile | None = None,
    spring_constant: float | Sequence[float] | None = None,
    max_samples: int | Mapping[str, int] | None = None,
) -> CurveBatch:
    """Select segments, resample, estimate noise and events, and pad into a `CurveBatch`.

    `max_samples`: resample any segment with more samples to this many (default 400 per
    segment for the relaxed model, 150 per segment for the history model).
    """
    if isinstance(curves, Curve):
        curves = [curves]
    curves = list(curves)
    if not curves:
        raise ValueError("curves: give at least one curve")
    if profile is None:
        if radius is None or not (math.isfinite(float(radius)) and float(radius) > 0):
            raise ValueError(f"radius must be finite and > 0 [m]; got {radius!r}")
        profile = jc.Parabola(float(radius))
    if max_samples is None:
        max_samples = 400 if spec.model == "relaxed" else 150
    if spring_constant is None or np.ndim(spring_constant) == 0:
        ks = [spring_constant] * len(curves)
    else:
        ks = list(spring_constant)
        if len(ks) != len(curves):
            raise ValueError("spring_constant: give one value or one per curve")
    rows = []
    for n, c in enumerate(curves):
        names = c.segment_names
        if spec.model == "relaxed":
            if "retract" in names:
                # the lift starts at the deepest sample up to the first retract sample (an
                # inferred one-sample "approach" at the top of a pure lift is kept)
                first = int(np.argmax(c.segment == names.index("retract")))
                head = c.displacement[: first + 1]
                i0 = int(len(head) - 1 - np.argmax(head[::-1]))
                c = c.replace(time=c.time[i0:], displacement=c.displacement[i0:],
                              force=c.force[i0:], segment=np.zeros(len(c) - i0, int),
                              segment_names=("retract",), limits=None)
        else:
            keep = [s for s in ("approach", "hold", "retract") if s in names]
            if "retract" not in keep:
                raise ValueError(f"curve {n} ({c.source or 'no source'}): the history model "
                                 f"needs a retract segment; segments are {names}")
            c = select_segments(c, *keep)
        counts = np.bincount(c.segment)
        limit = (max_samples if isinstance(max_samples, Mapping)
                 else dict.fromkeys(c.segment_names, int(max_samples)))
        target = {s: min(int(limit.get(s, cnt)), int(cnt))
                  for s, cnt in zip(c.segment_names, counts, strict=True)}
        if any(target[s] < cnt for s, cnt in zip(c.segment_names, counts, strict=True)):
            c = resample(c, target)
        t = c.time - c.time[0]
        d = c.displacement.copy()
        f = c.force.copy()
        k = ks[n]
        if spec.compliant:
            k = k if k is not None else c.spring_constant
            if k is None:
                raise ValueError(f"curve {n}: compliant loading needs a spring constant")
        ret = c.segment == c.segment_names.index("retract") if "retract" in c.segment_names \
            else np.ones(len(t), dtype=bool)
        noise = c.contact.noise if c.contact is not None else None
        sigma = _noise(f[ret], noise)
        if spec.model == "relaxed":
            depth = float(d[0])
            if depth <= 0:
                raise ValueError(f"curve {n}: the retract starts at indentation {depth:g} m "
                                 "<= 0; the relaxed model needs a positive start depth")
            drive = np.minimum(d, depth)
        else:
            depth = float(np.max(d))
            drive = d + f / k if spec.compliant else d
        if spec.compliant:
            fpull, fres, djump, dsig, found = _detachment_compliant(
                t[ret], drive[ret], f[ret], sigma)
        else:
            fpull, fres, djump, dsig, found = _detachment(t[ret], d[ret], f[ret], sigma)
        attached_end = (not found) and abs(float(f[-1])) > 3.0 * sigma
        dt = np.diff(t[ret]) if ret.sum() > 1 else np.array([1.0])
        rows.append(dict(
            ts=t, drive=drive, indentation=d, force=f, sigma=sigma,
            ramp_width=2.0 * float(np.median(dt)), depth=depth, pull_force=fpull,
            pull_sigma=math.hypot(sigma, fres),
            jump_disp=djump, jump_sigma=dsig, has_jump=float(found),
            attached_end=float(attached_end),
            stiffness=float(k) if spec.compliant else 1.0,
        ))
    n_max = max(len(r["ts"]) for r in rows)

    def pad(a):
        a = np.asarray(a, dtype=float)
        return np.concatenate([a, np.full(n_max - len(a), a[-1])])

    stack = {key: np.stack([pad(r[key]) for r in rows])
             for key in ("ts", "drive", "indentation", "force")}
    valid = np.stack([pad(np.ones(len(r["ts"]))) * (np.arange(n_max) < len(r["ts"]))
                      for r in rows])
    scal = {key: np.array([r[key] for r in rows], dtype=float)
            for key in ("sigma", "ramp_width", "depth", "pull_force", "pull_sigma", "jump_disp",
                        "jump_sigma", "has_jump", "attached_end", "stiffness")}
    # one transfer of all arrays (a `jnp.asarray` each costs ~30 µs of dispatch)
    arrays = jax.device_put(dict(stack, valid=valid, **scal))
    return CurveBatch(**arrays, profile=profile)


# --------------------------------------------------------------------------------------
# Forward model and residuals
# --------------------------------------------------------------------------------------


def _predict_one(spec: ModelSpec, p, profile, ts, drive, depth, stiffness):
    rheology = build_rheology(spec, p)
    dgamma = p[-1]
    if spec.model == "relaxed":
        return jc.retract(rheology, profile, work_of_adhesion=dgamma, depth=depth, ts=ts,
                          displacement=drive, throw=False)
    loading = (jc.CompliantLoading(stiffness) if spec.compliant
               else jc.DisplacementControl())
    return jc.simulate(rheology, profile, dgamma, ts, drive, loading=loading,
                       grid=jc.FoundationGrid(cells=spec.cells), throw=False)


def predict(spec: ModelSpec, p: Float[Array, " p"], data: CurveBatch) -> jc.ContactSolution:
    """Forward model for every curve (batched `ContactSolution`, leading axis = curve)."""
    return jax.vmap(
        lambda ts, drive, depth, k: _predict_one(spec, p, data.profile, ts, drive, depth, k)
    )(data.ts, data.drive, data.depth, data.stiffness)


def _smoothstep(x):
    x = jnp.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def residuals_natural(p: Float[Array, " p"], data: CurveBatch, spec: ModelSpec
                      ) -> Float[Array, " m"]:
    """Weighted residual vector for natural parameters `p` (length `C*n + 2*C`).

    Order: the force residuals of every curve (curve-major), then per curve the pull-off
    residual and the jump-off residual (one-sided for a curve that ends attached). See the
    module docstring for the jump-off ramp.
    """
    sol = predict(spec, p, data)
    t_jump = jnp.where(jnp.isfinite(sol.jumpoff_time), sol.jumpoff_time, jnp.inf)
    ramp = _smoothstep((t_jump[:, None] - data.ts) / data.ramp_width[:, None])
    force = jnp.where(jnp.isfinite(sol.force), sol.force, 0.0)
    r_force = data.valid * ramp * (force - data.force) / data.sigma[:, None]
    r_pull = (sol.max_tensile_force - data.pull_force) / data.pull_sigma
    jump = sol.jumpoff_displacement
    if spec.compliant:  # the drive position at the jump-off
        jump = jump + sol.jumpoff_force / data.stiffness
    jd = jnp.where(jnp.isfinite(jump), jump, data.jump_disp)
    r_jump = (data.has_jump * (jd - data.jump_disp)
              + data.attached_end * jnp.maximum(jd - data.jump_disp, 0.0)) / data.jump_sigma
    r = jnp.concatenate([r_force.ravel(), r_pull, r_jump])
    return jnp.where(jnp.isfinite(r), r, 1e6)


def residuals(theta_log: Float[Array, " p"], data: CurveBatch, spec: ModelSpec
              ) -> Float[Array, " m"]:
    """`residuals_natural` of $p = e^\\theta$ (pure and jittable)."""
    return residuals_natural(jnp.exp(theta_log), data, spec)


def jacobian_fn(fn):
    """`z -> (r, J)`: `fn(z)` and its Jacobian by forward mode (the project's one helper).

    `jax.linearize` evaluates the model once and keeps the partial derivatives of its
    intermediates; the linear map is then pushed along each free direction (`vmap` over
    the identity). On the relaxed model this measured 1.2–1.4× faster than `jax.jacfwd`
    (whose fused tangent kernels recompute the primal transcendentals per direction).
    Reverse mode is not used: through the forward models' jump-off refinement it gives NaN.
    """

    def fn_jac(z):
        r, lin = jax.linearize(fn, z)
        J = jax.vmap(lin, out_axes=1)(jnp.eye(z.shape[0], dtype=z.dtype))
        return r, J

    return fn_jac


@eqx.filter_jit
def log_jacobian(spec: ModelSpec, free: tuple[int, ...], theta, data: CurveBatch):
    """Residuals at log-parameters `theta` and their Jacobian w.r.t. the `free` entries."""
    idx = jnp.asarray(free)
    return jacobian_fn(lambda lf: residuals(theta.at[idx].set(lf), data, spec))(theta[idx])


_UNIT_SUFFIXES = ("Pa", "Pa_s", "s", "J_m2", "m", "N")


def canonical_name(name: str, names: Sequence[str]) -> str:
    """The short parameter name of `name` (``"G0"`` or ``"G0_Pa"``); `KeyError` if unknown."""
    if name in names:
        return name
    for n in names:
        if name.startswith(n + "_") and name[len(n) + 1:] in _UNIT_SUFFIXES:
            return n
    raise KeyError(f"unknown parameter {name!r}; the parameters are {list(names)}")


def normalise_names(mapping, names, what: str) -> dict:
    """`mapping` keyed by short parameter names; `ValueError` naming `what` if unknown."""
    out = {}
    for k, v in (mapping or {}).items():
        try:
            out[canonical_name(k, names)] = v
        except KeyError:
            raise ValueError(f"{what}: unknown parameter {k!r}; the parameters are "
                             f"{list(names)}") from None
    return out


# --------------------------------------------------------------------------------------
# Initial guess from the data
# --------------------------------------------------------------------------------------


def _hertz_modulus(force, depth, profile):
    """G from F = 8 G (a d - I(a)), a = profile_radius(d)."""
    if isinstance(profile, jc.Parabola):
        # a = sqrt(R d), I(a) = a^3/(3R), in plain floats (the general path below runs a few
        # eager JAX operations, ~0.1 ms per call, which a warm fit of ~3 ms notices)
        R = float(profile.R)
        a = math.sqrt(R * depth)
        integral = a**3 / (3.0 * R)
    else:
        a = float(jc.profile_radius(profile, depth))
        integral = float(profile.integral_g(a))
    lever = 8.0 * (a * depth - integral)
    return abs(force) / max(lever, 1e-300), a


def initial_guess(curves: Sequence[Curve], spec: ModelSpec, profile) -> dict[str, float]:
    r"""A default initial guess from the data (natural units).

    * Relaxed modulus $G_\infty$ from the force at the start of the lift (relaxed in the
      relaxed model, end of the hold in the history model): $F = 8G(a d - \int_0^a g)$,
      $g(a) = d$ (Hertz for the parabola).
    * Glass modulus $G_0$ from the first unloading slope $\mathrm dF/\mathrm dd = 8 G_0 a$
      (straight-line fit over the first 5 % of the retract, at least 4 samples), at least
      $1.5\,G_\infty$.
    * Relaxation time $\tau$: from the hold (time to relax by $1 - 1/e$ of the force drop) if
      there is one, else a fifth of the lift duration.
    * $\Delta\gamma$ from the largest tensile force, JKR with $\Delta\gamma_\mathrm{eff} =
      \Delta\gamma G_0/G_\infty$: $\Delta\gamma = |F_\min| G_\infty/(1.5\pi R G_0)$ for a
      parabola of radius $R$ (the profile's radius at the start depth otherwise).
    Values from several curves are combined by the geometric mean.
    """
    g_inf, g0, tau, dg = [], [], [], []
    for c in curves:
        names = c.segment_names
        r = c.segment == names.index("retract") if "retract" in names else np.ones(len(c), bool)
        t, d, f = c.time[r], c.displacement[r], c.force[r]
        depth = float(d[0]) if spec.model == "relaxed" else float(np.max(d[: max(1, len(d) // 20)]))
        if depth <= 0:
            continue
        gi, a0 = _hertz_modulus(f[0], depth, profile)
        m = max(4, len(d) // 20)
        dd = d[:m] - d[0]
        slope = float(np.dot(dd, f[:m] - f[0]) / max(float(np.dot(dd, dd)), 1e-300))
        g0_est = max(slope / (8.0 * a0), 1.5 * gi)
        tau_est = 0.2 * float(t[-1] - t[0])
        if "hold" in names:
            h = c.segment == names.index("hold")
            th, fh = c.time[h] - c.time[h][0], c.force[h]
            if len(fh) > 10 and fh[0] > fh[-1]:
                target = fh[-1] + (fh[0] - fh[-1]) / math.e
                k = int(np.argmax(fh <= target))
                tau_est = max(float(th[k]), float(th[1]))
                f_start = float(fh[0])
                g0_est = max(g0_est, _hertz_modulus(f_start, float(np.max(c.displacement[h])),
                                                    profile)[0])
        if isinstance(profile, jc.Parabola):
            rad = float(profile.R)
        else:
            rad = a0 * a0 / max(depth, 1e-300)
        fmin = float(np.min(f))
        dg_est = max(abs(fmin), 1e-3 * float(np.ptp(f))) * gi / (1.5 * math.pi * rad * g0_est)
        g_inf.append(gi)
        g0.append(g0_est)
        tau.append(tau_est)
        dg.append(dg_est)
    if not g_inf:
        raise ValueError("initial guess: no curve with a positive indentation")

    def gm(x):
        return float(np.exp(np.mean(np.log(x))))

    Gi, G0, T, DG = gm(g_inf), gm(g0), gm(tau), gm(dg)
    if spec.rheology == "standard":
        G1 = G0 * Gi / (G0 - Gi)
        out = {"G0": G0, "G1": G1, "eta1": T * (G0 + G1)}
    else:
        n = spec.arms
        out = {"G_inf": Gi}
        taus = T * np.logspace(-1, 1, n) if n > 1 else [T]
        for k in range(n):
            out[f"G_{k + 1}"] = (G0 - Gi) / n
            out[f"tau_{k + 1}"] = float(taus[k])
    out["work_of_adhesion"] = DG
    return out

