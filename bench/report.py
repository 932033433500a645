"""Reports: tables in the layout of the thesis beside its numbers, and figures.

:func:`write_report` turns a suite's results rows into ``report.md`` with, per batch,
the relative bias and NRMSE of every estimated parameter and the VAF (thesis Tables
II-IV layout) next to the paper's numbers where the suite gives them, plus PNG figures:
parameter traces (median and 25-75 % band over the batch against the truth) and the
10-s moving VAF. An HTML copy is written when the ``markdown`` package is installed.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.bench.papers import section_writer
from manualcontrol.envs._files import atomic_path, atomic_write
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.protocol import report_progress
from manualcontrol.pilots.models import MODEL_NAMES, make_model

if TYPE_CHECKING:  # the suites import the driving env and numba, which plots never need
    from manualcontrol.bench.scenarios import Suite

__all__ = [
    "best_estimators",
    "draw_trace",
    "nan_median",
    "nan_percentiles",
    "plot_estimation",
    "plot_recording",
    "pyplot",
    "save_figure",
    "subplots",
    "summarise",
    "thin_band",
    "thin_trace",
    "write_report",
]

FloatArray = NDArray[np.float64]


#: The report's VAF rows in words (definitions: :mod:`manualcontrol.estimators.analysis.metrics`).
VAF_DEFINITIONS = (
    "VAF rows (thesis eq. 38, over the scored samples): *one-step*: the filter's "
    "prediction of each sample from the samples before it, against u as measured "
    "(remnant included); *resimulated vs u*: the isolated pilot model with the "
    "identified parameter traces, driven by the recorded perceptions, against u as "
    "measured; *resimulated vs remnant-free u*: the same model driven by the "
    "perceptions of the remnant-free run, against the remnant-free u (u - u_n), the "
    "thesis's Table III/IV VAF. *Ceiling*: the same resimulation with the true parameter "
    "traces, what a perfect estimator scores on those runs.",
)


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files only, no window), imported here.

    matplotlib is optional and slow to import, so it is loaded on the first figure;
    a parent process calls this once before forking workers that draw.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: Margins of every report figure, in inches: the y tick labels and y label on the left,
#: the x label below, a title above (what ``tight_layout`` found for these figures; it
#: drew each figure once more to find it, a third of the figure's cost).
FIGURE_MARGINS_IN = {"left": 0.85, "right": 0.15, "bottom": 0.5, "top": 0.35}
#: Gaps between panels, in inches: rows (x tick labels shared) and columns (y tick labels).
FIGURE_GAPS_IN = (0.12, 0.6)
#: Points a drawn trace keeps: a minimum and a maximum per bucket, at least two buckets
#: per pixel column of a 9-inch, 100-dpi figure, so no peak a full trace shows is lost.
DRAWN_BUCKETS = 2000


def _lay_out(fig: Any) -> None:
    """Place the figure's grid of panels with :data:`FIGURE_MARGINS_IN` and gaps."""
    axes = fig.get_axes()
    if not axes or axes[0].get_subplotspec() is None:
        return
    rows, columns = axes[0].get_subplotspec().get_gridspec().get_geometry()
    width, height = fig.get_size_inches()
    margins = FIGURE_MARGINS_IN
    inner_width = width - margins["left"] - margins["right"]
    inner_height = height - margins["bottom"] - margins["top"]
    row_gap, column_gap = FIGURE_GAPS_IN
    panel_height = (inner_height - (rows - 1) * row_gap) / rows
    panel_width = (inner_width - (columns - 1) * column_gap) / columns
    fig.subplots_adjust(
        left=margins["left"] / width,
        right=1.0 - margins["right"] / width,
        bottom=margins["bottom"] / height,
        top=1.0 - margins["top"] / height,
        hspace=row_gap / panel_height,
        wspace=column_gap / panel_width,
    )


def thin_trace(t: ArrayLike, values: ArrayLike, buckets: int = DRAWN_BUCKETS) -> tuple:
    """``(t, values)`` reduced to the minimum and maximum of each of ``buckets`` buckets.

    Both extremes are kept in their time order, so the drawn line passes through every
    peak of the full trace; NaN samples are skipped within a bucket (a bucket of NaN
    stays NaN: a gap). Traces shorter than three samples a bucket are returned whole.
    """
    t = np.asarray(t, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    size = len(values) // buckets
    if size < 3:
        return t, values
    whole = (len(values) // size) * size
    block = values[:whole].reshape(-1, size)
    finite = np.isfinite(block)
    low = np.argmin(np.where(finite, block, np.inf), axis=1)
    high = np.argmax(np.where(finite, block, -np.inf), axis=1)
    start = np.arange(block.shape[0]) * size
    keep = np.column_stack([start + np.minimum(low, high), start + np.maximum(low, high)])
    keep = np.concatenate([keep.ravel(), np.arange(whole, len(values))])
    return t[keep], values[keep]


def thin_band(t: ArrayLike, low: ArrayLike, high: ArrayLike, buckets: int = DRAWN_BUCKETS) -> tuple:
    """``(t, low, high)`` of a band reduced to each bucket's lowest and highest edge.

    Each bucket keeps its first and last time with the minimum of ``low`` and the
    maximum of ``high`` over it (NaN skipped), so the drawn band covers the full one.
    """
    t = np.asarray(t, dtype=np.float64)
    low = np.asarray(low, dtype=np.float64)
    high = np.asarray(high, dtype=np.float64)
    size = len(t) // buckets
    if size < 3:
        return t, low, high
    whole = (len(t) // size) * size
    times = t[:whole].reshape(-1, size)[:, [0, -1]].ravel()
    lows = np.repeat(np.fmin.reduce(low[:whole].reshape(-1, size), axis=1), 2)
    highs = np.repeat(np.fmax.reduce(high[:whole].reshape(-1, size), axis=1), 2)
    return (
        np.concatenate([times, t[whole:]]),
        np.concatenate([lows, low[whole:]]),
        np.concatenate([highs, high[whole:]]),
    )


def draw_trace(axis: Any, t: ArrayLike, values: ArrayLike, **style: Any) -> Any:
    """``axis.plot`` of a trace thinned by :func:`thin_trace`."""
    return axis.plot(*thin_trace(t, values), **style)


def _band(axis: Any, t: ArrayLike, low: ArrayLike, high: ArrayLike, **style: Any) -> Any:
    """``axis.fill_between`` of a band thinned by :func:`thin_band`."""
    return axis.fill_between(*thin_band(t, low, high), **style)


def subplots(rows: int, columns: int, *, reusable: bool = False, **options: Any) -> tuple[Any, Any]:
    """``pyplot.subplots`` with titles at a fixed height above the panels.

    Matplotlib otherwise measures every x axis at each draw to lift a title clear of
    tick labels above the panel, which these figures never have (a tenth of a
    figure's cost).

    ``reusable=True`` is for figures drawn only with what :func:`_clear` takes away
    again (lines, bands, legends, panel titles, axis labels without font options,
    limits): inside :func:`_reusing_figures`, a figure of the same layout saved before
    is cleared and handed out instead of a new one.
    """
    key = (rows, columns, repr(sorted(options.items())))
    pool = _figure_pool
    if pool is not None and reusable and pool.free.get(key):
        fig, axes = pool.free[key].pop()
        _clear(fig)
        return fig, axes
    plt = pyplot()
    with plt.rc_context({"axes.titley": 1.0}):
        fig, axes = plt.subplots(rows, columns, **options)
    if pool is not None:  # closed when the report ends, whatever happens
        pool.made[id(fig)] = (key if reusable else None, fig, axes)
    return fig, axes


class _FigurePool(NamedTuple):
    free: dict[tuple[Any, ...], list[tuple[Any, Any]]]
    made: dict[int, tuple[tuple[Any, ...] | None, Any, Any]]  # key None: not reusable


#: The figures of the report being drawn (:func:`_reusing_figures`); None outside one.
_figure_pool: _FigurePool | None = None
#: Saved figures kept for reuse at most (each stays open in pyplot until the report ends).
_KEPT_FIGURES = 8


@contextlib.contextmanager
def _reusing_figures() -> Iterator[None]:
    """Within: :func:`save_figure` keeps each reusable figure for the next one of its layout.

    A report draws dozens of figures of a few layouts, and creating a figure's axes and
    the ticks they draw is about half of its cost. The next figure of the same layout
    gets the saved one cleared back to a new figure's state (:func:`_clear`); its PNG is
    byte for byte the one a new figure gives (tested). Every figure made inside is
    closed on leaving, also after an error.
    """
    global _figure_pool
    if _figure_pool is not None:  # nested: the outer one owns the figures
        yield
        return
    _figure_pool = _FigurePool({}, {})
    try:
        yield
    finally:
        pool, _figure_pool = _figure_pool, None
        plt = pyplot()
        for _, fig, _ in pool.made.values():
            plt.close(fig)


def _clear(fig: Any) -> None:
    """Remove what was drawn on ``fig``'s panels, leaving them as :func:`subplots` made them.

    Covers what the reusable figures draw: lines, bands and other collections, patches,
    texts, legends, titles, axis labels, limits set or autoscaled, and the colour cycle
    of lines drawn without a colour. :func:`_plain` keeps figures changed in other
    ways from being reused.
    """
    from matplotlib.transforms import Bbox

    for axis in fig.get_axes():
        for artist in (*axis.lines, *axis.collections, *axis.patches, *axis.texts, *axis.images):
            artist.remove()
        legend = axis.get_legend()
        if legend is not None:
            legend.remove()
        for where in ("left", "center", "right"):
            axis.set_title("", loc=where)
        axis.set_xlabel("")
        axis.set_ylabel("")
        axis.dataLim.set_points(Bbox.null().get_points())
        axis.set_xlim(0.0, 1.0, auto=True)
        axis.set_ylim(0.0, 1.0, auto=True)
        axis.set_prop_cycle(None)


def _plain(fig: Any, panels: int) -> bool:
    """``fig`` holds its grid of panels and nothing :func:`_clear` would leave behind."""
    from matplotlib.ticker import AutoLocator

    if len(fig.get_axes()) != panels or fig.texts or fig.legends or fig.get_suptitle():
        return False
    for axis in fig.get_axes():
        if (
            axis.get_xscale() != "linear"
            or axis.get_yscale() != "linear"
            or axis.get_aspect() != "auto"
            or not axis.axison
            or axis.containers
            or not isinstance(axis.xaxis.get_major_locator(), AutoLocator)
            or not isinstance(axis.yaxis.get_major_locator(), AutoLocator)
        ):
            return False
    return True


def save_figure(fig: Any, path: Path) -> Path:
    """Lay out ``fig`` (:data:`FIGURE_MARGINS_IN`) and write it to ``path`` as a PNG.

    The file appears whole or not at all. The figure is closed, or, when it was made
    reusable inside :func:`_reusing_figures`, kept for the next figure of its layout.
    """
    _lay_out(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as temporary:
        # zlib level 1: half the encoding time of the default 6, and no larger here
        fig.savefig(temporary, dpi=100, format="png", pil_kwargs={"compress_level": 1})
    pool = _figure_pool
    made = pool.made.get(id(fig)) if pool is not None else None
    if made is not None and made[0] is not None:
        key, _, axes = made
        free = pool.free.setdefault(key, [])
        if any(kept is fig for kept, _ in free):  # saved twice: kept once already
            return path
        rows, columns = key[0], key[1]
        if _plain(fig, rows * columns) and sum(map(len, pool.free.values())) < _KEPT_FIGURES:
            free.append((fig, axes))
            return path
    if made is not None:
        del pool.made[id(fig)]
    pyplot().close(fig)
    return path


def plot_recording(recording: Recording, path: str | Path) -> Path:
    """Target, output, error and stick of a recording, as a PNG."""
    fig, axes = subplots(3, 1, figsize=(10, 6.5), sharex=True)
    t = recording.t
    if "ft" in recording:
        draw_trace(axes[0], t, recording.ft, lw=0.9, label="target $f_t$")
    draw_trace(axes[0], t, recording.y, lw=0.9, label="output $y$")
    axes[0].legend(loc="upper right")
    draw_trace(axes[1], t, recording.e, lw=0.8, color="tab:red", label="error $e$")
    axes[1].legend(loc="upper right")
    draw_trace(axes[2], t, recording.u, lw=0.8, color="tab:green", label="control $u$")
    if "n" in recording:
        draw_trace(axes[2], t, recording.n, lw=0.6, color="tab:gray", label="remnant $n$")
    axes[2].legend(loc="upper right")
    axes[2].set_xlabel("time [s]")
    return save_figure(fig, Path(path))


def nearest_branch(phase_deg: Any, reference_deg: Any) -> Any:
    """Each measured phase moved by whole turns to the branch nearest ``reference_deg``.

    A measured phase is known only to a whole turn, and unwrapping it along frequency
    guesses wrong where a line buried in remnant jumps by more than half a turn; beside
    a fitted model, the branch nearest the model's phase is the reading the fit made.
    """
    phase = np.asarray(phase_deg, dtype=np.float64)
    return phase + 360.0 * np.round((np.asarray(reference_deg) - phase) / 360.0)


def plot_describing_function(
    describing: Any,
    path: str | Path,
    *,
    models: Mapping[str, Mapping[str, float]] | None = None,
    model: str = "precision",
) -> Path:
    """Bode plot of a measured describing function with its spread and fitted models.

    Measured points (filled where u's signal-to-noise ratio is at least 10, open below,
    error bars one standard deviation between periods when there are several) and, for
    each entry of ``models`` (a label and the ``model`` structure's parameter values),
    the model's exact response on a fine grid (the error channel, or minus the output
    channel of a two-channel model: what the measured ``U/E`` is), e.g. the
    frequency-domain fit beside a time-domain estimate's second-half values.
    """
    # here, not at the top: the estimators load their whole family and scipy.signal
    from manualcontrol.estimators.analysis.frequency import loop_response

    fig, axes = subplots(2, 1, figsize=(7.5, 6.5), sharex=True)
    omega = describing.frequencies
    gain, phase = describing.gain_db, describing.phase_deg
    grid = np.geomspace(omega[0] / 2.0, omega[-1] * 2.0, 400)
    structure = make_model(model)
    curves = []
    for label, values in (models or {}).items():
        response = loop_response(structure, values, grid)
        unwrapped = np.degrees(np.unwrap(np.angle(response)))
        # start on the same branch as the measured phase at the lowest frequency
        offset = 360.0 * np.round((phase[0] - np.interp(omega[0], grid, unwrapped)) / 360.0)
        curves.append((label, response, unwrapped + offset))
    if curves:
        phase = nearest_branch(phase, np.interp(omega, grid, curves[0][2]))
    strong = describing.snr >= 10.0
    spread = np.isfinite(describing.gain_spread_db)
    for axis, values, error in (
        (axes[0], gain, describing.gain_spread_db),
        (axes[1], phase, describing.phase_spread_deg),
    ):
        if spread.any():
            axis.errorbar(omega, values, yerr=error, fmt="none", ecolor="k", lw=0.8, capsize=2)
        axis.plot(omega[strong], values[strong], "ko", ms=5, label="measured (SNR >= 10)")
        if (~strong).any():
            axis.plot(
                omega[~strong],
                values[~strong],
                "o",
                mfc="white",
                mec="k",
                ms=5,
                label="measured (SNR < 10)",
            )
    for (label, response, unwrapped), colour in zip(
        curves, ("tab:red", "tab:blue", "tab:green", "tab:orange"), strict=False
    ):
        axes[0].plot(grid, 20.0 * np.log10(np.abs(response)), color=colour, lw=1.2, label=label)
        axes[1].plot(grid, unwrapped, color=colour, lw=1.2, label=label)
    axes[0].set_xscale("log")
    axes[0].set_ylabel("|H_p| [dB]")
    axes[1].set_ylabel("phase H_p [deg]")
    axes[1].set_xlabel("frequency [rad/s]")
    crossover = describing.crossover_frequency
    title = "pilot describing function at the forcing frequencies"
    if np.isfinite(crossover):
        title += (
            f"; crossover {crossover:.2f} rad/s, phase margin {describing.phase_margin:.0f} deg"
        )
    axes[0].set_title(title, fontsize=9)
    axes[0].legend(loc="lower left", fontsize=8)
    return save_figure(fig, Path(path))


def _unit(name: str) -> str:
    for model in MODEL_NAMES:
        structure = make_model(model)
        if name in structure.parameter_names:
            unit = structure.spec(name).unit
            return f"{name} [{unit}]" if unit and unit != "-" else name
    return name


def plot_estimation(
    recording: Recording, result: Any, path: str | Path, *, model_output: Any = None
) -> Path:
    """Estimated parameter traces (one-sigma band, truth when known), innovation, and fit.

    With ``model_output`` (the identified model resimulated) a last panel shows the
    measured ``u`` against it, so the quality of the fit can be seen. The innovation
    panel is scaled to the 0.5-99.5 % range of its values, so the start-up transient
    of the filter does not flatten the rest; a result without innovations (an offline
    fit such as ``sigmoid-fit``) has no such panel.
    """
    names = list(result.estimated)
    innovations = bool(np.any(np.isfinite(result.innovation)))
    panels = len(names) + innovations + (model_output is not None)
    fig, axes = subplots(panels, 1, figsize=(9, 1.8 * panels), sharex=True)
    axes = np.atleast_1d(axes)
    t = result.t
    for axis, name in zip(axes, names, strict=False):
        mean, std = result.mean_of(name), result.std_of(name)
        draw_trace(axis, t, mean, color="k", lw=1.0, label="estimate")
        _band(axis, t, mean - std, mean + std, color="k", alpha=0.15, lw=0)
        if name in recording.parameters:
            draw_trace(
                axis, recording.t, recording.parameters[name], color="tab:red", lw=1.0, label="true"
            )
        axis.set_ylabel(_unit(name))
    axes[0].legend(loc="upper right")
    if innovations:
        _innovation_panel(axes[len(names)], t, result)
    if model_output is not None:
        draw_trace(axes[-1], recording.t, recording.u, color="k", lw=0.6, label="measured u")
        draw_trace(
            axes[-1], recording.t, model_output, color="tab:blue", lw=0.8, label="identified model"
        )
        axes[-1].set_ylabel("u [stick]")
        axes[-1].legend(loc="upper right")
    axes[-1].set_xlabel("time [s]")
    return save_figure(fig, Path(path))


def _innovation_panel(axis: Any, t: Any, result: Any) -> None:
    draw_trace(axis, t, result.innovation, color="tab:red", lw=0.5, label="innovation")
    spread = np.sqrt(result.innovation_variance)
    draw_trace(axis, t, spread, color="k", lw=0.8, label="sqrt(variance)")
    both = np.concatenate([np.asarray(result.innovation), spread])
    both = both[np.isfinite(both)]
    low, high = np.percentile(both, [0.5, 99.5])
    margin = 0.1 * (high - low) or 1.0
    axis.set_ylim(low - margin, high + margin)
    axis.set_ylabel("innovation [stick]")
    axis.legend(loc="upper right")


def _number(value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return math.nan
    return number


def _finite(statistic: Any, values: Sequence[Any]) -> float:
    """``statistic`` of the finite entries (NaN when there are none)."""
    numbers = np.array([_number(value) for value in values])
    known = numbers[np.isfinite(numbers)]
    return float(statistic(known)) if known.size else math.nan


def summarise(
    rows: Sequence[Mapping[str, Any]], batch: str, estimator: str | None = None
) -> dict[str, Any]:
    """Batch means of the scores (successful runs only) and run counts.

    ``estimator``: only that estimator's rows (default: every row of the batch).
    """
    runs = [
        row
        for row in rows
        if row.get("batch") == batch and (estimator is None or row.get("estimator") == estimator)
    ]
    ok = [row for row in runs if row.get("status") == "ok"]
    summary: dict[str, Any] = {"runs": len(runs), "failed": len(runs) - len(ok), "parameters": {}}
    names = sorted({key[len("nrmse_") :] for row in ok for key in row if key.startswith("nrmse_")})
    for name in names:
        summary["parameters"][name] = {
            kind: _finite(np.mean, [row.get(f"{kind}_{name}") for row in ok])
            for kind in ("rel_bias", "nrmse")
        }
    for key in (
        "vaf_resimulated",
        "vaf_resimulated_ceiling",
        "vaf_resimulated_ideal",
        "vaf_resimulated_ideal_ceiling",
        "vaf_one_step",
        "innovations_within_1sigma",
        "run_time_s",
    ):
        values = [row.get(key) for row in ok]
        summary[key] = _finite(np.mean, values)
        summary[f"{key}_median"] = _finite(np.median, values)
    summary["diverged"] = sum(bool(row.get("diverged")) for row in ok)
    summary["smoothed"] = any(bool(row.get("smoothed")) for row in ok)
    return summary


def _runs(count: int) -> str:
    return f"{count} run" if count == 1 else f"{count} runs"


def _cell(value: Any, signed: bool = False) -> str:
    number = _number(value)
    if math.isnan(number):
        return "—"
    return f"{number:+.3f}" if signed else f"{number:.3f}"


def _batch_table(summary: Mapping[str, Any], reference: Mapping[str, Any]) -> list[str]:
    paper = dict(reference.get("parameters", {}))
    names = list(summary["parameters"]) + [n for n in paper if n not in summary["parameters"]]
    lines = [
        "| parameter | rel. bias (ours) | rel. bias (paper) | NRMSE (ours) | NRMSE (paper) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name in names:
        ours = summary["parameters"].get(name, {})
        theirs = paper.get(name, {})
        lines.append(
            f"| {name} | {_cell(ours.get('rel_bias'), True)} "
            f"| {_cell(theirs.get('rel_bias'), True)} "
            f"| {_cell(ours.get('nrmse'))} | {_cell(theirs.get('nrmse'))} |"
        )
    for key, label in (
        ("vaf_resimulated", "**VAF** resimulated pilot (eq. 38) vs u"),
        ("vaf_resimulated_ideal", "VAF resimulated vs remnant-free u"),
        ("vaf_one_step", "VAF one-step filter output"),
    ):
        paper = reference.get(key)
        lines.append(
            f"| {label} | {_cell(summary[key])} % (median {_cell(summary[key + '_median'])} %) | "
            f"{'—' if paper is None else f'{paper:.2f} %'} | | |"
        )
        ceiling = summary.get(f"{key}_ceiling")
        if ceiling is not None and math.isfinite(_number(ceiling)):
            lines.append(
                f"| ceiling: the same with the true parameters | {_cell(ceiling)} % | | | |"
            )
    return lines


def nan_percentiles(stack: ArrayLike, percentiles: Sequence[float]) -> FloatArray:
    """``np.nanpercentile(stack, percentiles, axis=0)`` (linear), without a loop per column.

    numpy's NaN-aware percentile along an axis makes one Python-level call per column
    (per time sample here: 85 % of a report's time). This sorts once (NaNs last) and
    interpolates every column at once with numpy's own formulas (virtual index
    ``(n - 1) q``, its two-sided ``lerp``), so the result is identical, bit for bit;
    all-NaN columns give NaN. Shape ``(len(percentiles), columns)``.
    """
    stack = np.asarray(stack, dtype=np.float64)
    if stack.shape[0] == 0:
        return np.full((len(percentiles), stack.shape[1]), np.nan)
    ordered = np.sort(stack, axis=0)
    count = np.count_nonzero(~np.isnan(stack), axis=0)
    last = np.maximum(count - 1, 0)
    columns = np.arange(stack.shape[1])
    fractions = np.true_divide(np.asarray(percentiles, dtype=np.float64), 100.0)
    out = np.empty((fractions.shape[0], stack.shape[1]))
    for i, fraction in enumerate(fractions):
        virtual = (count - 1) * fraction
        previous = np.floor(virtual)
        above = virtual >= count - 1  # numpy takes the largest value there
        low = ordered[np.where(above, last, previous).astype(np.intp), columns]
        high = ordered[np.where(above, last, previous + 1).astype(np.intp), columns]
        gamma = virtual - np.where(above, -1.0, previous)
        difference = high - low
        value = np.where(gamma >= 0.5, high - difference * (1 - gamma), low + difference * gamma)
        out[i] = np.where(count > 0, value, np.nan)
    return out


def nan_median(stack: ArrayLike) -> FloatArray:
    """``np.nanmedian(stack, axis=0)`` for all columns at once (identical results)."""
    stack = np.asarray(stack, dtype=np.float64)
    if stack.shape[0] == 0:
        return np.full(stack.shape[1], np.nan)
    ordered = np.sort(stack, axis=0)
    count = np.count_nonzero(~np.isnan(stack), axis=0)
    columns = np.arange(stack.shape[1])
    low = ordered[np.maximum((count - 1) // 2, 0), columns]
    high = ordered[np.minimum(count // 2, stack.shape[0] - 1), columns]
    return np.where(count > 0, (low + high) / 2.0, np.nan)


class _MeanTraces(NamedTuple):
    """What a batch figure reads of a saved result: times and parameter means."""

    t: FloatArray
    parameter_names: tuple[str, ...]
    estimated: tuple[str, ...]
    mean: FloatArray

    def mean_of(self, name: str) -> FloatArray:
        return self.mean[:, self.parameter_names.index(name)]


def _mean_traces(path: Path) -> _MeanTraces:
    """The entries of a saved result (its documented ``.npz`` layout) a figure needs.

    A whole :func:`~manualcontrol.estimators.protocol.load_result` reads and validates
    all 17 traces, three times the bytes; over a suite's 800 runs (2.5 GB) that
    reading was half of the report's time.
    """
    # here, not at the top: the estimators load their whole family and scipy.signal
    from manualcontrol.estimators.protocol import RESULT_FORMAT

    with np.load(path, allow_pickle=False) as archive:
        tag = str(archive["result_format"]) if "result_format" in archive.files else None
        if tag != RESULT_FORMAT:
            raise ValueError(f"{path}: not a saved EstimationResult (result_format {tag!r})")
        return _MeanTraces(
            archive["t"],
            tuple(json.loads(str(archive["parameter_names"]))),
            tuple(json.loads(str(archive["estimated"]))),
            archive["mean"],
        )


def _comparison_table(
    summaries: Mapping[str, Mapping[str, Any]], reference: Mapping[str, Any]
) -> list[str]:
    """Parameters down, estimators across: NRMSE (relative bias), the paper's last.

    The smallest NRMSE of a row, and the largest VAF, are set in bold.
    """
    paper = dict(reference.get("parameters", {}))
    names: list[str] = []
    for summary in summaries.values():
        names += [n for n in summary["parameters"] if n not in names]
    names += [n for n in paper if n not in names]
    estimators = list(summaries)
    lines = [
        "| NRMSE (rel. bias) | " + " | ".join(estimators) + " | paper |",
        "| --- | " + " | ".join("---:" for _ in estimators) + " | ---: |",
    ]

    def best(values: list[float], largest: bool) -> float:
        finite = [v for v in values if math.isfinite(v)]
        if not finite:
            return math.nan
        return max(finite) if largest else min(finite)

    for name in names:
        values = [
            _number(summaries[e]["parameters"].get(name, {}).get("nrmse")) for e in estimators
        ]
        top = best(values, largest=False)
        cells = []
        for e, value in zip(estimators, values, strict=True):
            bias = summaries[e]["parameters"].get(name, {}).get("rel_bias")
            text = f"{_cell(value)} ({_cell(bias, True)})" if math.isfinite(value) else "—"
            cells.append(f"**{text}**" if value == top else text)
        theirs = paper.get(name, {})
        paper_cell = (
            f"{_cell(theirs.get('nrmse'))} ({_cell(theirs.get('rel_bias'), True)})"
            if theirs
            else "—"
        )
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {paper_cell} |")
    for key, label in (
        ("vaf_resimulated", "VAF resimulated vs u [%]"),
        ("vaf_resimulated_ideal", "VAF resimulated vs remnant-free u [%]"),
        ("vaf_one_step", "VAF one-step [%]"),
    ):
        values = [_number(summaries[e][key]) for e in estimators]
        paper_value = reference.get(key)
        if paper_value is None and not any(math.isfinite(v) for v in values):
            continue  # e.g. no remnant-free VAF without remnant
        top = best(values, largest=True)
        cells = [f"**{_cell(v)}**" if v == top and math.isfinite(v) else _cell(v) for v in values]
        lines.append(
            f"| {label} | "
            + " | ".join(cells)
            + f" | {'—' if paper_value is None else f'{paper_value:.2f}'} |"
        )
        ceilings = [_number(summaries[e].get(f"{key}_ceiling")) for e in estimators]
        if any(math.isfinite(v) for v in ceilings):
            lines.append(
                "| ceiling (true parameters) [%] | "
                + " | ".join(_cell(v) for v in ceilings)
                + " | |"
            )
    counts = [f"{summaries[e]['runs']} ({summaries[e]['diverged']} diverged)" for e in estimators]
    lines.append("| runs | " + " | ".join(counts) + " | |")
    return lines


def _ranking_score(summaries: Mapping[str, Mapping[str, Any]]) -> dict[str, float]:
    """Mean NRMSE of each estimator over the parameters every one of them estimates."""
    common: set[str] | None = None
    for summary in summaries.values():
        names = {
            name
            for name, values in summary["parameters"].items()
            if math.isfinite(_number(values.get("nrmse")))
        }
        common = names if common is None else common & names
    if not common:
        return {name: math.nan for name in summaries}
    return {
        name: float(np.mean([_number(summary["parameters"][p]["nrmse"]) for p in sorted(common)]))
        for name, summary in summaries.items()
    }


def best_estimators(suite: Suite, rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The report's ranking section: the best online and the best smoothed estimator.

    Per batch, estimators are ranked by their mean NRMSE over the parameters all of
    them estimate; online filters (results filtered sample by sample, what runs in real
    time) and smoothed ones (results that used the whole run) are ranked apart. The
    suite's best of each kind is the one best in most batches (ties: the lower mean
    NRMSE relative to each batch's best). Empty when no batch has a scored estimator.
    """
    table: list[str] = []
    wins: dict[str, dict[str, int]] = {"online": {}, "smoothed": {}}
    ratios: dict[str, dict[str, list[float]]] = {"online": {}, "smoothed": {}}
    for batch in suite.batches:
        present = sorted({row.get("estimator") for row in rows if row.get("batch") == batch.name})
        summaries = {
            name: summarise(rows, batch.name, name) for name in present if name is not None
        }
        cells = []
        for kind in ("online", "smoothed"):
            group = {
                name: summary
                for name, summary in summaries.items()
                if summary["runs"] > summary["failed"]
                and summary["smoothed"] == (kind == "smoothed")
            }
            scores = {k: v for k, v in _ranking_score(group).items() if math.isfinite(v)}
            if not scores:
                cells.append("—")
                continue
            best = min(scores, key=lambda name: (scores[name], name))
            wins[kind][best] = wins[kind].get(best, 0) + 1
            for name, value in scores.items():
                ratios[kind].setdefault(name, []).append(
                    value / scores[best] if scores[best] else 1.0
                )
            cells.append(f"{best} ({scores[best]:.3f})")
        if any(cell != "—" for cell in cells):
            table.append(f"| {batch.name} | {cells[0]} | {cells[1]} |")
    if not table:
        return []
    lines = [
        "## Best estimator",
        "",
        "Per batch, the estimator with the lowest mean NRMSE over the parameters every "
        "estimator of the batch estimates; online filters (each estimate from the samples "
        "up to it, as in real time) and smoothed results (from the whole run, offline) "
        "are ranked apart.",
        "",
        "| batch | best online (mean NRMSE) | best smoothed (mean NRMSE) |",
        "| --- | --- | --- |",
        *table,
        "",
    ]
    for kind in ("online", "smoothed"):
        if not wins[kind]:
            continue
        best = min(
            wins[kind],
            key=lambda name: (-wins[kind][name], float(np.mean(ratios[kind][name])), name),
        )
        batches = sum(wins[kind].values())
        lines.append(
            f"**Best {kind} estimator of the suite: {best}** (best in {wins[kind][best]} of "
            f"{batches} batches)."
        )
    lines.append("")
    return lines


def _load_results(out: Path, rows: Sequence[Mapping[str, Any]]) -> list[Any]:
    """The mean traces of the rows' saved results (see :func:`_mean_traces`)."""
    results = []
    for row in rows:
        path = out / "runs" / f"{row['key']}.npz"
        if path.is_file():
            results.append(_mean_traces(path))
    return results


_ESTIMATOR_COLOURS = ("k", "tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown")


def _comparison_figure(
    suite: Suite,
    batch: str,
    estimators: Sequence[str],
    rows: Sequence[Mapping[str, Any]],
    out: Path,
) -> Path | None:
    """Each estimator's median trace and 25-75 % band per parameter, against the truth."""
    ok = [row for row in rows if row.get("batch") == batch and row.get("status") == "ok"]
    by_estimator = {
        name: _load_results(out, [row for row in ok if row.get("estimator") == name])
        for name in estimators
    }
    by_estimator = {name: results for name, results in by_estimator.items() if results}
    if not by_estimator:
        return None
    first = next(iter(by_estimator.values()))[0]
    names: list[str] = []
    for results in by_estimator.values():
        names += [n for n in results[0].estimated if n not in names]
    from manualcontrol.bench.scenarios import scenario_from_dict

    scenario = scenario_from_dict(ok[0]["scenario"])
    truth = {
        name: schedule(first.t) for name, schedule in scenario.build_pilot().parameters.items()
    }
    fig, axes = subplots(
        len(names), 1, reusable=True, figsize=(9, 1.8 * len(names) + 0.6), sharex=True
    )
    axes = np.atleast_1d(axes)
    for axis, name in zip(axes, names, strict=True):
        if name in truth:
            draw_trace(axis, first.t, truth[name], color="tab:red", lw=1.2, label="true")
        for colour, (estimator, results) in zip(
            _ESTIMATOR_COLOURS, by_estimator.items(), strict=False
        ):
            same = [r for r in results if len(r.t) == len(first.t) and name in r.estimated]
            if not same:
                continue
            stack = np.array([r.mean_of(name) for r in same])
            median = nan_median(stack)
            label = f"{estimator} (median of {len(stack)})" if len(stack) > 1 else estimator
            if len(stack) > 1:
                low, high = nan_percentiles(stack, [25, 75])
                _band(axis, first.t, low, high, color=colour, alpha=0.15, lw=0)
            draw_trace(axis, first.t, median, color=colour, lw=1.0, label=label)
        axis.set_ylabel(_unit(name))
    axes[0].legend(loc="upper right", fontsize=7, ncol=2)
    axes[0].set_title(f"{suite.name}: {batch} (bands: 25-75 % of the runs)")
    axes[-1].set_xlabel("time [s]")
    return save_figure(fig, out / "figures" / f"{batch}-estimators.png")


def _trace_figure(
    suite: Suite, batch: str, rows: Sequence[Mapping[str, Any]], out: Path
) -> Path | None:
    ok = [row for row in rows if row.get("batch") == batch and row.get("status") == "ok"]
    results = []
    for row in ok:
        path = out / "runs" / f"{row['key']}.npz"
        if path.is_file():
            results.append(_mean_traces(path))
    if not results:
        return None
    first = results[0]
    names = list(first.estimated)
    from manualcontrol.bench.scenarios import scenario_from_dict

    scenario = scenario_from_dict(ok[0]["scenario"])
    pilot = scenario.build_pilot().parameters if scenario.system is None else {}
    truth = {name: schedule(first.t) for name, schedule in pilot.items()}
    rows_in_figure = len(names) + 1
    fig, axes = subplots(
        rows_in_figure, 1, reusable=True, figsize=(9, 1.7 * rows_in_figure), sharex=True
    )
    axes = np.atleast_1d(axes)
    for axis, name in zip(axes, names, strict=False):
        stack = np.array(
            [result.mean_of(name) for result in results if len(result.t) == len(first.t)]
        )
        median = nan_median(stack)
        if len(stack) > 1:  # a band of one run would be a line mislabelled as a spread
            low, high = nan_percentiles(stack, [25, 75])
            _band(axis, first.t, low, high, color="k", alpha=0.2, lw=0, label="25-75 %")
            draw_trace(axis, first.t, median, color="k", lw=1.0, label=f"median of {len(stack)}")
        else:
            draw_trace(axis, first.t, median, color="k", lw=1.0, label="estimate (one run)")
        if name in truth:
            draw_trace(axis, first.t, truth[name], color="tab:red", lw=1.0, label="true")
        axis.set_ylabel(name)
    axes[0].legend(loc="upper right", fontsize=8)
    moving = [row.get("moving_vaf") for row in ok if row.get("moving_vaf")]
    if moving:
        length = min(len(m) for m in moving)
        stack = np.array([m[:length] for m in moving], dtype=float)
        times = np.asarray(ok[0].get("moving_vaf_t", np.arange(length)))[:length]
        quartiles = nan_percentiles(stack, [25, 75])  # NaN over the first 10 s
        median = nan_median(stack)
        finite = quartiles[0][np.isfinite(quartiles[0])]
        lowest = float(finite.min()) if finite.size else math.nan  # no window complete
        if len(stack) > 1:
            _band(axes[-1], times, *quartiles, color="tab:blue", alpha=0.2, lw=0)
        draw_trace(axes[-1], times, median, color="tab:blue", lw=1.0)
        axes[-1].set_ylim(max(0.0, lowest - 5.0), 101.0)
    axes[-1].set_ylabel("10-s VAF [%]")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(f"{suite.name}: {batch}")
    return save_figure(fig, out / "figures" / f"{batch}.png")


def write_report(suite: Suite, rows: Sequence[Mapping[str, Any]], out: str | Path) -> Path:
    """Write ``report.md`` (and figures) for a suite's results in ``out``."""
    with _reusing_figures():
        return _write_report(suite, rows, Path(out))


def _write_report(suite: Suite, rows: Sequence[Mapping[str, Any]], out: Path) -> Path:
    lines = [f"# {suite.name}", "", suite.description, ""]
    ok = [row for row in rows if row.get("status") == "ok"]
    runtime = sum(_number(row.get("run_time_s")) for row in ok)
    lines += [
        f"{len(rows)} runs, {len(rows) - len(ok)} failed; {runtime:.0f} s of run time in total.",
        "",
        *VAF_DEFINITIONS,
        "",
    ]
    drawn = [batch for batch in suite.batches if summarise(rows, batch.name)["runs"]]
    for number, batch in enumerate(drawn, start=1):
        report_progress(f"report: batch {number} of {len(drawn)}, {batch.name}")
        summary = summarise(rows, batch.name)
        reference = dict(batch.reference)
        source = reference.get("source", "")
        present = {row.get("estimator") for row in rows if row.get("batch") == batch.name}
        estimators = [name for name in batch.estimator_names if name in present]
        estimators += sorted(name for name in present if name not in estimators and name)
        lines += [f"## {batch.name}", ""]
        if len(estimators) > 1:
            summaries = {name: summarise(rows, batch.name, name) for name in estimators}
            runs = summaries[estimators[0]]["runs"]
            lines += [
                f"{_runs(runs)} simulated, each identified by {len(estimators)} estimators "
                f"({', '.join(estimators)})" + (f"; paper: {source}" if source else ""),
                "",
                *_comparison_table(summaries, reference),
                "",
            ]
            figure = _comparison_figure(suite, batch.name, estimators, rows, out)
        else:
            lines += [
                f"{_runs(summary['runs'])} ({summary['failed']} failed, "
                f"{summary['diverged']} diverged)"
                + (f", estimator {estimators[0]}" if estimators else "")
                + (f"; paper: {source}" if source else ""),
                "",
                *_batch_table(summary, reference),
                "",
            ]
            figure = _trace_figure(suite, batch.name, rows, out)
        if figure is not None:
            lines += [f"![{batch.name}](figures/{figure.name})", ""]
    lines += best_estimators(suite, rows)
    writer = section_writer(suite.name)
    if writer is not None:
        lines += [*writer(suite, rows, out), ""]
    failed = [row for row in rows if row.get("status") != "ok"]
    if failed:
        lines += ["## Failed runs", ""]
        lines += [f"- `{row['key']}`: {row.get('error', '')}" for row in failed]
        lines.append("")
    text = "\n".join(lines)
    path = atomic_write(out / "report.md", lambda p: p.write_text(text))
    try:
        import markdown
    except ImportError:
        return path
    html = markdown.markdown(text, extensions=["tables"])
    atomic_write(out / "report.html", lambda p: p.write_text(f"<html><body>{html}</body></html>"))
    return path
