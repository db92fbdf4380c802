"""Report figures: pure functions from numpy arrays to matplotlib Figures (Agg, no pyplot state).

Every function returns a `Figure` with its own Agg canvas, so building figures in a thread or a test
never touches a GUI backend; `png_bytes(fig)` renders and frees it.
"""

from __future__ import annotations

import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

from rig.analysis.heldout import nearest_sample_deg

BEFORE_COLOUR = "tab:orange"
AFTER_COLOUR = "tab:blue"
OUTLIER_COLOUR = "tab:red"
MAX_SCATTER_POINTS = 20000  # more points only slow the render; a seeded subsample looks the same
# titles at a fixed height above their axes (no axis has ticks on top): placing them automatically
# measured every tick label of every axis, a fifth of the report's time
TITLE_Y = 1.0


def new_figure(width_in: float, height_in: float, *, left_in: float = 0.85, right_in: float = 0.25,
               bottom_in: float = 0.6, top_in: float = 0.75, wspace: float = 0.25, hspace: float = 0.25
               ) -> Figure:
    """A figure with fixed margins in inches (room for labels, titles and a suptitle). A layout engine
    would measure every text first and draw twice: it took half the report's time."""
    fig = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=left_in / width_in, right=1 - right_in / width_in, bottom=bottom_in / height_in,
                        top=1 - top_in / height_in, wspace=wspace, hspace=hspace)
    return fig


def png_bytes(fig: Figure, dpi: int = 100) -> bytes:
    """Render to PNG and release the figure's memory."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    fig.clear()
    return buf.getvalue()


def _log_scale(axis, set_scale) -> None:
    """A log axis ticked at 1, 2 and 5 of each decade, labelled as plain numbers (20, 50, 100), without
    minor ticks: each tick is an artist of its own, and a log axis's default minor ticks and typeset
    labels cost more to draw than the rest of its figure."""
    set_scale("log")
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_locator(NullLocator())


def _thin(n: int, limit: int = MAX_SCATTER_POINTS) -> np.ndarray:
    """Row indices to plot: all rows, or an evenly spread subset when there are too many."""
    if n <= limit:
        return np.arange(n)
    return np.linspace(0, n - 1, limit).astype(int)


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def residuals_vs_temperature(
    temp_c: np.ndarray | None,
    before_nt: np.ndarray,
    after_nt: np.ndarray,
    labels: list[str],
    outliers: np.ndarray | None = None,
    title: str = "",
) -> Figure:
    """One row per component (x, y, z or |B|): error before calibration (left) and after (right).

    before_nt/after_nt are (N, k) errors in nT against the reference; `outliers` an optional (N,) mask of
    rows the robust fit rejected (drawn in red). Without temperatures the x axis is the sample index.
    """
    before_nt = np.asarray(before_nt, dtype=float).reshape(len(before_nt), -1)
    after_nt = np.asarray(after_nt, dtype=float).reshape(len(after_nt), -1)
    n, k = after_nt.shape
    x = np.arange(n, dtype=float) if temp_c is None else np.asarray(temp_c, dtype=float)
    x_label = "sample index" if temp_c is None else "DUT temperature (°C)"
    rows = _thin(n)
    mask = np.zeros(n, bool) if outliers is None else np.asarray(outliers, bool)
    fig = new_figure(10, 2.3 * k + 1.4, hspace=0.12, wspace=0.22)
    axes = fig.subplots(k, 2, sharex=True, squeeze=False)
    for i, label in enumerate(labels):
        for j, (err, colour, when) in enumerate(
            ((before_nt, BEFORE_COLOUR, "before"), (after_nt, AFTER_COLOUR, "after"))
        ):
            ax = axes[i, j]
            kept = rows[~mask[rows]]
            ax.scatter(
                x[kept],
                err[kept, i],
                s=3,
                alpha=0.4,
                color=colour,
                rasterized=True,
                label=f"{when} (RMS {_rms(err[~mask, i]):.1f} nT)",
            )
            lo, hi = _central_range(err[kept, i], share=1.0)
            ax.set_ylim(lo, hi)
            flagged = rows[mask[rows]]
            if flagged.size:
                # outliers beyond the axis are drawn on its edge, so they never squash the good samples
                y = np.clip(err[flagged, i], lo, hi)
                off = (err[flagged, i] < lo) | (err[flagged, i] > hi)
                ax.scatter(
                    x[flagged],
                    y,
                    s=14,
                    marker="x",
                    color=OUTLIER_COLOUR,
                    clip_on=False,
                    label=f"outliers ({int(mask.sum())}, {int(off.sum())} off-scale at the edge)",
                )
            ax.axhline(0.0, color="0.3", lw=0.8)
            ax.set_ylabel(f"{label} error (nT)")
            ax.legend(loc="upper right", fontsize=8, markerscale=3)
            ax.grid(alpha=0.3)
    axes[0, 0].set_title("before calibration (raw − reference)", y=TITLE_Y)
    axes[0, 1].set_title("after calibration (calibrated − reference)", y=TITLE_Y)
    for ax in axes[-1]:
        ax.set_xlabel(x_label)
    if title:
        fig.suptitle(title)
    return fig


def _central_range(x: np.ndarray, share: float = 0.998) -> tuple[float, float]:
    """The range holding the central `share` of x, widened 10 %: a few outliers do not squash the rest."""
    if x.size == 0:
        return -1.0, 1.0
    lo, hi = np.quantile(x, [(1 - share) / 2, 1 - (1 - share) / 2])
    pad = 0.1 * (hi - lo) or 1.0
    return float(lo - pad), float(hi + pad)


def norm_error_histogram(before_nt: np.ndarray, after_nt: np.ndarray, title: str = "") -> Figure:
    """Histograms of the field-magnitude error (|B| estimate − |B| reference, nT), before and after.

    Two panels because the two spreads differ by orders of magnitude.
    """
    fig = new_figure(10, 3.4, wspace=0.22)
    axes = fig.subplots(1, 2)
    for ax, err, colour, when in (
        (axes[0], before_nt, BEFORE_COLOUR, "before calibration"),
        (axes[1], after_nt, AFTER_COLOUR, "after calibration"),
    ):
        err = np.asarray(err, dtype=float)
        err = err[np.isfinite(err)]
        lo, hi = _central_range(err)
        beyond = int(np.sum((err < lo) | (err > hi)))
        note = f"\n{beyond} beyond the axis" if beyond else ""
        ax.hist(
            err,
            bins=60,
            range=(lo, hi),
            histtype="stepfilled",  # one outline, not 60 bars: the same picture for a tenth of the artists
            color=colour,
            alpha=0.85,
            label=f"mean {np.mean(err):.1f} nT\nRMS {_rms(err):.1f} nT\nN = {err.size}{note}",
        )
        ax.set_xlabel("|B| error (nT)")
        ax.set_ylabel("samples")
        ax.set_title(when, y=TITLE_Y)
        ax.legend(loc="upper right", fontsize=8, handlelength=0)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    return fig


def azimuth_elevation_deg(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (−180..180, from +x towards +y) and elevation (−90..90, towards +z) of vectors (N, 3)."""
    v = np.asarray(v, dtype=float)
    az = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    el = np.degrees(np.arctan2(v[:, 2], np.hypot(v[:, 0], v[:, 1])))
    return az, el


def direction_map(
    direction_nt: np.ndarray,
    residual_nt: np.ndarray,
    gap_deg: float = 40.0,
    title: str = "",
    residual_label: str = "|residual| after calibration (nT)",
) -> Figure:
    """Where the field pointed (in the reference axes) and where the error lives.

    Left: angular distance from every direction to the nearest sample; the red contour encloses the gaps
    (no sample within `gap_deg`). Right: each sample (or point) at its field direction, coloured by the
    size of its residual after calibration (`residual_label` says which residual).
    """
    az, el = azimuth_elevation_deg(direction_nt)
    resid = np.asarray(residual_nt, dtype=float)
    fig = new_figure(11, 4.0, right_in=0.1, wspace=0.12)
    ax_cov, ax_res = fig.subplots(1, 2, sharey=True)

    grid_az, grid_el = np.meshgrid(np.linspace(-180, 180, 145), np.linspace(-90, 90, 73))
    a, e = np.radians(grid_az.ravel()), np.radians(grid_el.ravel())
    probes = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    dist = nearest_sample_deg(probes, direction_nt).reshape(grid_az.shape)
    mesh = ax_cov.pcolormesh(
        grid_az,
        grid_el,
        dist,
        cmap="Reds",
        vmin=0,
        vmax=max(2 * gap_deg, dist.max()),
        shading="auto",
        rasterized=True,
    )
    if dist.max() > gap_deg:
        ax_cov.contour(grid_az, grid_el, dist, levels=[gap_deg], colors="darkred", linewidths=1.2)
    ax_cov.scatter(az, el, s=6 if len(az) < 500 else 1, color="black", label="sample directions")
    fig.colorbar(mesh, ax=ax_cov, label="angle to the nearest sample (deg)")
    gap_share = float(np.mean(dist > gap_deg))
    ax_cov.set_title(f"coverage: {100 * gap_share:.0f} % of the map > {gap_deg:g}° from any sample",
                     y=TITLE_Y)

    rows = _thin(len(resid))
    finite = rows[np.isfinite(resid[rows])]
    order = finite[np.argsort(resid[finite])]  # largest residuals drawn last, on top
    vmax = float(np.quantile(resid[finite], 0.99)) if finite.size else 1.0
    sc = ax_res.scatter(
        az[order], el[order], c=resid[order], s=14, cmap="viridis", vmin=0, vmax=vmax, rasterized=True
    )
    fig.colorbar(sc, ax=ax_res, extend="max", label=residual_label)
    ax_res.set_title("error after calibration, by field direction", y=TITLE_Y)
    for ax in (ax_cov, ax_res):
        ax.set_xlim(-180, 180)
        ax.set_ylim(-90, 90)
        ax.set_xticks(np.arange(-180, 181, 60))
        ax.set_yticks(np.arange(-90, 91, 30))
        ax.set_xlabel("field azimuth, reference axes (deg)")
        ax.grid(alpha=0.3)
    ax_cov.set_ylabel("field elevation, reference axes (deg)")
    if title:
        fig.suptitle(title)
    return fig


def model_comparison(
    models: list[str],
    fit_rms_nt: dict[str, list[float]],
    heldout_rms_nt: dict[str, list[float]],
    title: str = "",
) -> Figure:
    """One panel per metric ("vector", "|B|"): bars per model, RMS on fitted and on held-out points (log)."""
    metrics = list(fit_rms_nt)
    fig = new_figure(max(6.5, 5.0 * len(metrics) + 0.5), 4.0, top_in=0.9, wspace=0.3)
    axes = np.atleast_1d(fig.subplots(1, len(metrics), squeeze=False)[0])
    x = np.arange(len(models))
    width = 0.38
    for ax, metric in zip(axes, metrics, strict=True):
        drawn = []
        for offset, values, colour, label in (
            (-width / 2, fit_rms_nt[metric], "0.6", "fitted points"),
            (width / 2, heldout_rms_nt[metric], AFTER_COLOUR, "held-out points"),
        ):
            vals = np.array([v if v is not None and np.isfinite(v) and v > 0 else np.nan for v in values])
            bars = ax.bar(x + offset, np.nan_to_num(vals, nan=0.0), width, color=colour, label=label)
            drawn.append((bars, vals))
        finite = np.concatenate([vals[np.isfinite(vals)] for _, vals in drawn])
        floor = float(finite.min()) / 2 if finite.size else 0.1
        _log_scale(ax.yaxis, ax.set_yscale)
        ax.set_ylim(floor, float(finite.max()) * 3 if finite.size else 10.0)
        for bars, vals in drawn:
            for bar, v in zip(bars, vals, strict=True):
                text = "n/a" if np.isnan(v) else f"{v:.3g}"
                ax.annotate(
                    text,
                    (bar.get_x() + bar.get_width() / 2, floor if np.isnan(v) else v),
                    ha="center",
                    va="bottom",
                    fontsize=8,
                )
        ax.set_xticks(x, [m.upper() for m in models])
        ax.set_xlim(-0.75, len(models) - 0.25)
        ax.set_ylabel(f"{metric} error RMS (nT)")
        ax.set_title(f"{metric} error", y=TITLE_Y)
        ax.legend(fontsize=8, loc="upper left")
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle(title or "model comparison")
    return fig


def step_rms(
    temp_c: list[float], rms_before_nt: list[float], rms_after_nt: list[float], title: str = ""
) -> Figure:
    """Residual RMS per temperature step, before and after calibration (log scale)."""
    fig = new_figure(6.5, 3.4, top_in=0.45)
    ax = fig.subplots()
    ax.plot(temp_c, rms_before_nt, "o-", color=BEFORE_COLOUR, label="before calibration")
    ax.plot(temp_c, rms_after_nt, "s-", color=AFTER_COLOUR, label="after calibration")
    _log_scale(ax.yaxis, ax.set_yscale)
    ax.set_xlabel("temperature step (°C)")
    ax.set_ylabel("vector error RMS (nT)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(title or "residual per temperature step", y=TITLE_Y)
    return fig


def uncertainty_budget(sources: list[str], contributions_nt: list[float], field, title: str = "") -> Figure:
    """The budget as bars: each input's standard contribution to the calibrated field's error, the
    combined standard uncertainty u, the expanded U = k u and the largest 95 % radius of the 3-D error over
    the plan's grid (`field`: rig.analysis.judged.FieldFigures), nT (log scale)."""
    k = field.coverage_factor
    totals = [("combined standard u", field.standard_nt),
              (f"expanded U = k u (k = {k:.3g})" if k is not None else "expanded U (no k)",
               field.expanded_nt),
              ("95 % radius, largest", field.radius_nt)]
    labels = [*sources, *(label for label, _ in totals)]
    values = [*contributions_nt, *(np.nan if v is None else v for _, v in totals)]
    fig = new_figure(6.5, 0.35 * len(labels) + 1.2, left_in=1.6, right_in=0.45, top_in=0.45, bottom_in=0.5)
    ax = fig.subplots()
    y = np.arange(len(labels))[::-1]
    colours = [BEFORE_COLOUR] * len(sources) + [AFTER_COLOUR] * len(totals)
    shown = [max(v, 1e-3) if np.isfinite(v) else 1e-3 for v in values]  # a figure not stated: no bar
    ax.barh(y, shown, color=colours)
    for yi, v, at in zip(y, values, shown, strict=True):
        ax.text(at * 1.1, yi, f"{v:.3g}" if np.isfinite(v) else "not stated", va="center", fontsize=8)
    ax.set_yticks(y, labels, fontsize=8)
    _log_scale(ax.xaxis, ax.set_xscale)
    ax.set_xlabel("nT")
    ax.grid(alpha=0.3, axis="x")
    ax.set_title(title or "uncertainty budget", y=TITLE_Y)
    return fig
