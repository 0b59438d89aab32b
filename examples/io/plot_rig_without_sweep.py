"""
=======================================
Rigs without a sweep and without torque
=======================================

Not every rig records what the built-in benchmark records. This example
reads and fits two other layouts:

* a **three-cable arm tracked by motion capture**: the file holds the time,
  three commanded cable motors stepped at 4 Hz and the tip position, already
  in the arm's base frame; there is no torque, no base sensor and no
  calibration sweep: every row is motion;
* a **six-servo robot with motion capture at 100 Hz**, whose servo angles
  are updated only at 20 Hz: the log repeats the last angle between two
  updates.

Both are read with a column map (:func:`skcath.io.read_recording`), fitted
with :class:`~skcath.backbones.PolynomialBackbone` calibrated on the
training runs and :class:`~skcath.residuals.GRUResidual` without a sweep
context, and cross-validated with trials held out. The data are made with
the package's simulator: its two motors bend the catheter in two planes,
and the cables and servos of these rigs are the same bending seen through
three or six channels, written in each rig's layout. The
:ref:`reading_recordings` section of the data format page describes the
options used here.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# A three-cable arm at 4 Hz
# -------------------------
#
# We simulate eight trials of one catheter in one shaft setting at 4 Hz,
# each a run of its own (its own motor path, drifts and noise), and keep the
# first 150 s of their motion. The three cables pull at 0, 120 and 240
# degrees around the arm, so each cable's motor angle is the bending of the
# two planes projected on its direction. The file has the columns the
# motion-capture and motor logs give: ``time_s``, ``motor_a`` ..
# ``motor_c``, ``tip_x`` .. ``tip_z`` (mm) and ``trial``.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from sklearn.model_selection import cross_validate
from sklearn.pipeline import Pipeline

from skcath.backbones import PolynomialBackbone
from skcath.datasets import sample_catheter, simulate_run
from skcath.io import read_recording
from skcath.metrics import run_rmse_scorer
from skcath.model_selection import SettingGroupKFold
from skcath.residuals import GRUResidual, NoResidual

catheter = sample_catheter(3, "C3")
tmp = tempfile.TemporaryDirectory()
folder = Path(tmp.name)


def simulated_trials(rate_hz, n_channels, n_trials, motion_s):
    """Trials of one instrument: time (s), ``n_channels`` motor angles (deg), tip (mm).

    Every trial is the first ``motion_s`` seconds of the motion of a
    simulated run of the catheter in one shaft setting, with its own motor
    path, drifts and noise.
    """
    directions = np.deg2rad(360.0 / n_channels * np.arange(n_channels))
    projection = np.stack([np.cos(directions), np.sin(directions)])  # (2, n_channels)
    for seed in range(n_trials):
        sim = simulate_run(catheter, "S03", random_state=seed, rate_hz=rate_hz)
        motion = (sim.X["phase"] == "motion").to_numpy()
        t = sim.X.loc[motion, "t"].to_numpy()
        keep = t - t[0] < motion_s
        q = sim.X.loc[motion, ["q1", "q2"]].to_numpy()[keep]
        yield t[keep] - t[0], q @ projection, sim.y[motion][keep], seed + 1


arm = []
for t, channels, tip, number in simulated_trials(4.0, 3, n_trials=8, motion_s=150.0):
    trial = pd.DataFrame({"time_s": t})
    for name, values in zip(["motor_a", "motor_b", "motor_c"], channels.T):
        trial[name] = values
    trial[["tip_x", "tip_y", "tip_z"]] = tip
    trial["trial"] = f"arm-{number}"
    arm.append(trial)
pd.concat(arm).to_csv(folder / "arm.csv", index=False, float_format="%.4f")
pd.read_csv(folder / "arm.csv").head()

# %%
# Reading it
# ----------
#
# ``columns`` maps every skcath name to its column in the file: the time,
# the motors ``q1 .. q3``, the tip ``p_x, p_y, p_z`` (the target, given in
# the base frame, so no sensor pose is needed) and the run id. The trials
# are not shaft settings of a catheter, but the splitters of
# :mod:`skcath.model_selection` hold out settings: mapping ``setting`` to
# the trial column too makes every trial its own setting, so that they hold
# out whole trials. ``phase="motion"`` says that the file has no sweep, and
# ``torques=False`` that the rig measures no torque.
arm_columns = {
    "t": "time_s",
    "q1": "motor_a",
    "q2": "motor_b",
    "q3": "motor_c",
    "p_x": "tip_x",
    "p_y": "tip_y",
    "p_z": "tip_z",
    "run": "trial",
    "setting": "trial",
}
X_arm, y_arm = read_recording(
    folder / "arm.csv", columns=arm_columns, catheter="arm", phase="motion", torques=False
)
X_arm.head()

# %%
# Fitting and cross-validating
# ----------------------------
#
# Without a sweep, :class:`~skcath.backbones.PolynomialBackbone` is fitted
# once on the training runs (``calibration="fit"``). The residual learner
# reads no sweep either: no context (``use_context=False``) and the base
# frame (``frame="base"``: the sweep frame is fitted on a run's sweep), and
# no torque (``use_torque=False``). Its time scales are given in seconds and
# counted in samples at the rate it is fitted at: the default window of 20 s
# is 80 samples at 4 Hz, the burn-in of 5 s is 20. ``SettingGroupKFold(4)``
# holds out two trials per fold.


def pipelines():
    """The polynomial alone and with a GRU residual (default time scales, in seconds)."""
    gru = GRUResidual(
        use_context=False,
        frame="base",
        use_torque=False,
        max_epochs=15,
        module__hidden_size=16,
        n_threads=1,
        random_state=0,
    )
    return {
        "polynomial": Pipeline(
            [("backbone", PolynomialBackbone(calibration="fit")), ("residual", NoResidual())]
        ),
        "polynomial + GRU": Pipeline(
            [("backbone", PolynomialBackbone(calibration="fit")), ("residual", gru)]
        ),
    }


def held_out_errors(X, y, n_splits):
    """Mean per-run RMSE (mm) of the held-out trials of every fold, for both pipelines."""
    errors = {}
    cv = SettingGroupKFold(n_splits)
    for name, pipe in pipelines().items():
        scores = cross_validate(pipe, X, y, cv=cv, scoring=run_rmse_scorer)
        errors[name] = -scores["test_score"]
    return pd.DataFrame(errors, index=pd.Index(range(1, n_splits + 1), name="fold"))


arm_errors = held_out_errors(X_arm, y_arm, n_splits=4)
arm_errors.round(2)

# %%
# A six-servo robot at 100 Hz with held angles
# --------------------------------------------
#
# The motion capture samples at 100 Hz; the servo controller reports new
# angles at 20 Hz, and its log repeats the last one in between. We keep 40 s
# of four trials, and hold out two per fold.
robot = []
for t, channels, tip, number in simulated_trials(100.0, 6, n_trials=4, motion_s=40.0):
    trial = pd.DataFrame({"time_s": t})
    held = channels[(np.arange(len(channels)) // 5) * 5]  # a new angle every 5th row
    for k, values in enumerate(held.T, start=1):
        trial[f"servo{k}_deg"] = values
    trial[["mocap_x", "mocap_y", "mocap_z"]] = tip
    trial["trial"] = f"robot-{number}"
    robot.append(trial)
pd.concat(robot).to_csv(folder / "robot.csv", index=False, float_format="%.4f")
pd.read_csv(folder / "robot.csv").iloc[:7, :4]

# %%
# The held angles need nothing special: they are read as they are, a
# piecewise-constant channel. The backbone gives a tip that jumps at every
# update, and the GRU, which steps at the 100 Hz of the file, sees the
# motor step ``dq`` as zero on four rows out of five; it can learn how the
# tip moves on between updates. (A model fitted at another rate would read
# these runs resampled linearly in time, where a held angle stays held and
# each update becomes a ramp over one sample, 10 ms.) The time scales are
# set for 100 Hz.
robot_columns = {"t": "time_s", "run": "trial", "setting": "trial"}
robot_columns.update({f"q{k}": f"servo{k}_deg" for k in range(1, 7)})
robot_columns.update(zip(["p_x", "p_y", "p_z"], ["mocap_x", "mocap_y", "mocap_z"]))
X_robot, y_robot = read_recording(
    folder / "robot.csv", columns=robot_columns, catheter="robot", phase="motion", torques=False
)
robot_errors = held_out_errors(X_robot, y_robot, n_splits=2)
robot_errors.round(2)

# %%
# Errors on held-out trials
# -------------------------
#
# The mean per-run RMSE of the held-out trials over the folds (mm). The GRU
# residual lowers the polynomial's error on both rigs, from 6.78 to 5.26 mm
# on the arm and from 10.55 to 9.71 mm on the robot, which was trained on two
# trials of 40 s per fold. It learns the lag of the tip behind the motors
# that the trials share. What it cannot learn is what differs from trial to
# trial: the simulator gives every run its own motor offsets, drifts and
# base pose, which a calibration sweep would measure and these rigs do not
# record (:ref:`residuals_without_sweep`).
summary = pd.DataFrame({"three-cable arm": arm_errors.mean(), "six-servo robot": robot_errors.mean()})
print(summary.round(2).to_string())

fig, ax = plt.subplots(figsize=(6, 3.5), layout="constrained")
summary.T.plot.bar(ax=ax, rot=0, color=["tab:red", "tab:green"])
ax.set_ylabel("held-out RMSE per run (mm)")
ax.set_title("Trials held out")
ax.grid(alpha=0.3, axis="y")
plt.show()

tmp.cleanup()  # remove the temporary folder and its files
