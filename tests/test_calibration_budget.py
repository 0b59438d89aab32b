"""Reduced calibration budget: reduce_sweep, backbones on reduced sweeps, the experiment."""

import importlib.util
import sys

import numpy as np
import pandas as pd
import pytest
from sklearn.utils._param_validation import InvalidParameterError

from skcath._cli import main
from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse
from skcath.sweep import find_rays, reduce_sweep

SETTINGS = ("S00", "S01", "S02")
HAS_MATPLOTLIB = importlib.util.find_spec("matplotlib") is not None


@pytest.fixture(scope="module")
def bench():
    """Two catheters, one run of settings S00-S02 each (six runs)."""
    data = make_benchmark(n_catheters=2, n_runs=1)
    keep = data.X["setting"].astype(str).isin(SETTINGS).to_numpy()
    return data.X[keep].reset_index(drop=True), np.asarray(data.y, dtype=float)[keep]


@pytest.fixture(scope="module")
def one_run(bench):
    """The first run of ``bench``, with its index labels shifted (not a RangeIndex)."""
    X, y = bench
    rows = (X["run"] == X["run"].iloc[0]).to_numpy()
    X1 = X[rows].copy()
    X1.index = X1.index + 1000
    return X1, y[rows]


def _sweep(X):
    return X[X["phase"] == "sweep"]


def _rays(X, n_rays, spacing=45.0):
    return find_rays(_sweep(X)[["q1", "q2"]].to_numpy(), n_rays=n_rays, ray_spacing_deg=spacing)


def _directions_deg(rays):
    return np.sort(np.round(rays.directions_deg) % 360)


# ---------------------------------------------------------------------------
# reduce_sweep
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "n_rays, expected",
    [
        (8, [0, 45, 90, 135, 180, 225, 270, 315]),
        (6, [0, 45, 135, 180, 225, 315]),  # two opposite rays dropped
        (4, [0, 90, 180, 270]),  # every other ray
        (3, [0, 135, 225]),
        (2, [0, 90]),  # one ray per motor, not two opposite rays
    ],
)
def test_kept_rays_and_their_samples(one_run, n_rays, expected):
    X, y = one_run
    full = _rays(X, 8, None)
    Xr, yr = reduce_sweep(X, y, n_rays=n_rays)
    reduced = _rays(Xr, n_rays)
    assert reduced.n_rays == n_rays
    assert np.allclose(_directions_deg(reduced), expected, atol=1.0)
    # every kept ray keeps all its samples
    full_counts = np.bincount(full.labels[full.labels >= 0])
    assert np.array_equal(np.bincount(reduced.labels[reduced.labels >= 0]), full_counts[:n_rays])
    # the motion rows are untouched, the neutral start stays, rows keep their labels
    motion = X[X["phase"] == "motion"]
    pd.testing.assert_frame_equal(Xr[Xr["phase"] == "motion"], motion)
    assert Xr.index[0] == X.index[0]
    assert Xr.index.isin(X.index).all() and Xr.index.is_monotonic_increasing
    np.testing.assert_array_equal(yr, y[X.index.get_indexer(Xr.index)])
    assert list(Xr.dtypes) == list(X.dtypes)


def test_neutral_dwell_of_a_dropped_ray_goes_with_it(one_run):
    X, _ = one_run
    n_full = len(_sweep(X))
    kept = [len(_sweep(reduce_sweep(X, n_rays=n))) for n in (8, 6, 4, 3)]
    # each dropped ray removes the same block: its excursion and the dwell after it
    per_ray = (n_full - kept[2]) / 4
    assert kept[0] == n_full
    assert kept[1] == pytest.approx(n_full - 2 * per_ray, abs=20)
    assert kept[3] == pytest.approx(n_full - 5 * per_ray, abs=20)
    labels = _rays(X, 8, None).labels
    assert per_ray > np.bincount(labels[labels >= 0])[0]


@pytest.mark.parametrize("stride", [1, 3, 10])
def test_stride_keeps_every_stride_th_sweep_sample(one_run, stride):
    X, _ = one_run
    Xr = reduce_sweep(X, stride=stride)
    sweep = _sweep(X)
    expected = sweep.index[::stride]
    np.testing.assert_array_equal(_sweep(Xr).index.to_numpy(), expected.to_numpy())
    assert (Xr["phase"] == "motion").sum() == (X["phase"] == "motion").sum()


def test_rays_and_stride_together(one_run):
    X, _ = one_run
    Xr = reduce_sweep(X, n_rays=4, stride=5)
    assert _sweep(Xr).index.isin(_sweep(reduce_sweep(X, n_rays=4)).index).all()
    assert _sweep(Xr).index.isin(_sweep(reduce_sweep(X, stride=5)).index).all()
    assert _rays(Xr, 4).n_rays == 4


def test_input_is_never_modified(one_run):
    X, y = one_run
    X_before, y_before = X.copy(), y.copy()
    Xr, yr = reduce_sweep(X, y, n_rays=4, stride=2)
    Xr.iloc[:, 5] = 0.0
    yr[:] = 0.0
    pd.testing.assert_frame_equal(X, X_before)
    np.testing.assert_array_equal(y, y_before)


def test_y_keeps_its_type_and_every_run_is_reduced(bench):
    X, y = bench
    frame = pd.DataFrame(y, columns=["p_x", "p_y", "p_z"])
    Xr, yr = reduce_sweep(X, frame, n_rays=4)
    assert isinstance(yr, pd.DataFrame)
    pd.testing.assert_frame_equal(yr, frame.loc[Xr.index])
    assert reduce_sweep(X, n_rays=4).equals(Xr)
    for run, rows in Xr.groupby("run", observed=True):
        assert _rays(rows, 4).n_rays == 4, run


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"n_rays": 9}, "n_rays must be None or an integer from 2 to n_rays_swept=8"),
        ({"n_rays": 1}, "n_rays must be None or an integer from 2"),
        ({"n_rays": 4.0}, "n_rays must be None or an integer"),
        ({"stride": 0}, "stride must be a positive integer"),
        ({"stride": 2.5}, "stride must be a positive integer"),
        ({"n_rays_swept": 1}, "n_rays_swept must be an integer of at least 2"),
        ({"n_rays": 3, "n_rays_swept": 6}, r"Too many rays in the sweep of run 'C1-S00-R1'.*n_rays=6"),
    ],
)
def test_bad_arguments_raise(one_run, kwargs, message):
    X, _ = one_run
    with pytest.raises(ValueError, match=message):
        reduce_sweep(X, **kwargs)


def test_bad_recordings_raise(one_run):
    X, y = one_run
    with pytest.raises(TypeError):
        reduce_sweep(X.to_numpy(), n_rays=4)
    with pytest.raises(ValueError, match="q1"):
        reduce_sweep(X.drop(columns="q1"), n_rays=4)
    with pytest.raises(ValueError):
        reduce_sweep(X, y[:-1], n_rays=4)


# ---------------------------------------------------------------------------
# find_rays with a layout spacing
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("spacing", [0.0, -45.0, 91.0, "wide"])
def test_bad_ray_spacing_raises(one_run, spacing):
    X, _ = one_run
    with pytest.raises(ValueError, match="ray_spacing_deg must"):
        _rays(X, 4, spacing)


def test_layout_spacing_still_detects_a_wrong_count(one_run):
    X, _ = one_run
    Xr = reduce_sweep(X, n_rays=4)
    with pytest.raises(ValueError, match="Rays missing.*n_rays=5 rays from a layout spaced 45 deg"):
        _rays(Xr, 5)


def _layout_sweep(directions_deg):
    """Motor angles of a sweep with one out-and-back ray per direction (degrees)."""
    from skcath.datasets._protocol import sweep_trajectory

    return np.concatenate([sweep_trajectory(n_rays=1, first_direction_deg=d) for d in directions_deg])


@pytest.mark.parametrize(
    "directions, message",
    [
        ((0, 45, 136, 180, 225, 315), "Rays missing .* a gap of 91.0 deg"),  # 6 of 8, one ray 1 deg off
        ((0, 89), "Rays missing .* found 1 distinct"),  # 2 of 8, merged at the even spacing
    ],
)
def test_layout_spacing_accepts_subsets_the_even_spacing_refuses(directions, message):
    q = _layout_sweep(directions)
    with pytest.raises(ValueError, match=message):
        find_rays(q, n_rays=len(directions))
    rays = find_rays(q, n_rays=len(directions), ray_spacing_deg=45.0)
    error = (rays.directions_deg[:, None] - np.asarray(directions)[None, :] + 180) % 360 - 180
    assert np.abs(error).min(axis=0).max() < 1.0  # every direction found, within 1 deg


def test_default_spacing_is_the_even_layout(one_run):
    X, _ = one_run
    q = _sweep(X)[["q1", "q2"]].to_numpy()
    a, b = find_rays(q), find_rays(q, ray_spacing_deg=45.0)
    for field in ("labels", "directions", "amplitudes", "neutral", "q_neutral"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


# ---------------------------------------------------------------------------
# backbones on reduced sweeps
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Est", [PCCBackbone, PDLBackbone])
def test_backbones_calibrate_on_reduced_sweeps(bench, Est):
    X, y = bench
    errors = {}
    for n_rays in (8, 4, 3):
        Xr, yr = reduce_sweep(X, y, n_rays=n_rays)
        est = Est(n_rays=n_rays, ray_spacing_deg=45.0).fit(Xr)
        pred = est.predict(Xr)
        assert np.isfinite(pred).all()
        errors[n_rays] = mean_per_run_rmse(yr, pred, Xr)
        if Est is PDLBackbone:
            assert all(p.n_rays == n_rays for p in est.calibrate(Xr).params.values())
    # fewer rays never help, and 8 rays with the spacing given is the default backbone
    assert errors[3] > errors[8]
    np.testing.assert_allclose(Est(ray_spacing_deg=45.0).fit(X).predict(X), Est().fit(X).predict(X))


def test_backbone_with_the_wrong_count_names_it(bench):
    X, _ = bench
    Xr = reduce_sweep(X, n_rays=4)
    with pytest.raises(ValueError, match="n_rays=8"):
        PDLBackbone().fit(Xr).predict(Xr)


@pytest.mark.parametrize("spacing", [0.0, -1.0, 400.0, "45"])
def test_bad_ray_spacing_parameter_raises_at_fit(bench, spacing):
    X, _ = bench
    with pytest.raises(InvalidParameterError, match="ray_spacing_deg"):
        PDLBackbone(ray_spacing_deg=spacing).fit(X)


# ---------------------------------------------------------------------------
# the experiment
# ---------------------------------------------------------------------------
def _tiny_schedule():
    from skcath.protocol import Schedule

    return Schedule(
        name="tiny",
        seeds=(0,),
        n_setting_folds=2,
        variants=("PDL+GRU",),
        model_params={"module__hidden_size": 8, "window_step_s": 20.0, "sweep_stride_s": 4.0},
        pretrain_params={"max_epochs": 1},
        finetune_params={"max_epochs": 1},
    )


def test_backbone_budgets_match_a_direct_calibration(bench):
    from skcath.protocol import run_calibration_budget

    X, y = bench
    result = run_calibration_budget(
        X, y, rays=(4, 8), strides=(10,), learned=False, exclude_settings="S00", n_jobs=1
    )
    table = result.summary
    assert list(table[["n_rays", "stride"]].itertuples(index=False, name=None)) == [(8, 1), (4, 1), (8, 10)]
    assert list(table.columns) == ["n_rays", "stride", "sweep_samples", "sweep_s", "PCC", "PDL"]
    evaluated = (X["setting"] != "S00").to_numpy()
    Xr, yr = reduce_sweep(X[evaluated], y[evaluated], n_rays=4)
    direct = mean_per_run_rmse(yr, PDLBackbone(n_rays=4, ray_spacing_deg=45).fit(Xr).predict(Xr), Xr)
    assert table.loc[1, "PDL"] == pytest.approx(direct, rel=1e-12)
    # half the rays: about half the sweep time; stride 10: a tenth of the samples, same time
    assert table.loc[1, "sweep_s"] == pytest.approx(table.loc[0, "sweep_s"] / 2, rel=0.05)
    assert table.loc[2, "sweep_s"] == pytest.approx(table.loc[0, "sweep_s"], rel=0.01)
    assert table.loc[2, "sweep_samples"] == pytest.approx(table.loc[0, "sweep_samples"] / 10, abs=1)
    runs = result.run_rmse
    assert set(runs["run"]) == set(X.loc[evaluated, "run"].astype(str))
    assert len(runs) == 3 * 2 * runs["run"].nunique()
    assert (runs["seed"] == -1).all()


def test_learned_budgets_with_a_tiny_schedule(bench):
    from skcath.protocol import format_budget_report, run_calibration_budget

    X, y = bench
    result = run_calibration_budget(
        X, y, rays=(8, 3), strides=(20,), schedule=_tiny_schedule(), catheters=["C1"],
        exclude_settings=["S00"], n_jobs=1,
    )
    table = result.summary
    assert list(table.columns)[-3:] == ["PCC", "PDL", "PDL+GRU"]
    assert np.isfinite(table[["PCC", "PDL", "PDL+GRU"]].to_numpy()).all()
    runs = result.run_rmse
    assert set(runs["catheter"]) == {"C1"}
    assert set(runs.loc[runs["method"] == "PDL+GRU", "seed"]) == {0}
    text = format_budget_report(result)
    assert "schedule 'tiny'" in text and "catheters C1" in text and "PDL+GRU" in text


def test_learned_budgets_on_a_sweep_of_four_rays(bench):
    """Recordings whose sweep has 4 rays: the full-sweep backbone of training uses 4 too."""
    from skcath.protocol import run_calibration_budget
    from skcath.sweep import reduce_sweep

    X4, y4 = reduce_sweep(*bench, n_rays=4)  # every other ray: an even 4-ray layout
    result = run_calibration_budget(
        X4, y4, rays=(3,), strides=(20,), n_rays_swept=4, schedule=_tiny_schedule(),
        catheters=["C1"], exclude_settings=["S00"], n_jobs=1,
    )
    table = result.summary
    assert np.isfinite(table[["PCC", "PDL", "PDL+GRU"]].to_numpy()).all()
    assert list(zip(table["n_rays"], table["stride"])) == [(4, 1), (3, 1), (4, 20)]
    # the full-sweep budget is each backbone calibrated on the 4 rays as recorded
    # (90 degrees apart), computed here on the evaluated runs
    evaluated = ((X4["catheter"].astype(str) == "C1") & (X4["setting"].astype(str) != "S00")).to_numpy()
    Xe, ye = X4[evaluated], y4[evaluated]
    sweep = Xe[(Xe["phase"] == "sweep").to_numpy()]
    assert table.loc[0, "sweep_samples"] == sweep.groupby("run", observed=True).size().median()
    for name, Backbone in (("PCC", PCCBackbone), ("PDL", PDLBackbone)):
        pred = Backbone(n_rays=4, ray_spacing_deg=90.0).fit(Xe).predict(Xe)
        assert table.loc[0, name] == pytest.approx(mean_per_run_rmse(ye, pred, Xe), rel=1e-9)
    # PDL+GRU, trained on the 4-ray sweeps, is far from the mean tip of the
    # evaluated runs' motion rows (measured: 9.4 mm against 21.6 mm)
    motion = (Xe["phase"] == "motion").to_numpy()
    constant = mean_per_run_rmse(ye, np.broadcast_to(np.nanmean(ye[motion], axis=0), ye.shape), Xe)
    assert table.loc[0, "PDL+GRU"] < 0.6 * constant


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"rays": (2,)}, "rays must hold integers from 3 to 8"),
        ({"rays": (9,)}, r"rays must hold integers from 3 to 8 \(.*n_rays_swept=8 has no more\)"),
        ({"strides": (0,)}, "strides must hold integers from 1"),
        ({"catheters": ["C9"]}, "catheters must name catheters"),
        ({"n_rays_swept": 2}, "n_rays_swept must be an integer of at least 3"),
    ],
)
def test_experiment_bad_arguments_raise(bench, kwargs, message):
    from skcath.protocol import run_calibration_budget

    X, y = bench
    with pytest.raises(ValueError, match=message):
        run_calibration_budget(X, y, learned=False, **kwargs)


def test_learned_needs_two_catheters(bench):
    from skcath.protocol import run_calibration_budget

    X, y = bench
    c1 = (X["catheter"] == "C1").to_numpy()
    with pytest.raises(ValueError, match="at least two catheters"):
        run_calibration_budget(X[c1], y[c1], rays=(8,), strides=(5,))


# ---------------------------------------------------------------------------
# command line and figure
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def csv_path(bench, tmp_path_factory):
    X, y = bench
    frame = X.copy()
    for k, axis in enumerate("xyz"):
        frame[f"p_{axis}"] = y[:, k]
    path = tmp_path_factory.mktemp("budget") / "recordings.csv"
    frame.to_csv(path, index=False)
    return path


def test_command_prints_the_table_and_writes_its_files(csv_path, tmp_path, capsys):
    from skcath.protocol import BUDGET_FILES

    out = tmp_path / "out"
    argv = ["calibration-budget", "--data", str(csv_path), "--out", str(out), "--backbones-only",
            "--rays", "8", "4", "--strides", "10", "--n-jobs", "1", "--exclude-settings", "S00"]
    if not HAS_MATPLOTLIB:
        argv.append("--no-figures")
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "Calibration budget: mean per-run RMSE (mm)" in printed
    assert "backbones only" in printed and "settings S00 excluded" in printed
    files = {p.name for p in out.iterdir()}
    expected = {BUDGET_FILES["summary"], BUDGET_FILES["run_rmse"]}
    if HAS_MATPLOTLIB:
        expected.add(BUDGET_FILES["figure"])
    assert files == expected
    assert f"wrote {len(expected)} files to" in printed
    summary = pd.read_csv(out / BUDGET_FILES["summary"])
    assert summary[["n_rays", "stride"]].to_numpy().tolist() == [[8, 1], [4, 1], [8, 10]]
    assert np.isfinite(summary[["PCC", "PDL"]].to_numpy()).all()


def test_command_trains_the_quick_schedule(csv_path, tmp_path, monkeypatch, capsys):
    from skcath import protocol

    monkeypatch.setattr(protocol, "QUICK", _tiny_schedule())
    out = tmp_path / "out"
    argv = ["calibration-budget", "--data", str(csv_path), "--out", str(out), "--no-figures",
            "--rays", "8", "--strides", "50", "--catheters", "C2", "--n-jobs", "1",
            "--exclude-settings", "S00"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "schedule 'tiny'" in printed and "catheters C2" in printed
    summary = pd.read_csv(out / "calibration_budget.csv")
    assert np.isfinite(summary["PDL+GRU"]).all()


@pytest.mark.parametrize(
    "extra, message",
    [
        # range errors come from run_calibration_budget, reported as usage errors
        (["--rays", "2"], "rays must hold integers from 3 to 8 (the backbones need at least 3 rays"),
        (["--rays", "8", "--n-rays-swept", "6"], "rays must hold integers from 3 to 6"),
        (["--n-rays-swept", "2"], "n_rays_swept must be an integer of at least 3; got 2"),
        (["--rays", "0"], "--rays: expected a positive integer"),
        (["--strides", "0"], "--strides: expected a positive integer"),
        (["--n-jobs", "0"], "--n-jobs: expected a positive number"),
        (["--catheters", "C7"], "catheters must name catheters"),
    ],
)
def test_command_bad_arguments_exit_2(csv_path, tmp_path, extra, message, capsys):
    argv = ["calibration-budget", "--data", str(csv_path), "--out", str(tmp_path), "--no-figures",
            "--backbones-only", *extra]
    with pytest.raises(SystemExit) as excinfo:
        main(argv)
    assert excinfo.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.skipif(not HAS_MATPLOTLIB, reason="needs matplotlib")
def test_figure_has_a_panel_per_reduction():
    from skcath.protocol import plot_calibration_budget

    summary = pd.DataFrame(
        {"n_rays": [8, 4, 8], "stride": [1, 1, 10], "PCC": [3.0, 4.0, 3.1], "PDL": [2.0, 3.0, 2.1]}
    )
    before = summary.copy()
    figure = plot_calibration_budget(summary)
    left, right = figure.axes
    assert [line.get_label() for line in left.get_lines()] == ["PCC", "PDL"]
    np.testing.assert_array_equal(left.get_lines()[1].get_xdata(), [4, 8])
    np.testing.assert_array_equal(right.get_lines()[0].get_ydata(), [3.0, 3.1])
    pd.testing.assert_frame_equal(summary, before)


def test_missing_matplotlib_names_the_extra(monkeypatch):
    from skcath.protocol import plot_calibration_budget

    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    monkeypatch.setitem(sys.modules, "matplotlib.backends.backend_agg", None)
    summary = pd.DataFrame({"n_rays": [8], "stride": [1], "PDL": [2.0]})
    with pytest.raises(ImportError, match=r"skcath\[plot\]"):
        plot_calibration_budget(summary)
