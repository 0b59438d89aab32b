"""The TEE-probe workflow on the package: recordings of a one-motor probe.

``docs/studies/real_data.rst`` reads the recordings of a robotised TEE probe with
:func:`skcath.io.read_recording` and estimates the tip with
:class:`skcath.backbones.PolynomialBackbone` (fitted once on the training
acquisition) followed by a residual learner. These tests run the same calls
on synthetic acquisitions written in the layout of the TEE-probe files, and
on the recordings themselves when their folder is found (they are not
distributed with skcath: ``SKCATH_TEE_PROBE``, else ``../shared/data/tee-probe``
next to the repository).
"""

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation
from sklearn.pipeline import Pipeline

from skcath.backbones import PolynomialBackbone
from skcath.io import read_recording
from skcath.metrics import mean_per_run_rmse, per_run_rmse
from skcath.model_selection import BlockKFold
from skcath.residuals import GRUResidual, MLPResidual

#: skcath name -> column(s) of the TEE-probe CSV files: the motor channels, and
#: the position (x, y, z) and quaternion (x, y, z, w) of the tip and base sensors.
COLUMNS = {"q1": "motor_position", "tau1": "current"}
for _sensor in ("tip", "base"):
    for _kind, _axes in (("position", "xyz"), ("orientation", "xyzw")):
        COLUMNS[f"{_sensor}_{_kind}"] = [f"{_sensor}_{_kind}_{c}" for c in _axes]
#: The learners of the benchmark, tiny: the tests check the plumbing, not accuracy.
TINY = dict(
    use_context=False, frame="base", window_s=10.0, burn_in_s=2.0, window_step_s=1.0,
    batch_size=32, module__hidden_size=8, n_threads=1, max_epochs=2, random_state=0,
)


def _file(motor, acquisition):
    return f"motor{motor}_current60_acq{acquisition}.csv"


def _read(path, motor, acquisition, quat_order="xyzw"):
    """One acquisition as one run, as the benchmark reads it (10 leading 'sweep' samples)."""
    return read_recording(
        path, columns=COLUMNS, quat_order=quat_order, constants={"q2": 0.0, "tau2": 0.0},
        catheter="tee-probe", setting=f"motor{motor}", run=f"motor{motor}-acq{acquisition}",
        rate_hz=10.0, n_sweep=10,
    )


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
    for motor in (1, 2):
        for a in (1, 2, 3):
            path = folder / _file(motor, a)
            if motor == 2 and a == 3:
                path.write_bytes((folder / _file(2, 1)).read_bytes())
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
    X, y = _read(folder / _file(1, 2), 1, 2)
    np.testing.assert_allclose(y, truth[1, 2], atol=1e-6)
    assert (X["phase"].iloc[:10] == "sweep").all() and (X["phase"].iloc[10:] == "motion").all()
    assert (X["q2"] == 0).all() and (X["tau2"] == 0).all()
    assert X["run"].iloc[0] == "motor1-acq2"
    np.testing.assert_allclose(np.diff(X["t"]), 1 / 10.0)


def test_the_other_quaternion_order_gives_another_tip(synthetic_folder):
    folder, truth = synthetic_folder
    _, y = _read(folder / _file(1, 1), 1, 1, quat_order="wxyz")
    assert np.abs(y - truth[1, 1]).max() > 10.0


def test_polynomial_backbone_on_an_acquisition(synthetic_folder):
    folder, _ = synthetic_folder
    X, y = _read(folder / _file(1, 1), 1, 1)
    before = X.copy()
    poly = PolynomialBackbone(degree=3, calibration="fit").fit(X, y)
    Xt = poly.transform(X)
    pd.testing.assert_frame_equal(X, before)  # input left alone
    assert list(Xt.columns) == [*X.columns, "b_x", "b_y", "b_z"]
    rmse = np.sqrt(np.mean(np.sum((poly.predict(X) - y) ** 2, axis=1)))
    constant = np.sqrt(np.mean(np.sum((y - y.mean(axis=0)) ** 2, axis=1)))
    assert rmse < 0.5 * constant
    # rows with a NaN target are skipped, not fatal
    y_nan = y.copy()
    y_nan[::2] = np.nan
    assert np.isfinite(PolynomialBackbone(degree=3, calibration="fit").fit(X, y_nan).predict(X)).all()
    with pytest.raises(ValueError, match="degree"):
        PolynomialBackbone(degree=0, calibration="fit").fit(X, y)
    with pytest.raises(ValueError, match="q1"):
        PolynomialBackbone(calibration="fit").fit(X.drop(columns="q1"), y)
    # ten "sweep" samples cannot calibrate a polynomial of degree 5 per run
    with pytest.raises(ValueError, match="motor1-acq1"):
        PolynomialBackbone(degree=5).fit(X).predict(X)


@pytest.mark.parametrize("Learner", [MLPResidual, GRUResidual])
def test_polynomial_and_residual_train_on_one_acquisition(synthetic_folder, Learner):
    folder, _ = synthetic_folder
    X1, y1 = _read(folder / _file(2, 1), 2, 1)
    model = Pipeline([
        ("backbone", PolynomialBackbone(degree=3, calibration="fit")),
        ("residual", Learner(**TINY)),
    ]).fit(X1, y1)
    for a in (2, 3):
        X, y = _read(folder / _file(2, a), 2, a)
        pred = model.predict(X)
        assert pred.shape == y.shape and np.isfinite(pred).all()
        rmse = per_run_rmse(y, pred, X).iloc[0]
        # a root mean square over the motion rows: the squares of the RMSEs of two
        # parts that split the run, weighted by their motion rows, add up to it
        q = X["q1"].to_numpy()
        motion = (X["phase"] == "motion").to_numpy()
        first = np.zeros(len(X), dtype=bool)
        first[: int(np.argmax(q)) + 1] = True
        squares = 0.0
        for rows in (first, ~first):
            y_part = y.copy()
            y_part[~rows] = np.nan
            squares += (rows & motion).sum() * per_run_rmse(y_part, pred, X).iloc[0] ** 2
        assert rmse == pytest.approx(np.sqrt(squares / motion.sum()), rel=1e-12)
        # and the model explains most of the motion: far below the mean tip of the
        # training acquisition (measured: 2.1-2.4 mm against 21.4 mm)
        constant = per_run_rmse(y, np.broadcast_to(y1.mean(axis=0), y.shape), X).iloc[0]
        assert rmse < 0.25 * constant
    # motor 2's acquisition 3 is a copy of acquisition 1: the training error exactly
    X3, y3 = _read(folder / _file(2, 3), 2, 3)
    assert_array_equal(X3[["q1", "tau1"]], X1[["q1", "tau1"]])
    assert_allclose(
        per_run_rmse(y3, model.predict(X3), X3).iloc[0], per_run_rmse(y1, model.predict(X1), X1).iloc[0]
    )


def test_hidden_targets_are_skipped_by_the_whole_pipeline(synthetic_folder):
    # the blocked cross-validation of the benchmark hides the targets of
    # held-out blocks as NaN; the fit must not read them
    folder, _ = synthetic_folder
    X, y = _read(folder / _file(1, 1), 1, 1)
    held = np.zeros(len(X), dtype=bool)
    held[100:200] = True
    y_hidden = y.copy()
    y_hidden[held] = np.nan
    y_other = y.copy()
    y_other[held] = 1e3  # what the fit would learn if it read them

    def fitted(target):
        return Pipeline([
            ("backbone", PolynomialBackbone(degree=3, calibration="fit")),
            ("residual", MLPResidual(**{**TINY, "burn_in_s": 0.0})),
        ]).fit(X, target)

    pred = fitted(y_hidden).predict(X)
    assert np.isfinite(pred).all()
    assert np.abs(pred - fitted(y_other).predict(X)).max() > 1.0
    assert_array_equal(fitted(y_hidden).predict(X), pred)  # seeded: reproducible


def test_blocked_cross_validation_inside_an_acquisition(synthetic_folder):
    # the benchmark's choices inside acquisition 1: 2 folds of 20 blocks of its
    # motion rows, the held-out targets hidden as NaN, scored on the held-out rows
    folder, _ = synthetic_folder
    X, y = _read(folder / _file(1, 1), 1, 1)
    motion = np.flatnonzero((X["phase"] == "motion").to_numpy())
    folds = list(BlockKFold(2, n_blocks=20).split(X))
    assert len(folds) == 2
    tested = np.concatenate([test for _, test in folds])
    assert_array_equal(np.sort(tested), motion)  # every motion row once, no sweep row
    scores = []
    for k, (train, test) in enumerate(folds):
        assert np.isin(np.arange(10), train).all()
        # block b of the motion rows is tested by fold b % 2
        blocks = np.array_split(motion, 20)
        assert_array_equal(test, np.concatenate(blocks[k::2]))
        y_hidden = y.copy()
        y_hidden[test] = np.nan
        model = PolynomialBackbone(degree=3, calibration="fit").fit(X, y_hidden)
        y_test = np.full_like(y, np.nan)
        y_test[test] = y[test]
        scores.append(mean_per_run_rmse(y_test, model.predict(X), X))
    constant = np.sqrt(np.mean(np.sum((y[motion] - y[motion].mean(axis=0)) ** 2, axis=1)))
    assert np.all(np.isfinite(scores)) and max(scores) < 0.5 * constant


def _real_folder():
    default = Path(__file__).resolve().parents[2] / "shared" / "data" / "tee-probe"
    path = Path(os.environ.get("SKCATH_TEE_PROBE") or default)
    names = [_file(m, a) for m in (1, 2) for a in (1, 2, 3)]
    return path if all((path / name).is_file() for name in names) else None


def _plane_angle_deg(path, quat_order):
    """Angle between the tip sensor's rotation axis relative to the base sensor and
    the normal of the plane the tip moves in (deg); small for the right order."""
    frame = pd.read_csv(path)
    _, y = _read(path, 1, 1, quat_order=quat_order)
    to_scipy = [0, 1, 2, 3] if quat_order == "xyzw" else [1, 2, 3, 0]
    base = Rotation.from_quat(frame[COLUMNS["base_orientation"]].to_numpy()[:, to_scipy])
    tip = Rotation.from_quat(frame[COLUMNS["tip_orientation"]].to_numpy()[:, to_scipy])
    turn = (base.inv() * tip) * (base[0].inv() * tip[0]).inv()
    axis = np.linalg.svd(turn.as_rotvec(), full_matrices=False)[2][0]
    normal = np.linalg.svd(y - y.mean(axis=0), full_matrices=False)[2][2]
    return float(np.degrees(np.arccos(min(1.0, abs(axis @ normal)))))


@pytest.mark.skipif(
    _real_folder() is None,
    reason="TEE-probe recordings not found (not distributed; set SKCATH_TEE_PROBE)",
)
def test_the_real_recordings():
    folder = _real_folder()
    # motor 2's third acquisition is a copy of its first, motor 1's are not
    for motor, copied in ((1, False), (2, True)):
        first = pd.read_csv(folder / _file(motor, 1)).to_numpy(dtype=np.float64)
        third = pd.read_csv(folder / _file(motor, 3)).to_numpy(dtype=np.float64)
        same = first.shape == third.shape and np.array_equal(first, third, equal_nan=True)
        assert same is copied
    for motor in (1, 2):
        path = folder / _file(motor, 1)
        # the export is scalar last: that order is consistent, the other is not
        assert _plane_angle_deg(path, "xyzw") < 10 and _plane_angle_deg(path, "wxyz") > 30
        X, y = _read(path, motor, 1)
        # the polynomial explains most of the motion of the tip in training
        poly = PolynomialBackbone(degree=3, calibration="fit").fit(X, y)
        motion = (X["phase"] == "motion").to_numpy()
        err = np.sqrt(np.mean(np.sum((poly.predict(X) - y)[motion] ** 2, axis=1)))
        spread = np.sqrt(np.mean(np.sum((y[motion] - y[motion].mean(axis=0)) ** 2, axis=1)))
        assert err < 0.3 * spread
        # the tip stays 76-88 mm from the base sensor in these recordings
        distance = np.linalg.norm(y, axis=1)
        assert 70 < distance.min() and distance.max() < 95
