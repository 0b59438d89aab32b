"""Tests of the protocol figures drawn from the summary tables."""

import sys

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("matplotlib")

from matplotlib.figure import Figure  # noqa: E402
from matplotlib.image import imread  # noqa: E402
from matplotlib.patches import PathPatch  # noqa: E402

from skcath.protocol import _figures as figures  # noqa: E402

CATHETERS = ("C1", "C2", "C3", "C4")
MAIN = ("PCC", "PDL", "PDL+GRU")
ALL_METHODS = {
    "PCC": 8.0,
    "PDL": 5.0,
    "PDL+GRU": 2.5,
    "PDL+MLP": 3.2,
    "PDL+GRU (no torque)": 3.0,
    "PDL+GRU (no context)": 3.3,
    "PDL+GRU (no torque, no context)": 3.8,
    "PDL+GRU (LOCO)": 4.0,
}
COMPARISONS = (
    "PDL -> PDL+GRU",
    "PDL+MLP -> PDL+GRU",
    "torque (with context)",
    "context (with torque)",
)


# ---------------------------------------------------------------------------
# synthetic summary tables in the protocol's formats
# ---------------------------------------------------------------------------
def make_run_rmse(seed=0, n_settings=6, loco_catheters=("C1", "C2", "C3")):
    """Per-run RMSE (mm) of every method; the LOCO method on some catheters only."""
    rng = np.random.default_rng(seed)
    rows = []
    for method, scale in ALL_METHODS.items():
        catheters = loco_catheters if method == "PDL+GRU (LOCO)" else CATHETERS
        for number, catheter in enumerate(CATHETERS):
            if catheter not in catheters:
                continue
            for k in range(n_settings):
                rmse = scale * (1.0 + 0.1 * number) * rng.lognormal(0.0, 0.35)
                rows.append((method, catheter, f"S{k:02d}", f"{catheter}-R{k:02d}", rmse))
    return pd.DataFrame(rows, columns=["method", "catheter", "setting", "run", "rmse_mm"])


def make_cdf(step=0.25, stop=30.0):
    """Weibull-shaped error CDFs on a common grid (mm)."""
    grid = np.arange(0.0, stop + step / 2, step)
    frames = []
    for method, scale in ALL_METHODS.items():
        fraction = 1.0 - np.exp(-((grid / scale) ** 1.6))
        frames.append(pd.DataFrame({"method": method, "error_mm": grid, "fraction": fraction}))
    return pd.concat(frames, ignore_index=True)


def make_bins(seed, stop, slope, n_runs=12, methods=MAIN):
    """Run-bin RMSE (mm) in 10-unit bins from 0 to ``stop``."""
    rng = np.random.default_rng(seed)
    lefts = np.arange(0.0, stop, 10.0)
    rows = []
    for method in methods:
        scale = ALL_METHODS[method]
        for run in range(n_runs):
            for left in lefts:
                rmse = scale * (1.0 + slope * left) * rng.lognormal(0.0, 0.3)
                rows.append((method, f"R{run:02d}", left, left + 10.0, rmse))
    return pd.DataFrame(rows, columns=["method", "run", "bin_left", "bin_right", "rmse_mm"])


def make_paired(seed=3):
    """Mean reductions (mm) with confidence intervals for every comparison and scope."""
    rng = np.random.default_rng(seed)
    rows = []
    for number, comparison in enumerate(COMPARISONS):
        for scope in (*CATHETERS, "pooled"):
            reduction = (2.0 - 0.4 * number) + rng.normal(0.0, 0.3)
            half = 0.3 if scope == "pooled" else rng.uniform(0.4, 0.9)
            rows.append(
                (
                    comparison,
                    scope,
                    reduction,
                    reduction - half,
                    reduction + half,
                    100.0 * reduction / 5.0,
                    float(rng.uniform(0.6, 1.0)),
                )
            )
    columns = list(figures.TABLE_COLUMNS["paired"])
    return pd.DataFrame(rows, columns=columns)


def make_example(seed=4, duration=60.0):
    """One motion run at 10 Hz: a smooth tip path (mm) and a noisy biased estimate."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 0.1)
    p = np.column_stack(
        [
            30.0 * np.sin(2 * np.pi * t / 20.0),
            20.0 * np.sin(2 * np.pi * t / 13.0),
            80.0 - 0.01 * (30.0 * np.sin(2 * np.pi * t / 20.0)) ** 2,
        ]
    )
    phat = p + np.array([0.8, -0.5, 0.3]) + rng.normal(0.0, 1.0, p.shape)
    columns = list(figures.TABLE_COLUMNS["example"])
    frame = pd.DataFrame(np.column_stack([t, p, phat]), columns=columns)
    frame.attrs.update({"run": "C2-R03", "method": "PDL+GRU", "rmse_mm": 1.87})
    return frame


@pytest.fixture(scope="module")
def tables():
    return {
        "run_rmse": make_run_rmse(),
        "cdf": make_cdf(),
        "magnitude_bins": make_bins(1, 180.0, 0.01),
        "time_bins": make_bins(2, 300.0, 0.002),
        "paired": make_paired(),
        "example": make_example(),
    }


def _legend_texts(figure):
    texts = []
    for legend in [*figure.legends, *(ax.get_legend() for ax in figure.axes)]:
        if legend is not None:
            texts.extend(text.get_text() for text in legend.get_texts())
    return texts


def _boxes(ax):
    return [patch for patch in ax.patches if isinstance(patch, PathPatch)]


def _copy(table):
    copy = table.copy(deep=True)
    copy.attrs = dict(table.attrs)
    return copy


# ---------------------------------------------------------------------------
# per-run RMSE boxes
# ---------------------------------------------------------------------------
def test_rmse_boxes_groups_and_legend(tables):
    figure = figures.plot_rmse_boxes(tables["run_rmse"])
    assert isinstance(figure, Figure)
    (ax,) = figure.axes
    assert [label.get_text() for label in ax.get_xticklabels()] == [*CATHETERS, "pooled"]
    assert len(_boxes(ax)) == 5 * 3
    assert _legend_texts(figure) == list(MAIN)
    assert "mm" in ax.get_ylabel()
    assert tuple(figure.get_size_inches()) == (8.0, 4.5)


def test_rmse_boxes_medians_match_the_data(tables):
    run_rmse = tables["run_rmse"]
    figure = figures.plot_rmse_boxes(run_rmse, methods=("PDL",))
    (ax,) = figure.axes
    medians = sorted(
        line.get_ydata()[0]
        for line in ax.get_lines()
        if len(line.get_ydata()) == 2 and line.get_color() == "black"
    )
    rows = run_rmse[run_rmse["method"] == "PDL"]
    expected = sorted([*rows.groupby("catheter")["rmse_mm"].median(), rows["rmse_mm"].median()])
    np.testing.assert_allclose(medians, expected)


def test_rmse_boxes_tick_labels_do_not_overlap(tables):
    figure = figures.plot_rmse_boxes(tables["run_rmse"])
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    (ax,) = figure.axes
    boxes = [label.get_window_extent(renderer) for label in ax.get_xticklabels()]
    for left, right in zip(boxes, boxes[1:]):
        assert left.x1 < right.x0


def test_rmse_boxes_skip_absent_methods_and_catheters(tables):
    run_rmse = tables["run_rmse"]
    figure = figures.plot_rmse_boxes(run_rmse, methods=("PCC", "no such method", "PDL+GRU"))
    assert _legend_texts(figure) == ["PCC", "PDL+GRU"]
    assert len(_boxes(figure.axes[0])) == 5 * 2
    # the held-out-catheter method covers C1-C3 only: 4 boxes (3 catheters + pooled)
    figure = figures.plot_rmse_boxes(run_rmse, methods=figures.NEW_CATHETER_METHODS)
    assert _legend_texts(figure) == list(figures.NEW_CATHETER_METHODS)
    assert len(_boxes(figure.axes[0])) == 5 + 4
    figure = figures.plot_rmse_boxes(run_rmse, methods="PDL+MLP")
    assert len(_boxes(figure.axes[0])) == 5
    with pytest.raises(ValueError, match="None of the requested methods"):
        figures.plot_rmse_boxes(run_rmse, methods=("XYZ", "ABC"))


def test_rmse_boxes_natural_catheter_order():
    frame = make_run_rmse(n_settings=3)
    frame["catheter"] = frame["catheter"].map({"C1": "C10", "C2": "C2", "C3": "C1", "C4": "C3"})
    figure = figures.plot_rmse_boxes(frame)
    labels = [label.get_text() for label in figure.axes[0].get_xticklabels()]
    assert labels == ["C1", "C2", "C3", "C10", "pooled"]


def test_rmse_boxes_rejects_duplicate_runs_and_infinite_values(tables):
    run_rmse = tables["run_rmse"]
    doubled = pd.concat([run_rmse, run_rmse.iloc[:2]], ignore_index=True)
    with pytest.raises(ValueError, match="one row per"):
        figures.plot_rmse_boxes(doubled)
    bad = run_rmse.copy()
    bad.loc[0, "rmse_mm"] = np.inf
    with pytest.raises(ValueError, match="'rmse_mm'.*'run_rmse'"):
        figures.plot_rmse_boxes(bad)
    text = run_rmse.astype({"rmse_mm": str})
    with pytest.raises(ValueError, match="must hold numbers"):
        figures.plot_rmse_boxes(text)


# ---------------------------------------------------------------------------
# error CDF
# ---------------------------------------------------------------------------
def test_error_cdf_legend_gives_fraction_at_mark(tables):
    cdf = tables["cdf"]
    figure = figures.plot_error_cdf(cdf, mark_mm=5.0)
    (ax,) = figure.axes
    texts = _legend_texts(figure)
    assert len(texts) == 3
    for method, text in zip(MAIN, texts):
        rows = cdf[cdf["method"] == method]
        fraction = np.interp(5.0, rows["error_mm"], rows["fraction"])
        assert text.startswith(method)
        assert f"{100 * fraction:.1f}%" in text
        assert figures.cdf_fraction_at(cdf, method, 5.0) == pytest.approx(fraction)
    marker_lines = [line for line in ax.get_lines() if list(line.get_xdata()) == [5.0, 5.0]]
    assert len(marker_lines) == 1
    assert ax.get_xlabel() == "Tip error (mm)"


def test_error_cdf_between_grid_points_and_without_marker(tables):
    cdf = tables["cdf"]
    pdl = cdf[cdf["method"] == "PDL"]
    expected = np.interp(4.1, pdl["error_mm"], pdl["fraction"])
    texts = _legend_texts(figures.plot_error_cdf(cdf, methods=("PDL",), mark_mm=4.1))
    assert texts == [f"PDL: {100 * expected:.1f}% within 4.1 mm"]
    assert _legend_texts(figures.plot_error_cdf(cdf, mark_mm=None)) == list(MAIN)


def test_error_cdf_rejects_bad_values(tables):
    cdf = tables["cdf"].copy()
    cdf.loc[3, "fraction"] = 1.5
    with pytest.raises(ValueError, match="'fraction'.*between 0 and 1"):
        figures.plot_error_cdf(cdf)
    with pytest.raises(ValueError, match="mark_mm"):
        figures.plot_error_cdf(tables["cdf"], mark_mm=-1.0)


# ---------------------------------------------------------------------------
# binned errors
# ---------------------------------------------------------------------------
def _line_for(figure, method):
    index = _legend_texts(figure).index(method)
    lines = [
        line
        for line in figure.axes[0].get_lines()
        if line.get_marker() == "o" and len(line.get_xdata()) > 2
    ]
    return lines[index]


def test_error_by_magnitude_median_line_and_sparse_boxes(tables):
    bins = tables["magnitude_bins"]
    figure = figures.plot_error_by_magnitude(bins, box_every=3)
    (ax,) = figure.axes
    assert _legend_texts(figure) == list(MAIN)
    assert len(_boxes(ax)) == 3 * len(range(0, 18, 3))
    line = _line_for(figure, "PDL")
    rows = bins[bins["method"] == "PDL"]
    expected = rows.groupby("bin_left")["rmse_mm"].median()
    np.testing.assert_allclose(line.get_xdata(), expected.index + 5.0)
    np.testing.assert_allclose(line.get_ydata(), expected.to_numpy())
    assert "(deg)" in ax.get_xlabel()


def test_error_over_time_mean_line_and_every_fourth_box(tables):
    bins = tables["time_bins"]
    figure = figures.plot_error_over_time(bins, methods=("PDL+GRU", "missing", "PCC"))
    (ax,) = figure.axes
    assert _legend_texts(figure) == ["PDL+GRU", "PCC"]
    # 30 bins of 10 s: a box at every 4th bin by default, 8 positions
    assert len(_boxes(ax)) == 2 * 8
    line = _line_for(figure, "PCC")
    expected = bins[bins["method"] == "PCC"].groupby("bin_left")["rmse_mm"].mean()
    np.testing.assert_allclose(line.get_ydata(), expected.to_numpy())
    assert "(s)" in ax.get_xlabel()


def test_binned_rejects_bad_bins(tables):
    bins = tables["time_bins"].copy()
    bins.loc[0, "bin_right"] = bins.loc[0, "bin_left"]
    with pytest.raises(ValueError, match="bin_right > bin_left"):
        figures.plot_error_over_time(bins)
    with pytest.raises(ValueError, match="box_every"):
        figures.plot_error_by_magnitude(tables["magnitude_bins"], box_every=0)


# ---------------------------------------------------------------------------
# motion example
# ---------------------------------------------------------------------------
def test_motion_example_panels(tables):
    example = tables["example"]
    figure = figures.plot_motion_example(example)
    ax_xy, ax_xz, ax_err = figure.axes
    assert ax_xy.get_aspect() == 1.0 and ax_xz.get_aspect() == 1.0
    spans = [np.ptp(limits) for ax in (ax_xy, ax_xz) for limits in (ax.get_xlim(), ax.get_ylim())]
    np.testing.assert_allclose(spans, spans[0])
    labels = (ax_xy.get_xlabel(), ax_xy.get_ylabel(), ax_xz.get_ylabel())
    assert labels == ("x (mm)", "y (mm)", "z (mm)")
    p = example[["p_x", "p_y", "p_z"]].to_numpy()
    errors = example[["phat_x", "phat_y", "phat_z"]].to_numpy() - p
    error_lines = [line for line in ax_err.get_lines() if line.get_label() in ("x", "y", "z")]
    assert len(error_lines) == 3
    for k, line in enumerate(error_lines):
        np.testing.assert_allclose(line.get_ydata(), errors[:, k])
    title = figure.get_suptitle()
    assert "C2-R03" in title and "PDL+GRU" in title and "1.87 mm" in title
    assert ax_err.get_xlabel() == "Time (s)"


def test_motion_example_with_tracker_dropouts():
    example = make_example().sample(frac=1.0, random_state=0)
    example.attrs = {}
    example.loc[example.index[:20], ["p_x", "p_y", "p_z"]] = np.nan
    before = _copy(example)
    figure = figures.plot_motion_example(example)
    assert "tip RMSE" in figure.get_suptitle()
    pd.testing.assert_frame_equal(example, before)
    empty = example.copy()
    empty[["p_x", "p_y", "p_z"]] = np.nan
    with pytest.raises(ValueError, match="measured tip position"):
        figures.plot_motion_example(empty)


# ---------------------------------------------------------------------------
# paired reductions
# ---------------------------------------------------------------------------
def test_paired_reductions_rows_and_emphasis(tables):
    paired = tables["paired"]
    figure = figures.plot_paired_reductions(paired)
    (ax,) = figure.axes
    labels = ax.get_yticklabels()
    assert len(labels) == len(COMPARISONS) * 5
    assert [label.get_text() for label in labels[:5]] == [*CATHETERS, "pooled"]
    bold = [label.get_text() for label in labels if label.get_fontweight() == "bold"]
    assert bold == ["pooled"] * len(COMPARISONS)
    assert _legend_texts(figure) == list(COMPARISONS)
    assert any(list(line.get_xdata()) == [0.0, 0.0] for line in ax.get_lines())


def test_paired_reductions_selects_comparisons(tables):
    paired = tables["paired"]
    chosen = ["context (with torque)", "absent", "PDL -> PDL+GRU"]
    figure = figures.plot_paired_reductions(paired, comparisons=chosen)
    assert _legend_texts(figure) == ["context (with torque)", "PDL -> PDL+GRU"]
    assert len(figure.axes[0].get_yticklabels()) == 10
    with pytest.raises(ValueError, match="None of the requested comparisons"):
        figures.plot_paired_reductions(paired, comparisons=["absent"])
    bad = paired.copy()
    bad.loc[0, "ci_low_mm"] = bad.loc[0, "ci_high_mm"] + 1.0
    with pytest.raises(ValueError, match="ci_low_mm <= ci_high_mm"):
        figures.plot_paired_reductions(bad)


# ---------------------------------------------------------------------------
# shared validation
# ---------------------------------------------------------------------------
PLOTTERS = {
    "run_rmse": figures.plot_rmse_boxes,
    "cdf": figures.plot_error_cdf,
    "magnitude_bins": figures.plot_error_by_magnitude,
    "time_bins": figures.plot_error_over_time,
    "paired": figures.plot_paired_reductions,
    "example": figures.plot_motion_example,
}
CASES = [(name, column) for name, columns in figures.TABLE_COLUMNS.items() for column in columns]


@pytest.mark.parametrize(("name", "column"), CASES)
def test_missing_column_is_named(tables, name, column):
    table = tables[name].drop(columns=column)
    with pytest.raises(ValueError, match=rf"'{name}' table lacks the column\(s\) '{column}'"):
        PLOTTERS[name](table)


@pytest.mark.parametrize("name", list(PLOTTERS))
def test_not_a_frame_or_empty(tables, name):
    with pytest.raises(ValueError, match=f"'{name}' table must be a pandas DataFrame"):
        PLOTTERS[name](tables[name].to_dict())
    with pytest.raises(ValueError, match=f"'{name}' table is empty"):
        PLOTTERS[name](tables[name].iloc[:0])


@pytest.mark.parametrize("name", list(PLOTTERS))
def test_inputs_are_not_modified(tables, name):
    table = tables[name]
    before = _copy(table)
    figure = PLOTTERS[name](table)
    figure.canvas.draw()
    pd.testing.assert_frame_equal(table, before)
    assert table.attrs == before.attrs


def test_missing_matplotlib_names_the_extra(tables, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    monkeypatch.setitem(sys.modules, "matplotlib.backends.backend_agg", None)
    with pytest.raises(ImportError, match=r'pip install "skcath\[plot\]"'):
        figures.plot_error_cdf(tables["cdf"])


# ---------------------------------------------------------------------------
# writing the PNG files
# ---------------------------------------------------------------------------
def _check_png(path):
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 150 and image.shape[1] > 250
    assert float(np.std(image[..., :3])) > 0.02


def test_write_figures_writes_every_figure(tables, tmp_path):
    out_dir = tmp_path / "figures" / "nested"
    paths = figures.write_figures(tables, out_dir, dpi=40)
    assert [path.name for path in paths] == list(figures.FIGURE_FILES)
    assert sorted(p.name for p in out_dir.iterdir()) == sorted(figures.FIGURE_FILES)
    for path in paths:
        _check_png(path)
    # 8 x 4.5 in at 40 dpi
    assert imread(paths[0]).shape[:2] == (180, 320)


def test_write_figures_skips_missing_tables_and_methods(tables, tmp_path):
    run_rmse = tables["run_rmse"]
    main_only = run_rmse[run_rmse["method"].isin(MAIN)]
    paths = figures.write_figures(
        {"run_rmse": main_only, "cdf": tables["cdf"], "example": tables["example"], "paired": None},
        tmp_path,
        dpi=30,
    )
    names = [path.name for path in paths]
    assert names == ["rmse_boxes.png", "error_cdf.png", "motion_example.png"]
    for path in paths:
        assert float(np.std(imread(path)[..., :3])) > 0.02
    with_variant = run_rmse[run_rmse["method"].isin([*MAIN, "PDL+GRU (no torque)", "PDL+MLP"])]
    paths = figures.write_figures({"run_rmse": with_variant}, tmp_path / "variant", dpi=20)
    expected = ["rmse_boxes.png", "residual_learners.png", "conditioning.png"]
    assert [path.name for path in paths] == expected
    assert figures.write_figures({}, tmp_path / "none") == []
    with pytest.raises(ValueError, match="Unknown table name"):
        figures.write_figures({"runs": run_rmse}, tmp_path)
    with pytest.raises(ValueError, match="dpi"):
        figures.write_figures({"cdf": tables["cdf"]}, tmp_path, dpi=0)
    with pytest.raises(ValueError, match="'cdf' table lacks the column"):
        figures.write_figures({"cdf": tables["cdf"].drop(columns="fraction")}, tmp_path)
