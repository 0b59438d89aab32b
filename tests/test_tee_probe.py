"""The real-data benchmark ``benchmarks/bench_tee_probe.py``.

One test runs the script's core on the TEE-probe recordings when their folder
is present (they are not distributed with skcath); the others run on
synthetic acquisitions written by the test in the same file layout.
"""

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]


def _load_script():
    spec = importlib.util.spec_from_file_location(
        "bench_tee_probe", REPO / "benchmarks" / "bench_tee_probe.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up here
    spec.loader.exec_module(module)
    return module


bench = _load_script()

#: A tiny learner configuration: the tests check the plumbing, not accuracy.
TINY = {"max_epochs": 2, "use_torque": True}


# ---------------------------------------------------------------------------
# synthetic acquisitions in the layout of the TEE-probe files
# ---------------------------------------------------------------------------
def _cycle(centre, high, low, n):
    """Motor position centre -> high -> low -> centre in n samples (counts)."""
    legs = np.array([centre, high, low, centre], dtype=float)
    lengths = np.abs(np.diff(legs))
    knots = np.concatenate([[0.0], np.cumsum(lengths)]) / lengths.sum() * (n - 1)
    return np.round(np.interp(np.arange(n), knots, legs))


def _acquisition(rng, n, backlash, base_rotation, base_position):
    """One synthetic acquisition: the tip bends about the base x axis with backlash.

    The bending angle follows the motor position through a play (backlash)
    element of half-width ``backlash`` counts, so that the tip differs between
    loading and unloading; the tip sensor's orientation turns with the angle.
    """
    q = _cycle(1600, 2200, 1000, n)
    play = np.empty(n)
    play[0] = q[0]
    for k in range(1, n):
        play[k] = np.clip(play[k - 1], q[k] - backlash, q[k] + backlash)
    theta = np.radians(0.06 * (play - 1600))  # bending angle (rad)
    radius = 60.0
    p_base = np.column_stack(
        [np.zeros(n), radius * (1 - np.cos(theta)), 20.0 + radius * np.sin(theta)]
    )
    p_base = p_base + rng.normal(scale=0.05, size=p_base.shape)
    r_wb = Rotation.from_quat(np.tile(base_rotation.as_quat(), (n, 1)))
    r_wt = r_wb * Rotation.from_rotvec(np.column_stack([theta, np.zeros(n), np.zeros(n)]))
    tip = base_position + r_wb.apply(p_base)
    current = np.sign(np.diff(q, prepend=q[0])) * 50 + rng.normal(scale=3, size=n)
    frame = {"sample": np.arange(1, n + 1), "motor_position": q, "current": np.round(current)}
    for name, values in (
        ("tip_position", tip),
        ("tip_orientation", r_wt.as_quat()),  # scipy: x, y, z, w
        ("base_position", np.tile(base_position, (n, 1))),
        ("base_orientation", r_wb.as_quat()),
    ):
        for j, c in enumerate("xyzw"[: values.shape[1]]):
            frame[f"{name}_{c}"] = values[:, j]
    return pd.DataFrame(frame), p_base


@pytest.fixture(scope="module")
def synthetic_folder(tmp_path_factory):
    """Six acquisition files; motor 2's acquisition 3 is a copy of its acquisition 1."""
    folder = tmp_path_factory.mktemp("tee")
    rng = np.random.default_rng(0)
    base_rotation = Rotation.from_rotvec([0.3, -0.5, 1.2])
    truth = {}
    for motor in bench.MOTORS:
        for a in bench.ACQUISITIONS:
            path = folder / bench.file_name(motor, a)
            if motor == 2 and a == 3:
                path.write_bytes((folder / bench.file_name(2, 1)).read_bytes())
                truth[motor, a] = truth[motor, 1]
                continue
            frame, p_base = _acquisition(
                rng, 300 + 7 * a, 40.0, base_rotation, np.array([5.0, -20.0, -100.0])
            )
            frame.to_csv(path, index=False)
            truth[motor, a] = p_base
    return folder, truth


def test_read_acquisition_gives_tip_in_base_frame(synthetic_folder):
    folder, truth = synthetic_folder
    X, y = bench.read_acquisition(folder / bench.file_name(1, 2), 1, 2, n_sweep=10)
    np.testing.assert_allclose(y, truth[1, 2], atol=1e-6)
    assert (X["phase"].iloc[:10] == "sweep").all() and (X["phase"].iloc[10:] == "motion").all()
    assert (X["q2"] == 0).all() and (X["tau2"] == 0).all()
    assert X["run"].iloc[0] == "motor1-acq2"
    np.testing.assert_allclose(np.diff(X["t"]), 1 / bench.NOMINAL_RATE_HZ)


def test_quaternion_order_check_separates_the_orders(synthetic_folder):
    folder, _ = synthetic_folder
    angles = bench.quaternion_order_check(folder / bench.file_name(1, 1))
    assert angles["xyzw"] < 5.0
    assert angles["wxyz"] > 20.0


def test_run_benchmark_on_synthetic_acquisitions(synthetic_folder):
    folder, _ = synthetic_folder
    results, selection, checks = bench.run_benchmark(
        folder, seeds=(0,), config=TINY, degrees=range(1, 4), log=lambda *a: None
    )
    # 2 motors x 2 test acquisitions x 3 methods, one seed
    assert len(results) == 12
    assert set(results["method"]) == set(bench.METHODS)
    errors = results[["rmse_mm", "first_leg_rmse_mm", "rest_rmse_mm"]]
    assert np.isfinite(errors.to_numpy()).all() and (errors.to_numpy() > 0).all()
    # the two parts of the cycle make up the whole: the RMSE lies between them
    low = errors[["first_leg_rmse_mm", "rest_rmse_mm"]].min(axis=1)
    high = errors[["first_leg_rmse_mm", "rest_rmse_mm"]].max(axis=1)
    assert ((low <= errors["rmse_mm"] + 1e-12) & (errors["rmse_mm"] <= high + 1e-12)).all()
    leaks = results.drop_duplicates(["motor", "test_acquisition"]).set_index(
        ["motor", "test_acquisition"]
    )["leaks_training"]
    assert leaks.to_dict() == {(1, 2): False, (1, 3): False, (2, 2): False, (2, 3): True}
    assert checks.set_index("motor")["copies_of_acq1"].to_dict() == {1: "", 2: "acq3"}
    # a copy of the training acquisition scores exactly the training error
    copy = results[(results["motor"] == 2) & (results["test_acquisition"] == 3)]
    np.testing.assert_allclose(copy["rmse_mm"], copy["train_rmse_mm"])

    summary = bench.summarize(results)
    poly = summary[summary["method"] == "polynomial"]
    np.testing.assert_allclose(poly["ratio_to_polynomial"], 1.0)
    ratios = bench.headline(summary)
    assert list(ratios.index) == ["polynomial+MLP", "polynomial+GRU"]
    # the headline averages over the three tests that are not copies
    clean = summary[~summary["leaks_training"] & (summary["method"] == "polynomial+GRU")]
    assert len(clean) == 3
    assert ratios["polynomial+GRU"] == pytest.approx(clean["ratio_to_polynomial"].mean())
    assert set(selection["method"]) == {"polynomial"}
    assert selection["degree"].between(1, 3).all()


def test_block_folds_partition_the_motion_rows(synthetic_folder):
    folder, _ = synthetic_folder
    X, _ = bench.read_acquisition(folder / bench.file_name(1, 1), 1, 1, n_sweep=10)
    folds = bench.block_folds(X, n_folds=2, n_blocks_per_fold=5)
    assert len(folds) == 2
    assert not (folds[0] & folds[1]).any()
    motion = (X["phase"] == "motion").to_numpy()
    np.testing.assert_array_equal(folds[0] | folds[1], motion)
    # 10 contiguous blocks alternate between the folds
    changes = np.flatnonzero(np.diff(folds[0][motion].astype(int)))
    assert changes.size == 9


def test_select_config_searches_inside_the_training_run(synthetic_folder):
    folder, _ = synthetic_folder
    X, y = bench.read_acquisition(folder / bench.file_name(1, 1), 1, 1, n_sweep=10)
    grid = {"max_epochs": [1], "use_torque": [True, False]}
    before = y.copy()
    best, table = bench.select_config("polynomial+GRU", X, y, 2, grid, seed=0)
    np.testing.assert_array_equal(y, before)  # the held-out targets are hidden on a copy
    assert len(table) == 2 and np.isfinite(table["cv_rmse_mm"]).all()
    assert set(best) == set(grid)
    chosen = table.loc[table["use_torque"] == best["use_torque"], "cv_rmse_mm"]
    assert chosen.iloc[0] == table["cv_rmse_mm"].min()


def test_first_leg_ends_at_the_motor_maximum(synthetic_folder):
    folder, _ = synthetic_folder
    X, _ = bench.read_acquisition(folder / bench.file_name(1, 1), 1, 1, n_sweep=10)
    rows = bench.first_leg(X)
    q = X["q1"].to_numpy()
    end = np.flatnonzero(rows)[-1]
    assert rows[: end + 1].all() and not rows[end + 1 :].any()
    assert q[end] == q.max() and (np.diff(q[: end + 1]) >= 0).all()


def test_motor_polynomial_backbone(synthetic_folder):
    folder, truth = synthetic_folder
    X, y = bench.read_acquisition(folder / bench.file_name(1, 1), 1, 1, n_sweep=10)
    before = X.copy()
    poly = bench.MotorPolynomial(degree=3).fit(X, y)
    Xt = poly.transform(X)
    pd.testing.assert_frame_equal(X, before)  # input left alone
    assert list(Xt.columns) == [*X.columns, "b_x", "b_y", "b_z"]
    rmse = np.sqrt(np.mean(np.sum((poly.predict(X) - y) ** 2, axis=1)))
    constant = np.sqrt(np.mean(np.sum((y - y.mean(axis=0)) ** 2, axis=1)))
    assert rmse < 0.5 * constant
    # rows with a NaN target are skipped, not fatal
    y_nan = y.copy()
    y_nan[::2] = np.nan
    assert np.isfinite(bench.MotorPolynomial(degree=3).fit(X, y_nan).predict(X)).all()
    with pytest.raises(ValueError, match="degree"):
        bench.MotorPolynomial(degree=0).fit(X, y)
    with pytest.raises(ValueError, match="q1"):
        bench.MotorPolynomial().fit(X.drop(columns="q1"), y)


def test_missing_folder_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(bench.ENV_VAR, raising=False)
    with pytest.raises(FileNotFoundError, match=bench.ENV_VAR):
        bench.resolve_data_folder(tmp_path / "absent")
    (tmp_path / bench.file_name(1, 1)).write_text("sample\n")
    with pytest.raises(FileNotFoundError, match="lacks"):
        bench.resolve_data_folder(tmp_path)
    assert bench.main(["--data", str(tmp_path / "absent"), "--out", str(tmp_path)]) == 2
    assert "not distributed" in capsys.readouterr().err


def _real_folder():
    path = os.environ.get(bench.ENV_VAR) or bench.DEFAULT_DATA
    try:
        return bench.resolve_data_folder(path)
    except FileNotFoundError:
        return None


@pytest.mark.skipif(
    _real_folder() is None,
    reason=f"TEE-probe recordings not found (not distributed; set {bench.ENV_VAR})",
)
def test_run_benchmark_on_the_real_recordings():
    folder = _real_folder()
    results, selection, checks = bench.run_benchmark(
        folder, seeds=(0,), config=TINY, degrees=range(1, 4), log=lambda *a: None
    )
    assert len(results) == 12
    assert np.isfinite(results["rmse_mm"]).all()
    # motor 2's third acquisition is a copy of its first
    checks = checks.set_index("motor")
    assert checks.loc[1, "copies_of_acq1"] == "" and checks.loc[2, "copies_of_acq1"] == "acq3"
    # the export is scalar last: that order is consistent, the other is not
    assert (checks["angle_xyzw_deg"] < 10).all() and (checks["angle_wxyz_deg"] > 30).all()
    # the polynomial explains most of the motion of the tip in training
    for motor in bench.MOTORS:
        data = bench.load_motor(folder, motor)
        X, y = data.X[1], data.y[1]
        poly = bench.MotorPolynomial(degree=3).fit(X, y)
        motion = (X["phase"] == "motion").to_numpy()
        err = np.sqrt(np.mean(np.sum((poly.predict(X) - y)[motion] ** 2, axis=1)))
        spread = np.sqrt(np.mean(np.sum((y[motion] - y[motion].mean(axis=0)) ** 2, axis=1)))
        assert err < 0.3 * spread
        # the tip stays 76-88 mm from the base sensor in these recordings
        distance = np.linalg.norm(y, axis=1)
        assert 70 < distance.min() and distance.max() < 95
