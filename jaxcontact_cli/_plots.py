"""Figures (the top layer: matplotlib lives here, never in `jaxcontact` or `fitting`)."""

from __future__ import annotations

import math
import pathlib

import numpy as np

__all__ = ["plot_fit", "plot_map", "plot_corner", "plot_fit_posterior", "plot_sweep",
           "plot_pulloff_demo"]

_SEGMENT_COLOURS = {"approach": "tab:blue", "hold": "tab:orange", "retract": "tab:green"}
_SEGMENTS = ("approach", "hold", "retract")

#: One line on the figure per flag of a fit (:mod:`fitting._quality`).
_FLAG_TEXT = {
    "model_inadequate": "MODEL INADEQUATE: residuals far above the noise; the ± are not "
                        "a measurement precision",
    "segment_not_described": "a fitted segment is NOT DESCRIBED by the model (see the "
                             "segment lines)",
    "contact_outside_data": "the fitted contact lies outside the data: the start of contact "
                            "is not described",
    "force_after_detachment": "after the model's jump-off the measured force stays off the "
                              "model's (tethers? a retract offset?): see the warnings",
    "baseline_trend": "the free force before contact has a trend the constant baseline "
                      "leaves in the data: see the warnings for the remedies",
    "drift_not_baseline": "the fitted force drift is NOT the free force's own slope: it "
                          "takes up a misfit of the model in contact; see the warnings",
    "not_converged": "NOT CONVERGED: the best point found is shown",
    "outside_jkr_limit": "outside the JKR limit (Tabor's mu < 5): the work of adhesion is "
                         "biased",
}


def _fmt(v, s, status):
    if status == "ok" and math.isfinite(s):
        return f"{v:.4g} ± {s:.2g}"
    if status == "fixed":
        return f"{v:.4g} (fixed)"
    return f"{v:.4g} ({status})"


def plot_fit(result, path=None):
    """Data and fit of a :class:`fitting.FitResult`; saved to `path` (PNG) if given.

    Four panels: force against time (the hold shows), force against indentation, the
    residuals (model − data)/σ against time (σ: the curve's noise), and the fitted values
    with their standard errors (and what they are) and the fit quality, overall and per
    segment, with the fit's flags in red (model inadequate, a segment not described, the
    contact outside the data, a force after the jump-off, a baseline trend, not converged,
    outside the JKR limit). Colours mark the segments (approach, hold, retract), the black
    line is the model; the dashed vertical line is the detected contact point (indentation 0), the
    dotted one the fitted contact point (when the contact offset was fitted). Returns the
    matplotlib figure.
    """
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    data = result.data
    valid = np.asarray(data.valid) > 0
    ts, d, f = (np.asarray(x) for x in (data.ts, data.indentation, data.force))
    seg = np.asarray(data.segment)
    fm = np.asarray(result.model_force)
    res = result.normalised_residuals
    sigma = np.asarray(data.sigma)
    delta = result["contact_offset"] if result.spec.contact_offset else None
    fig, ax = plt.subplots(2, 2, figsize=(12, 8), gridspec_kw={"height_ratios": [3, 1.6]})
    a_t, a_d, a_r, a_txt = ax[0, 0], ax[0, 1], ax[1, 0], ax[1, 1]
    styles = ["-", "--", ":", "-."]
    for c in range(data.n_curves):
        m = valid[c]
        label_curve = f" (curve {c + 1})" if data.n_curves > 1 else ""
        for j, name in enumerate(_SEGMENTS):
            s = m & (seg[c] == j)
            if not s.any():
                continue
            kw = dict(ms=2.5, alpha=0.55, color=_SEGMENT_COLOURS[name])
            lab = f"data, {name}" if c == 0 else None
            a_t.plot(ts[c, s], f[c, s] * 1e9, ".", label=lab, **kw)
            a_d.plot(d[c, s] * 1e6, f[c, s] * 1e9, ".", **kw)
            a_r.plot(ts[c, s], res[c, s], ".", **kw)
        ls = styles[c % len(styles)]
        a_t.plot(ts[c, m], fm[c, m] * 1e9, ls, color="k", lw=1.2,
                 label=f"model{label_curve}")
        a_d.plot(d[c, m] * 1e6, fm[c, m] * 1e9, ls, color="k", lw=1.2)
    a_d.axvline(0.0, color="grey", ls="--", lw=0.8, label="detected contact")
    if delta is not None:
        a_d.axvline(-delta * 1e6, color="tab:red", ls=":", lw=1.2, label="fitted contact")
    for a in (a_t, a_d):
        a.axhline(0.0, color="grey", lw=0.5)
    a_t.set_xlabel("time [s]")
    a_t.set_ylabel("force [nN] (compressive > 0)")
    a_t.legend(fontsize=8, loc="best")
    a_d.set_xlabel("indentation [µm]")
    a_d.set_ylabel("force [nN]")
    a_d.legend(fontsize=8, loc="best")
    a_r.axhline(0.0, color="k", lw=0.5)
    a_r.set_xlabel("time [s]")
    a_r.set_ylabel("(model − data) / σ")
    noise = ", ".join(f"{s * 1e12:.3g}" for s in sigma)
    a_r.set_title(f"residuals in units of the noise σ = {noise} pN", fontsize=9)
    a_txt.axis("off")
    lines = [f"{result.spec.model} model, {result.rheology}",
             f"R² = {result.r_squared:.4f} (all, sample-weighted; unweighted "
             f"{result.r_squared_unweighted:.4f}), {result.r_squared_contact:.4f} (in contact)",
             f"χ²_red = {result.reduced_chi2:.3g}, converged: {result.converged}"]
    for q in result.segments:
        lines.append(f"  {q.segment:<9} R² {q.r_squared:7.3f}  χ²_red {q.reduced_chi2:9.3g}"
                     f"  max|r| {q.max_residual:7.3g} σ" + ("" if q.described else
                                                          "  NOT DESCRIBED"))
    lines.append("")
    for col, v, s, st in zip(result.columns, result.values, result.stderr, result.status,
                             strict=True):
        lines.append(f"{col:<24} {_fmt(float(v), float(s), st)}")
    young = [d for d in result.derived if d["name"].startswith("E")]
    if young:
        lines.append("E = 3G: " + ", ".join(
            f"{d['name']} {_fmt(d['value'], d['stderr'], d['status'])}" for d in young))
    lines.append(f"±: Gauss–Newton error × √χ²_red (= {result.stderr_scale:.3g})"
                 + ("" if result.adequate else ", not a measurement precision"))
    a_txt.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", family="monospace",
               fontsize=8, transform=a_txt.transAxes)
    alarms = [_FLAG_TEXT[k] for k in result.flags if k in _FLAG_TEXT]
    rest = len(result.warnings) - len(result.flags)
    if rest > 0:
        alarms.append(f"{rest} further warning(s): see parameters.json")
    src = ", ".join(pathlib.Path(c.source).name for c in result.curves if c.source)
    fig.suptitle(src or "fit", fontsize=10)
    bottom = 0.0
    if alarms:  # below the panels, in red when the fit is flagged
        bottom = 0.025 * len(alarms) + 0.01
        fig.text(0.01, 0.005, "\n".join(alarms), va="bottom", ha="left", fontsize=9,
                 color="tab:red" if result.flags else "k")
    fig.tight_layout(rect=(0.0, bottom, 1.0, 1.0))
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig


#: Units of the parameter columns as a figure writes them.
_UNIT_TEXT = {"Pa_s": "Pa s", "J_m2": "J/m²"}


def _map_title(name: str, unit: str) -> str:
    """A map panel's title: the parameter with its unit; a shear modulus (unit Pa: "G0",
    "G_inf", "G_1", "G") as the Young's modulus E = 3G ("E0 [Pa] = 3 G0")."""
    text = _UNIT_TEXT.get(unit, unit)
    if unit == "Pa" and name.startswith("G"):
        return f"E{name[1:]} [{text}] = 3 {name}"
    return f"{name} [{text}]"


def plot_map(result, path=None):
    """Maps of a :class:`fitting.FitEachResult`; saved to `path` (PNG) if given.

    One panel per free parameter, one for $R^2$ in contact and, where the file's heights
    are the instrument's frame (JPK, Asylum), one of the sample's surface height at each
    contact above the lowest one [µm] (:meth:`fitting.FitEachResult.surface_heights`: the
    topography), titled with its unit. Shear
    moduli are drawn as Young's moduli $E = 3G$ (the incompressible half-space, $\nu = 0.5$:
    the field's convention; ``E0 [Pa] = 3 G0``), their errors scaled alike; ``map.csv`` keeps
    both. A force map (curves with
    grid indices, one per grid point) is drawn as images on the grid (``grid_x`` to the
    right, ``grid_y`` up; grey: no curve at that point, or a failed fit, marked ×);
    other batches as values against the curve index with their standard errors (failed
    curves marked × on the axis). Values at a bound or not determined are drawn hollow;
    flagged curves (not converged, residuals far above the noise, ...) get a red triangle.
    Returns the matplotlib figure.
    """
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    first = next(r for r in result.results if r is not None)
    free = [j for j in range(len(result.names)) if not first.fixed[j]]
    panels = [(_map_title(result.names[j], result.units[j]), j) for j in free] + [
        ("R² in contact", None)]
    heights, height_se = result.surface_heights()
    if np.isfinite(heights).any():
        panels.append(("surface height above the lowest [µm]", "height"))
        low = np.nanmin(heights)
        heights, height_se = (heights - low) * 1e6, height_se * 1e6
    vals, errs = result.values(), result.stderr()
    # shear moduli as Young's moduli, E = 3G (the titles say so)
    young = np.array([3.0 if u == "Pa" else 1.0 for u in result.units])
    vals, errs = vals * young, errs * young
    r2 = np.array([r.r_squared_contact if r is not None else np.nan for r in result.results])
    status = [[r.status[j] if r is not None else "failed" for j in range(len(result.names))]
              for r in result.results]
    try:
        grid = result.grid()
    except ValueError:
        grid = None
    ncol = min(3, len(panels))
    nrow = -(-len(panels) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.6 * nrow), squeeze=False)
    failed = np.array([e is not None for e in result.errors])
    flagged = np.array([r is not None and e is None and bool(r.flags)
                        for r, e in zip(result.results, result.errors, strict=True)])
    for k, (title, j) in enumerate(panels):
        ax = axes[k // ncol, k % ncol]
        values = r2 if j is None else heights if j == "height" else vals[:, j]
        height = j == "height"
        j = None if height else j  # (no parameter's status, unit or log scale)
        if grid is not None:
            # the whole grid of the map (its shape from the file's metadata), one pixel per
            # grid point; points without a curve are grey
            gx = np.asarray([m.get("grid index x", -1) for m in result.metadata], int)
            gy = np.asarray([m.get("grid index y", -1) for m in result.metadata], int)
            nx = max(int(result.metadata[0].get("grid shape x", 0) or 0), gx.max() + 1)
            ny = max(int(result.metadata[0].get("grid shape y", 0) or 0), gy.max() + 1)
            img = np.full((ny, nx), np.nan)
            img[gy, gx] = values
            finite = values[np.isfinite(values)]
            log = j is not None and finite.size and np.all(finite > 0) and \
                result.units[j] not in ("m", "N")
            cmap = matplotlib.colormaps["viridis"].with_extremes(bad="0.85")
            norm = matplotlib.colors.LogNorm() if log else None
            im = ax.imshow(np.ma.masked_invalid(img), origin="lower", cmap=cmap, norm=norm,
                           interpolation="nearest", extent=(-0.5, nx - 0.5, -0.5, ny - 0.5))
            fig.colorbar(im, ax=ax)
            odd = np.array([j is not None and st[j] not in ("ok", "fixed", "failed")
                            for st in status])
            for mask, mark, label in ((failed, "x", "failed"),
                                      (odd, "o", "at a bound / not determined"),
                                      (flagged, "^", "flagged (map.csv: flags)")):
                if mask.any():
                    ax.plot(gx[mask], gy[mask], mark, mfc="none", color="tab:red", ms=8,
                            ls="none", label=label)
            ax.set_xlabel("grid x")
            ax.set_ylabel("grid y")
            if failed.any() or odd.any() or flagged.any():
                ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18),
                          ncol=2, frameon=False)
        else:
            idx = np.arange(len(values))
            ok = np.array([st[j] == "ok" for st in status]) if j is not None else ~failed
            se = height_se if height else None if j is None else errs[:, j]
            e = np.zeros_like(values) if se is None else np.where(np.isfinite(se), se, 0.0)
            ax.errorbar(idx[ok], values[ok], yerr=e[ok], fmt="o", ms=4, color="tab:blue")
            rest = ~ok & ~failed
            ax.plot(idx[rest], values[rest], "o", mfc="none", color="tab:blue",
                    label="at a bound / not determined")
            ax.plot(idx[failed], np.zeros(failed.sum()), "x", color="tab:red",
                    label="failed")
            ax.plot(idx[flagged], values[flagged], "^", mfc="none", color="tab:red", ms=9,
                    label="flagged (map.csv: flags)")
            if j is not None and np.all(values[np.isfinite(values)] > 0) and \
                    result.units[j] not in ("m", "N"):
                ax.set_yscale("log")
            ax.set_xlabel("curve")
            if rest.any() or failed.any() or flagged.any():
                ax.legend(fontsize=7)
        ax.set_title(title, fontsize=10)
    for k in range(len(panels), nrow * ncol):
        axes[k // ncol, k % ncol].axis("off")
    fig.suptitle(f"{result.model} model, {result.rheology}: {len(result.results)} curves, "
                 f"{result.n_converged} converged, {int(flagged.sum())} flagged, "
                 f"{result.n_failed} failed", fontsize=10)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig



def plot_corner(posterior, path=None, *, max_points: int = 2000):
    """Corner plot of a :class:`fitting.PosteriorResult`: the marginal histogram of every
    sampled parameter on the diagonal (the 5 %, 50 % and 95 % quantiles dashed, the fit's
    optimum and linearised ±1 standard error in red), the draws of every pair below it
    (at most `max_points`, all chains). Positive parameters spread over more than a
    decade on logarithmic axes, the others linear. Saved to `path` (PNG) if given; returns the
    figure."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    names = list(posterior.names)
    k = len(names)
    rows = {r["name"]: r for r in posterior.rows}
    draws = {n: np.asarray(posterior.samples[n]).ravel() for n in names}
    n_all = len(next(iter(draws.values())))
    pick = np.random.default_rng(0).choice(n_all, size=min(n_all, max_points), replace=False)
    # logarithmic axes for positive parameters spread over more than a decade
    log = {n: bool(np.all(draws[n] > 0)) and not n.endswith("offset")
           and float(np.max(draws[n]) / np.min(draws[n])) > 10.0 for n in names}
    fig, ax = plt.subplots(k, k, figsize=(2.0 * k + 1, 2.0 * k + 1), squeeze=False)
    for i, ni in enumerate(names):
        for j, nj in enumerate(names):
            a = ax[i, j]
            if j > i:
                a.axis("off")
                continue
            if i == j:
                x = draws[ni]
                bins = (np.geomspace(x.min(), x.max(), 40) if log[ni] and x.min() < x.max()
                        else 40)
                a.hist(x, bins=bins, color="tab:blue", alpha=0.7)
                r = rows[ni]
                for q in (r["q05"], r["median"], r["q95"]):
                    a.axvline(q, color="k", ls="--", lw=0.8)
                if r["fit_status"] == "ok" and math.isfinite(r["fit_stderr"]):
                    a.axvspan(r["fit_value"] - r["fit_stderr"], r["fit_value"] + r["fit_stderr"],
                              color="tab:red", alpha=0.15)
                if math.isfinite(r["fit_value"]):
                    a.axvline(r["fit_value"], color="tab:red", lw=1.0)
                a.set_yticks([])
                a.set_title(f"{ni}: {r['identifiability']}", fontsize=7)
            else:
                a.plot(draws[nj][pick], draws[ni][pick], ".", ms=1.5, alpha=0.4,
                       color="tab:blue")
                if log[ni]:
                    a.set_yscale("log")
            if log[nj]:
                a.set_xscale("log")
            if i == k - 1:
                unit = rows[nj]["unit"]
                a.set_xlabel(f"{nj} [{unit}]" if unit != "1" else nj, fontsize=8)
            else:
                a.set_xticklabels([])
            if j == 0 and i > 0:
                unit = rows[ni]["unit"]
                a.set_ylabel(f"{ni} [{unit}]" if unit != "1" else ni, fontsize=8)
            elif i != j:
                a.set_yticklabels([])
            for axis, name in ((a.xaxis, nj), (a.yaxis, ni))[:1 if i == j else 2]:
                if not log[name]:
                    axis.set_major_locator(MaxNLocator(3))
            a.tick_params(labelsize=6)
    fig.suptitle(f"posterior: NUTS, {posterior.chains} chains x {posterior.draws} draws, "
                 f"{posterior.divergences} divergences (red: fit ± linearised error)",
                 fontsize=9)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=100)
        plt.close(fig)
    return fig


def plot_fit_posterior(posterior, path=None):
    """:func:`plot_fit` of the posterior's fit with the posterior band of the model force
    (5-95 % over draws, grey; the noise not included) on the force panels. Saved to `path`
    (PNG) if given; returns the figure."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig = plot_fit(posterior.fit)
    band = posterior.predictive
    if band is not None:
        data = posterior.fit.data
        valid = np.asarray(data.valid) > 0
        ts, d = np.asarray(data.ts), np.asarray(data.indentation)
        a_t, a_d = fig.axes[0], fig.axes[1]
        for c in range(data.n_curves):
            m = valid[c] & np.isfinite(band[0, c]) & np.isfinite(band[2, c])
            lab = "posterior 5-95 %" if c == 0 else None
            a_t.fill_between(ts[c, m], band[0, c, m] * 1e9, band[2, c, m] * 1e9,
                             color="0.4", alpha=0.35, lw=0, label=lab, zorder=3)
            a_d.fill_between(d[c, m] * 1e6, band[0, c, m] * 1e9, band[2, c, m] * 1e9,
                             color="0.4", alpha=0.35, lw=0, zorder=3)
        a_t.legend(fontsize=8, loc="best")
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig


def plot_sweep(ds, path, summary, x, log):
    """One summary of a `jaxcontact sweep` dataset (`ds`, xarray) against a swept
    parameter, saved to `path` (PNG): `summary` the variable plotted, `x` the parameter
    along the horizontal axis (`None`: the longest swept one), one line per value of a
    second swept parameter (the others at their first value, named in the title), `log`
    `{parameter: True}` for those swept logarithmically (a log axis); a force that is
    adhesive everywhere is plotted as its magnitude (the label says −)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    swept = [d for d in ds[summary].dims]
    fig, ax = plt.subplots(figsize=(7.6, 4.4))
    y = ds[summary]
    note = []
    if not swept:
        ax.plot([0], [float(y)], "o")
        ax.set_xlabel("(no swept parameter)")
    else:
        if x is None:
            x = max(reversed(swept), key=lambda d: ds.sizes[d])
        series = [d for d in swept if d != x]
        line = series[0] if series else None
        for d in series[1:]:
            note.append(f"{d} = {float(ds[d][0]):.3g} {ds[d].attrs.get('units', '')}")
            y = y.isel({d: 0})
        flip = summary.endswith("_force_N") and bool(np.nanmax(y.values) <= 0)
        values = -y if flip else y
        xs = ds[x].values
        if line is None:
            ax.plot(xs, values.values, "o-", ms=3)
        else:
            for i in range(ds.sizes[line]):
                v = float(ds[line][i])
                ax.plot(xs, values.isel({line: i}).values, "o-", ms=3,
                        label=f"{line} = {v:.3g} {ds[line].attrs.get('units', '')}")
            # beside the axes, never over a line
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                      borderaxespad=0.0)
        if log.get(x):
            ax.set_xscale("log")
        finite = values.values[np.isfinite(values.values)]
        if finite.size and finite.min() > 0 and finite.max() > 30 * finite.min():
            ax.set_yscale("log")
        ax.set_xlabel(f"{x} [{ds[x].attrs.get('units', '')}]")
        unit = ds[summary].attrs.get("units", "")
        name = summary.rsplit("_", 1)[0] if unit else summary
        label = name.replace("_", " ")
        ax.set_ylabel(("−" if flip else "") + label + (f" [{unit}]" if unit else ""))
    ax.set_title(f"jaxcontact sweep ({ds.attrs['model']})" + (": " + ", ".join(note)
                                                               if note else ""), fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120, format="png")
    plt.close(fig)


def plot_pulloff_demo(elastic, lifts, title: str, path) -> None:
    """The figure of ``jaxcontact demo``, saved to `path` (PNG): force against indentation
    of the elastic JKR curve `elastic` (`(displacement [m], force [N])`, dashed) and of each
    viscoelastic lift of `lifts` (`(velocity [m/s], displacement [m], force [N], t / t_end,
    contact radius [m])`, the samples in contact), with `title`; beside it the contact
    radius against the lift's time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(elastic[0] * 1e6, elastic[1] * 1e6, "k--",
             label="elastic JKR, $E^*=4G_\\infty$, $\\Delta\\gamma_{eff}$")
    for v, d, f, t, a in lifts:
        ax1.plot(d * 1e6, f * 1e6, label=f"viscoelastic, v = {v:g} m/s")
        ax2.plot(t, a * 1e6)
    ax1.set_xlabel("indentation d [µm]")
    ax1.set_ylabel("force F [µN] (adhesive < 0)")
    ax1.legend(fontsize=8)
    ax1.set_title(title, fontsize=9)
    ax2.set_xlabel("t / t_end")
    ax2.set_ylabel("contact radius a [µm]")
    ax2.set_title("Pinned, receding, jump-off")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=120)
    finally:
        plt.close(fig)
