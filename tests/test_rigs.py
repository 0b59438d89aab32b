"""Rigs without a sweep phase and without torque: reading, fitting, scoring, cross-validating."""

import pickle

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from sklearn.base import clone
from sklearn.model_selection import cross_validate
from sklearn.pipeline import Pipeline

from skcath import persist
from skcath.backbones import PolynomialBackbone
from skcath.datasets import simulate_run
from skcath.io import read_recording, read_recordings
from skcath.metrics import mean_per_run_rmse, run_rmse_scorer
from skcath.model_selection import SettingGroupKFold
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

from _helpers import tiny_residual

#: The parameters of a residual learner that reads no sweep, on a rig without torque.
NO_SWEEP = {"use_context": False, "frame": "base", "use_torque": False}


@pytest.fixture(scope="module")
def swept():
    """Four simulated runs (sweep then motion) of a three-motor instrument without torques, and y."""
    runs = [
        simulate_run(random_state=k, setting="S03", run=f"trial-{k}", n_motors=3) for k in range(4)
    ]
    X = pd.concat([r.X for r in runs], ignore_index=True)
    for column in ("catheter", "setting", "run", "phase"):
        X[column] = X[column].astype(str)
    X["setting"] = X["run"]  # every trial its own setting: the splitters hold out trials
    return X.drop(columns=["tau1", "tau2", "tau3"]), np.vstack([r.y for r in runs])


@pytest.fixture(scope="module")
def motion_only(swept):
    """The motion rows of ``swept`` alone: recordings of a rig without a sweep phase."""
    X, y = swept
    motion = (X["phase"] == "motion").to_numpy()
    return X[motion].reset_index(drop=True), y[motion]


def _pipeline(Est, **params):
    residual = tiny_residual(Est, **{**NO_SWEEP, **params})
    return Pipeline([("backbone", PolynomialBackbone(calibration="fit")), ("residual", residual)])


@pytest.mark.parametrize("Est", [GRUResidual, MLPResidual])
def test_learner_without_sweep_fits_and_predicts(motion_only, Est):
    X, y = motion_only
    before = X.copy()
    pipe = _pipeline(Est).fit(X, y)
    residual = pipe.named_steps["residual"]
    assert residual.s_scaler_ is None  # no sweep row: no sweep statistic
    assert residual.n_motors_ == 3
    tip = pipe.predict(X)
    assert np.isfinite(tip).all()
    assert not np.allclose(tip, pipe.named_steps["backbone"].predict(X))  # a residual is added
    pd.testing.assert_frame_equal(X, before)


def test_learner_without_sweep_reads_the_motion_of_swept_runs_alike(swept, motion_only):
    """A learner fitted without sweeps predicts runs with one: 0 on the sweep, the same motion.

    Only the first motion step differs (its ``dq`` from the last sweep sample
    instead of 0), and the recurrent state forgets it.
    """
    X, y = swept
    Xm, ym = motion_only
    on_motion = _pipeline(GRUResidual).fit(Xm, ym)
    backbone = on_motion.named_steps["backbone"]
    residual = on_motion.named_steps["residual"]
    motion = (X["phase"] == "motion").to_numpy()
    r_swept = residual.predict_residual(backbone.transform(X))
    r_motion = residual.predict_residual(backbone.transform(Xm))
    assert_array_equal(r_swept[~motion], 0.0)
    later = (Xm.groupby("run").cumcount() >= 100).to_numpy()  # 10 s into the motion
    assert_allclose(r_swept[motion][later], r_motion[later], atol=1e-4)


def test_learner_reading_the_sweep_refuses_runs_without_one(motion_only):
    X, y = motion_only
    Xb = PolynomialBackbone(calibration="fit").fit(X, y).transform(X)
    with pytest.raises(ValueError, match=r"GRUResidual\(frame='sweep', use_context=True\) reads "
                       r"the calibration sweep.*pass frame='base' and use_context=False"):
        tiny_residual(GRUResidual, use_torque=False).fit(Xb, y)
    with pytest.raises(ValueError, match=r"MLPResidual\(use_context=True\) reads"):
        tiny_residual(MLPResidual, use_torque=False, frame="base").fit(Xb, y)


def test_persisted_and_pickled_learner_without_sweep(motion_only, tmp_path):
    X, y = motion_only
    pipe = _pipeline(GRUResidual).fit(X, y)
    expected = pipe.predict(X)
    assert_array_equal(pickle.loads(pickle.dumps(pipe)).predict(X), expected)
    persist.save(pipe, tmp_path / "rig.skcath")
    assert_array_equal(persist.load(tmp_path / "rig.skcath").predict(X), expected)


def test_cross_validation_and_scoring_without_sweep(motion_only):
    X, y = motion_only
    pipe = Pipeline([("backbone", PolynomialBackbone(calibration="fit")), ("residual", NoResidual())])
    cv = SettingGroupKFold(2)
    scores = cross_validate(pipe, X, y, cv=cv, scoring=run_rmse_scorer)["test_score"]
    # each score is the negated mean per-run RMSE of the held-out trials (every
    # trial its own setting), from a polynomial fitted on the other trials, as a
    # hand-written fold loop gives it. The trials are four simulated units, so
    # no accuracy bound: a polynomial fitted on two units does not carry over.
    folds = list(cv.split(X, y))
    tested = sorted(run for _, test in folds for run in set(X["run"].iloc[test]))
    assert tested == sorted(set(X["run"]))  # every trial held out once
    for score, (train, test) in zip(scores, folds):
        assert not set(X["run"].iloc[train]) & set(X["run"].iloc[test])
        fold = clone(pipe).fit(X.iloc[train], y[train])
        expected = mean_per_run_rmse(y[test], fold.predict(X.iloc[test]), X.iloc[test])
        assert score == pytest.approx(-expected, rel=1e-12)


def test_scorer_still_refuses_a_run_cut_from_its_sweep(swept):
    """Runs with a sweep beside one without: a cut run, as before."""
    X, y = swept
    cut = ~((X["run"] == "trial-0") & (X["phase"] == "sweep")).to_numpy()
    pipe = Pipeline([("backbone", PolynomialBackbone(calibration="fit")), ("residual", NoResidual())])
    pipe.fit(X, y)
    with pytest.raises(ValueError, match=r"hold 1 run\(s\) without 'sweep' rows, first "
                       r"'trial-0', beside runs with them"):
        run_rmse_scorer(pipe, X[cut], y[cut])


def _rig_file(path, X, y, rate_hz=None):
    """One trial of ``X, y`` written in a rig's own column names."""
    table = pd.DataFrame(
        {
            "time_s": X["t"].to_numpy() - X["t"].iloc[0],
            "motor_a": X["q1"], "motor_b": X["q2"], "motor_c": X["q3"],
            "tip_x": y[:, 0], "tip_y": y[:, 1], "tip_z": y[:, 2],
            "trial": X["run"],
        }
    )
    table.to_csv(path, index=False)


ARM_COLUMNS = {
    "t": "time_s", "q1": "motor_a", "q2": "motor_b", "q3": "motor_c",
    "p_x": "tip_x", "p_y": "tip_y", "p_z": "tip_z", "run": "trial", "setting": "trial",
}


def test_reading_a_rig_without_sweep_base_pose_and_torque(motion_only, tmp_path):
    """Tip in the base frame, no phase, one file column giving both the run and the setting."""
    X, y = motion_only
    for run in ("trial-0", "trial-1"):
        rows = (X["run"] == run).to_numpy()
        _rig_file(tmp_path / f"{run}.csv", X[rows], y[rows])
    X_read, y_read = read_recordings(
        tmp_path, columns=ARM_COLUMNS, catheter="arm", phase="motion", torques=False,
        progress=False,
    )
    rows = X["run"].isin(["trial-0", "trial-1"]).to_numpy()
    assert list(X_read.columns) == [
        "catheter", "setting", "run", "t", "phase", "q1", "q2", "q3", "ref_x", "ref_y", "ref_z"
    ]
    assert (X_read["phase"] == "motion").all()
    assert_array_equal(X_read["setting"], X_read["run"])
    assert X_read[["ref_x", "ref_y", "ref_z"]].isna().all().all()
    assert_allclose(y_read, y[rows], atol=1e-9)
    assert_allclose(X_read[["q1", "q2", "q3"]], X.loc[rows, ["q1", "q2", "q3"]], atol=1e-9)
    # a file without a phase column: the phase is never guessed
    with pytest.raises(ValueError, match=r"the file has no 'phase' column; pass n_sweep .*"
                       r"phase='motion'"):
        read_recording(tmp_path / "trial-0.csv", columns=ARM_COLUMNS, catheter="arm", torques=False)


def test_held_servo_angles_are_read_as_they_are(motion_only):
    """A servo angle held between updates is a piecewise-constant channel; no option needed."""
    X, y = motion_only
    X = X[X["run"] == "trial-0"].reset_index(drop=True)
    held = X.copy()
    index = (np.arange(len(X)) // 5) * 5  # a new angle every fifth sample
    for column in ("q1", "q2", "q3"):
        held[column] = X[column].to_numpy()[index]
    pipe = _pipeline(GRUResidual).fit(held, y[: len(X)])
    assert np.isfinite(pipe.predict(held)).all()
    # the polynomial of held angles is held too: the tip steps at the updates
    b = pipe.named_steps["backbone"].predict(held)
    assert_array_equal(b[1:5], np.repeat(b[:1], 4, axis=0))
