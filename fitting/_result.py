"""The outcome of a fit: :class:`FitResult`, with a printable summary."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ._spec import canonical_name, rheology_name

__all__ = ["FitResult", "ModelChoice"]


@dataclass
class ModelChoice:
    """One candidate of ``rheology="auto"``: its name, $\\chi^2$, number of fitted
    parameters `k` (those ending at a bound included: a richer model whose extra arm ends
    at a bound is the simpler one at the same $\\chi^2$, not a cheaper model), measured
    samples `n`, AIC $= n_e\\ln(\\chi^2/n) + 2k$, BIC $= n_e\\ln(\\chi^2/n) +
    k\\ln n_e$ and whether it was chosen (smallest BIC). $n_e$ is Kish's effective number of
    samples of the fit (:attr:`fitting.CurveBatch.n_effective`: $n$ when every sample is
    kept, about the kept samples' number when a curve is subsampled, whose weighted
    $\\chi^2$ differences are inflated by the weights)."""

    rheology: str
    chi2: float
    k: int
    n: int
    aic: float
    bic: float
    chosen: bool = False


@dataclass
class FitResult:
    """The outcome of :func:`fitting.fit` (numpy values, SI units).

    **Parameters:** `names` (short names), `units`, `columns` (names with units, e.g.
    ``G0_Pa``), `values`, `stderr` (nan for fixed parameters and those at a bound, inf for
    parameters the data do not determine), `status` (per parameter: "ok", "fixed", "not
    determined", "at lower bound", "at upper bound"), `covariance`, `correlation`.

    **Quality:** `chi2` ($\\sum r^2$ of the fitted residuals), `reduced_chi2` ($\\chi^2/(m -
    k)$), `n_data` ($m$: measured samples; kept samples carry weights, see
    :mod:`fitting._prepare`), `n_free` ($k$), `r_squared` (of `model_force` over all fitted
    samples, each weighted by the measured samples it stands for), `r_squared_contact` (over
    the samples where the data or the model is in contact: indentation > 0 before the
    measured jump-off or $|F| > 3\\sigma$, or a model contact radius > 0), `aic`, `bic` (see
    :class:`ModelChoice`), `converged`.

    **Search:** `start_losses` (final $\\chi^2$ of every start of the global search and
    the local rounds, on the search's grid), `start_steps` (iterations of every start),
    `polish_losses`, `polish_steps` (the history model searched on a coarser grid than
    its own, ``search_cells < cells``: $\\chi^2$ and iterations of the search's best
    distinct end points continued on `cells`, whose best is the result; else `None`),
    `optimiser`, `model_selection` (the candidates of ``rheology="auto"``, else empty),
    `search` (the search's settings: `n_starts`, `screen`, `local_rounds`, `max_steps`,
    `explore_steps`, `abandon`, `optimiser`, `rtol`, `seed`, and for the history model `cells` and
    `search_cells`; with the data they give the same optimum again).

    **Data and model:** `spec`, `data` (the `CurveBatch` fitted), `curves`, `profile`,
    `radius` (of a parabola or sphere), `model_force` (the model's force at the sample
    times [N], force offset included; $R^2$ uses it), `fitted_force` (the same with the
    jump-off resolved inside its sample interval, as the residuals use it;
    :mod:`fitting._objective`), `model_contact_radius` (the model's contact radius at the
    sample times [m]; these three of shape `(curves, samples)`, from the search's own
    evaluation at the optimum), `model_solution` (the model's batched `ContactSolution` at
    the optimum, every field of the forward model: evaluated and compiled on first access,
    not by the fit), `in_contact` (the samples counted by `r_squared_contact`),
    `parameterisation`, `warnings`, `timings` [s].

    **Honesty** (:mod:`fitting._quality`): `r_squared_unweighted` ($R^2$ over the kept
    samples, each once), `segments` (a :class:`fitting._quality.SegmentQuality` per
    fitted segment: $R^2$, reduced $\\chi^2$, largest residual in σ), `flags` (code →
    message: ``model_inadequate``, ``segment_not_described``, ``contact_outside_data``,
    ``force_after_detachment``, ``not_converged``; their messages are also in
    `warnings`), `convergence` (reason and advice when the search did not converge),
    `stderr_scale` ($\\sqrt{\\chi^2_\\mathrm{red}}$, the factor the Gauss–Newton errors carry:
    `stderr` / `stderr_scale` is the error the noise alone would give), `derived`
    (Young's moduli $E = 3G$ beside every shear modulus, the relaxed modulus $G_\\infty$ and
    $E_\\infty$, with standard errors from the covariance:
    :func:`fitting._uncertainty.derived_quantities`; with adhesion, Tabor's
    parameter ``tabor_mu`` of the JKR limit, :func:`fitting._quality.tabor_entry`, flagged
    ``outside_jkr_limit`` below :data:`fitting._quality.TABOR_JKR_MIN`).
    """

    names: list[str]
    units: list[str]
    columns: list[str]
    values: np.ndarray
    stderr: np.ndarray
    status: list[str]
    covariance: np.ndarray
    correlation: np.ndarray
    fixed: np.ndarray
    chi2: float
    reduced_chi2: float
    n_data: int
    n_free: int
    r_squared: float
    r_squared_contact: float
    aic: float
    bic: float
    converged: bool
    start_losses: np.ndarray
    spec: object
    data: object
    curves: list = field(default_factory=list)
    profile: object = None
    radius: float | None = None
    #: `(u, spec, param, data)`: where :attr:`model_solution` evaluates the model
    model_at: tuple | None = field(default=None, repr=False)
    model_force: np.ndarray | None = None
    fitted_force: np.ndarray | None = None
    in_contact: np.ndarray | None = None
    parameterisation: object = None
    optimiser: str = "lm"
    start_steps: np.ndarray | None = None
    polish_losses: np.ndarray | None = None
    polish_steps: np.ndarray | None = None
    model_selection: list[ModelChoice] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    r_squared_unweighted: float = float("nan")
    segments: list = field(default_factory=list)
    flags: dict = field(default_factory=dict)
    convergence: dict = field(default_factory=dict)
    stderr_scale: float = float("nan")
    derived: list = field(default_factory=list)
    search: dict = field(default_factory=dict)
    model_contact_radius: np.ndarray | None = None

    @functools.cached_property
    def model_solution(self):
        """The forward model's batched `ContactSolution` at the optimum (leading axis: the
        curves; numpy leaves), evaluated on first access (one compilation of the model;
        a fit itself reports the forces and the contact radius from its search's own
        evaluation: `model_force`, `fitted_force`, `model_contact_radius`). `None` when
        the fit holds no model (`model_at` None)."""
        if self.model_at is None:
            return None
        from ._objective import model_solution_at

        return model_solution_at(*self.model_at)

    def as_dict(self) -> dict[str, float]:
        """Parameter values by short name."""
        return dict(zip(self.names, (float(v) for v in self.values), strict=True))

    def surface_height(self, curve: int = 0) -> tuple[float, float]:
        """The sample's surface height [m] at the contact of curve `curve` (index into
        `curves`), with this fit's contact offset
        (:meth:`fitting.Curve.surface_height`: the instrument's frame, larger for a taller
        sample; a force map's topography), and its standard error (the contact offset's,
        where it was fitted and determined; else nan). Both are nan where the fitted contact
        lies outside the data (flag ``contact_outside_data``: the offset is a failure of the
        model to describe the start of contact, not a measured contact). The height is nan
        where the file's heights are relative to each curve's start or the curve has no
        contact point."""
        c = self.curves[curve]
        if "contact_outside_data" in self.flags:  # the fitted contact is no measured one
            return math.nan, math.nan
        if not self.spec.contact_offset:
            return c.surface_height(), math.nan
        j = self.names.index("contact_offset")
        se = float(self.stderr[j]) if self.status[j] == "ok" else math.nan
        return c.surface_height(float(self.values[j])), se

    def __getitem__(self, name: str) -> float:
        return self.as_dict()[canonical_name(name, self.names)]

    @property
    def normalised_residuals(self) -> np.ndarray:
        """$(F^\\mathrm{eff}_i - F_i)/\\sigma_i$ per sample, shape `(curves, samples)`
        (padding included: mask with ``data.valid``): the fitted force minus the measured
        one in units of the sample's noise, without the sample weight (``fit.csv``'s
        `residual`, the figure's residual panel)."""
        return ((np.asarray(self.fitted_force) - np.asarray(self.data.force))
                / np.asarray(self.data.noise))

    @property
    def adequate(self) -> bool:
        """The residuals are near the noise (no ``model_inadequate`` or
        ``segment_not_described`` flag)."""
        return not ({"model_inadequate", "segment_not_described"} & set(self.flags))

    @property
    def stderr_basis(self) -> str:
        """What `stderr` is, in words (the JSON's and the console's statement)."""
        return stderr_basis(self.stderr_scale, self.adequate)

    @property
    def rheology(self) -> str:
        """"standard" or "prony:N"."""
        return rheology_name(self.spec)

    def _free_count(self) -> str:
        """"N free parameter(s)" as the fit's start line counts them (every parameter not
        fixed), with those that ended at a bound (not counted in `n_free`, AIC and BIC)."""
        free = int(np.sum(~np.asarray(self.fixed, dtype=bool)))
        at_bound = free - int(self.n_free)
        return f"{free} free parameter(s)" + (
            f" ({at_bound} at a bound, not counted in AIC/BIC)" if at_bound > 0 else "")

    def summary(self) -> str:
        """A short report: model, convergence, quality (overall and per segment), one line
        per parameter and per derived quantity, the sample's surface height at each
        contact where the heights are the instrument's frame (:meth:`surface_height`),
        warnings."""
        conv = "True" if self.converged else \
            f"False: {self.convergence.get('reason', 'did not converge')}"
        status = "ok" if self.converged and self.adequate and not self.flags else \
            "FLAGGED (" + ", ".join(self.flags) + ")"
        lines = [f"[[fit]] model={self.spec.model}, rheology={self.rheology}, "
                 f"{len(self.curves)} curve(s), {self.n_data} samples "
                 f"({self.data.n_samples} kept), "
                 f"{self._free_count()}, optimiser={self.optimiser}",
                 f"    status             {status}",
                 f"    converged          {conv}",
                 f"    chi2               {self.chi2:.6g}",
                 f"    reduced chi2       {self.reduced_chi2:.6g}"
                 + ("  (model inadequate: residuals far above the noise)"
                    if "model_inadequate" in self.flags else ""),
                 f"    R^2 (all)          {self.r_squared:.5f} (each kept sample weighted by "
                 f"the measured samples it stands for); unweighted "
                 f"{self.r_squared_unweighted:.5f}",
                 f"    R^2 (in contact)   {self.r_squared_contact:.5f} (weighted)",
                 f"    AIC, BIC           {self.aic:.6g}, {self.bic:.6g}"]
        if self.segments:
            lines.append("[[segments]]        R^2 (weighted, unweighted)  reduced chi2  "
                         "max |residual| [sigma]")
            for q in self.segments:
                mark = "" if q.described else "  <- not described"
                lines.append(f"    {q.segment:<15} {q.r_squared:9.4f} {q.r_squared_unweighted:9.4f}"
                             f"   {q.reduced_chi2:12.4g}  {q.max_residual:10.3g}{mark}")
        lines.append(f"[[parameters]] (+/-: {self.stderr_basis})")
        for col, v, s, st in zip(self.columns, self.values, self.stderr, self.status,
                                 strict=True):
            if st == "ok":
                rel = f"({100 * s / abs(v):.2g} %)" if v != 0 and math.isfinite(s) else ""
                lines.append(f"    {col:<26} {v:12.6g} +/- {s:<10.3g} {rel}")
            else:
                lines.append(f"    {col:<26} {v:12.6g}   {st}")
        if self.derived:
            lines.append("[[derived]] (Young's modulus E = 3G: incompressible, nu = 0.5; "
                         "Tabor's mu: the JKR limit needs a large mu; errors from the covariance)")
            for d in self.derived:
                col = f"{d['name']}_{d['unit']}"
                if d["status"] == "ok":
                    v, s = d["value"], d["stderr"]
                    rel = f"({100 * s / abs(v):.2g} %)" if v != 0 and math.isfinite(s) else ""
                    lines.append(f"    {col:<26} {v:12.6g} +/- {s:<10.3g} {rel}")
                else:
                    lines.append(f"    {col:<26} {d['value']:12.6g}   {d['status']}")
        heights = [self.surface_height(i) for i in range(len(self.curves))]
        if any(math.isfinite(h) for h, _ in heights):
            lines.append("[[surface]] (the sample's surface where each curve touched it, in "
                         "the instrument's frame of heights)")
            for i, (h, se) in enumerate(heights):
                if math.isfinite(h):
                    err = f" +/- {se:.3g}" if math.isfinite(se) else (
                        " (no error: the contact offset is not fitted, not determined or "
                        "at a bound)")
                    lines.append(f"    curve {i}: height {h:.9g} m{err}")
        if self.model_selection:
            lines.append("[[model selection]] (smallest BIC chosen)")
            for m in self.model_selection:
                mark = " <-" if m.chosen else ""
                lines.append(f"    {m.rheology:<10} chi2 {m.chi2:12.6g}  k {m.k}  "
                             f"AIC {m.aic:12.6g}  BIC {m.bic:12.6g}{mark}")
        corr = []
        k = len(self.names)
        for i in range(k):
            for j in range(i + 1, k):
                c = self.correlation[i, j]
                if np.isfinite(c) and abs(c) > 0.9:
                    corr.append(f"    C({self.names[i]}, {self.names[j]}) = {c:+.3f}")
        if corr:
            lines.append("[[correlations]] (|C| > 0.9)")
            lines += corr
        if self.warnings:
            lines.append("[[warnings]]")
            lines += [f"    {w}" for w in self.warnings]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        vals = ", ".join(f"{n}={v:.4g}" for n, v in zip(self.names, self.values, strict=True))
        return (f"FitResult({self.spec.model}, {self.rheology}: {vals}; chi2={self.chi2:.4g}, "
                f"converged={self.converged})")


def stderr_basis(scale: float, adequate: bool) -> str:
    """What a fit's standard errors are (`scale`: $\\sqrt{\\chi^2_\\mathrm{red}}$)."""
    text = (f"Gauss-Newton standard error scaled by sqrt(reduced chi2) = {scale:.3g} "
            "(lmfit's scale_covar)")
    if not adequate:
        text += ("; the model does not describe the data, so it measures how tightly the "
                 "misfit holds the parameters, not the measurement precision")
    return text
