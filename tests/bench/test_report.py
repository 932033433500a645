"""Report statistics: the vectorised NaN-aware percentiles equal numpy's, bit for bit."""

import warnings

import numpy as np
import pytest

from manualcontrol.bench.report import nan_median, nan_percentiles


def _numpy(stack, percentiles):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        return np.nanpercentile(stack, percentiles, axis=0), np.nanmedian(stack, axis=0)


@pytest.mark.parametrize("seed", range(12))
def test_equal_to_numpy_with_nans(seed):
    rng = np.random.default_rng(seed)
    runs, samples = int(rng.integers(1, 60)), int(rng.integers(1, 400))
    stack = rng.standard_normal((runs, samples)) * 10.0 ** rng.uniform(-3, 3)
    stack[rng.random(stack.shape) < rng.uniform(0.0, 0.6)] = np.nan
    stack[:, :2] = np.nan  # all-NaN columns (the first 10 s of a moving VAF)
    stack[:, 2] = 1.5  # ties
    percentiles = [0, 10, 25, 50, 75, 99.9, 100]
    expected, median = _numpy(stack, percentiles)
    np.testing.assert_array_equal(nan_percentiles(stack, percentiles), expected)
    np.testing.assert_array_equal(nan_median(stack), median)


def test_empty_stack_gives_nan():
    assert np.all(np.isnan(nan_percentiles(np.zeros((0, 3)), [25, 75])))
    assert np.all(np.isnan(nan_median(np.zeros((0, 3)))))


def test_a_thinned_trace_keeps_every_extreme_in_time_order():
    from manualcontrol.bench.report import thin_band, thin_trace

    rng = np.random.default_rng(3)
    t = np.arange(22_000) * 0.01
    values = np.cumsum(rng.standard_normal(t.size))
    values[5000] = 1e3  # a one-sample spike
    values[8000:8100] = np.nan  # a gap longer than a bucket
    kept_t, kept = thin_trace(t, values, buckets=2000)
    assert len(kept) <= 2 * 2000 + 11 and np.all(np.diff(kept_t) >= 0)
    assert np.nanmax(kept) == 1e3 and np.nanmin(kept) == np.nanmin(values)
    assert np.isnan(kept).any()  # the gap stays a gap
    # every kept point is a sample of the trace, and each bucket's extremes are kept
    index = np.searchsorted(t, kept_t)
    np.testing.assert_array_equal(kept, values[index])
    bucket = values[11 * 7 : 11 * 8]
    assert bucket.max() in kept and bucket.min() in kept
    short = np.arange(100.0)
    np.testing.assert_array_equal(thin_trace(short, short)[1], short)  # too short to thin
    low, high = values - 1.0, values + 1.0
    band_t, band_low, band_high = thin_band(t, low, high, buckets=2000)
    assert np.all(np.diff(band_t) >= 0)
    # the drawn band covers the full one: each sample lies within its bucket's edges
    for k in (0, 4999, 5000, 12_345, 21_999):
        at = np.searchsorted(band_t, t[k], side="right") - 1
        assert band_low[at] <= low[k] and band_high[at] >= high[k]


def _draw(axes, variant):
    """Panels in the ways the report draws them; ``variant`` changes every kind of content."""
    t = np.linspace(0.0, 40.0 - 10.0 * variant, 600)  # shorter: stale x limits would show
    for row, axis in enumerate(axes[:-1]):
        scale = (row + 1) * (1.0 + variant)
        axis.fill_between(t, np.sin(t) * scale - 0.3, np.sin(t) * scale + 0.3, alpha=0.2, lw=0)
        for k in range(2 + variant):  # lines without a colour take the colour cycle
            axis.plot(t, np.cos(t / (k + 1)) * scale, lw=0.8, label=f"line {k}")
        axis.set_ylabel(f"p{row}" if variant == 0 else f"parameter {row} [s]")
    if variant == 0:
        axes[-1].plot(t, 50.0 + t, color="tab:blue")
        axes[-1].set_ylim(20.0, 101.0)
        axes[0].set_title("first", loc="left", fontsize=8)
        axes[0].text(0.5, 0.5, "note", transform=axes[0].transAxes)
    # variant 1 leaves the last panel empty: a new figure's limits must come back
    axes[0].legend(loc="upper right", fontsize=7)
    axes[0].set_title(f"figure {variant}")
    axes[-1].set_xlabel("time [s]")


def test_a_reused_figure_draws_what_a_new_one_draws(tmp_path):
    from manualcontrol.bench.report import _reusing_figures, pyplot, save_figure, subplots

    plt = pyplot()
    before = set(plt.get_fignums())
    layout = {"reusable": True, "figsize": (6.0, 5.0), "sharex": True}
    with _reusing_figures():
        fig, axes = subplots(3, 1, **layout)
        _draw(axes, 0)
        save_figure(fig, tmp_path / "first.png")
        again, axes = subplots(3, 1, **layout)
        assert again is fig  # handed out again, not made anew
        _draw(axes, 1)
        save_figure(again, tmp_path / "reused.png")
        other, _ = subplots(2, 1, **layout)  # another layout gets a figure of its own
        assert other is not fig
    assert set(plt.get_fignums()) == before  # all closed on leaving, unsaved ones too
    fig, axes = subplots(3, 1, **layout)
    _draw(axes, 1)
    save_figure(fig, tmp_path / "new.png")
    assert (tmp_path / "reused.png").read_bytes() == (tmp_path / "new.png").read_bytes()
    assert (tmp_path / "first.png").read_bytes() != (tmp_path / "new.png").read_bytes()


def test_figures_are_closed_when_a_report_fails(tmp_path):
    from manualcontrol.bench.report import _reusing_figures, pyplot, subplots

    plt = pyplot()
    before = set(plt.get_fignums())
    with pytest.raises(RuntimeError, match="drawing failed"), _reusing_figures():
        subplots(2, 1)
        raise RuntimeError("drawing failed")
    assert set(plt.get_fignums()) == before


def test_only_plain_reusable_figures_are_kept(tmp_path):
    from manualcontrol.bench.report import _reusing_figures, pyplot, save_figure, subplots

    plt = pyplot()
    before = set(plt.get_fignums())
    with _reusing_figures():
        fig, _ = subplots(2, 1)  # not marked reusable (a public plot_* figure)
        save_figure(fig, tmp_path / "a.png")
        assert not plt.fignum_exists(fig.number)  # closed at once
        for change in (
            lambda f, a: f.suptitle("figure title"),
            lambda f, a: a[0].set_yscale("log"),
            lambda f, a: a[0].twinx(),
            lambda f, a: a[1].set_yticks([0.0, 0.5]),
        ):
            fig, axes = subplots(2, 1, reusable=True)
            change(fig, axes)
            save_figure(fig, tmp_path / "b.png")
            assert not plt.fignum_exists(fig.number)  # _clear would not undo it
        fig, _ = subplots(2, 1, reusable=True)
        save_figure(fig, tmp_path / "c.png")
        save_figure(fig, tmp_path / "c.png")  # saved twice: kept once, handed out once
        assert subplots(2, 1, reusable=True)[0] is fig
        assert subplots(2, 1, reusable=True)[0] is not fig
    assert set(plt.get_fignums()) == before


def test_measured_phases_are_drawn_on_the_fitted_models_branch():
    from manualcontrol.bench.report import nearest_branch

    # a line buried in remnant read -100 deg where the model, a turn further on, is at
    # -470: drawn at -460; lines already beside the model stay where they are
    moved = nearest_branch([-30.0, -253.0, -100.0, 190.0], [-25.0, -300.0, -470.0, -160.0])
    np.testing.assert_allclose(moved, [-30.0, -253.0, -460.0, -170.0])
