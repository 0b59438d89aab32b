"""
============================
Bringing your own recordings
============================

Recordings from a rig rarely arrive in the long format of skcath
(:doc:`/data_format`): the drive and the EM tracker write their own column
names, the tracker reports raw sensor poses in its own frame with its own
quaternion order, and the file may have no phase or id columns at all.
:func:`skcath.io.read_recording` maps such a file to the long format. This
example writes two files shaped like a combined drive and tracker export,
reads them back, checks them, and calibrates a backbone on them. The files
are made from simulator output, so that we can compare what is read with
what was written.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Two exported files
# ------------------
#
# We simulate two runs of one catheter, in a low and a high shaft setting,
# with the tip sensor lost on about 1 % of the samples, and write each run to
# its own CSV file in a temporary folder, as an export might look:
#
# * the drive channels are called ``Motor1_deg``, ``Motor2_deg``,
#   ``Motor1_torque`` and ``Motor2_torque``;
# * the time stamps ``time_s`` come from the clock of the rig, so they do not
#   start at 0;
# * the tracker columns hold the raw poses in the tracker frame: the position
#   of the tip sensor, and the position and orientation of the sensor at the
#   base of the bending section, its quaternion written **scalar last**;
# * a ``Status`` column reads ``OK``, or ``MISSING`` where the tip sensor was
#   lost (its cells are then empty);
# * there is no phase column: the calibration sweep is the first part of the
#   file, and the drive log tells how many samples it has;
# * there are no catheter, setting or run columns: the file name says which
#   run it is.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from skcath import check_recordings
from skcath.backbones import PDLBackbone
from skcath.datasets import sample_catheter, simulate_run
from skcath.io import read_recording
from skcath.metrics import per_run_rmse

catheter = sample_catheter(7, "C7")
tmp = tempfile.TemporaryDirectory()
folder = Path(tmp.name)
simulated, n_sweep = {}, {}
for seed, setting in enumerate(["S02", "S10"]):
    run_id = f"C7-{setting}-R1"
    sim = simulate_run(catheter, setting, random_state=seed, run=run_id, dropout_rate=0.01)
    simulated[run_id], n_sweep[run_id] = sim, int(sim.runs["n_sweep"].iloc[0])
    s = sim.sensors
    export = pd.DataFrame(
        {
            "time_s": 1726.0 + sim.X["t"],
            "Motor1_deg": sim.X["q1"],
            "Motor2_deg": sim.X["q2"],
            "Motor1_torque": sim.X["tau1"],
            "Motor2_torque": sim.X["tau2"],
            "Tip_X": s["tip_px"], "Tip_Y": s["tip_py"], "Tip_Z": s["tip_pz"],
            "Base_X": s["base_px"], "Base_Y": s["base_py"], "Base_Z": s["base_pz"],
            "Base_Qx": s["base_qx"], "Base_Qy": s["base_qy"], "Base_Qz": s["base_qz"], "Base_Qw": s["base_qw"],
            "Status": np.where(s["tip_px"].isna(), "MISSING", "OK"),
        }
    )
    export.to_csv(folder / f"{run_id}.csv", index=False, float_format="%.6f")

print(sorted(p.name for p in folder.glob("*.csv")))
export.head()

# %%
# Reading the files
# -----------------
#
# ``columns`` maps the skcath names to the names in the file, only for the
# columns whose names differ. The tracker poses are mapped by sensor: three
# position columns for ``tip_position`` and ``base_position``, four
# orientation columns for ``base_orientation``, listed in the order given by
# ``quat_order``. Stating the order is required: scalar-first and scalar-last
# quaternions both give plausible rotations, and skcath never guesses.
# :func:`~skcath.io.read_recording` then computes the tip position in the frame of the base
# sensor, the target ``y``, from the two sensor poses; on the sweep rows it
# also becomes the reference ``ref_x, ref_y, ref_z`` that calibrates a
# backbone. ``valid="Status"`` marks the rows whose status is not ``OK``:
# they keep their place with a NaN target, never imputed.
#
# The catheter and setting ids are given as arguments (here parsed from the
# file name), the run id defaults to the file name, and ``n_sweep`` says how
# many samples at the start of the file are the sweep.
columns = {
    "t": "time_s",
    "q1": "Motor1_deg",
    "q2": "Motor2_deg",
    "tau1": "Motor1_torque",
    "tau2": "Motor2_torque",
    "tip_position": ["Tip_X", "Tip_Y", "Tip_Z"],
    "base_position": ["Base_X", "Base_Y", "Base_Z"],
    "base_orientation": ["Base_Qx", "Base_Qy", "Base_Qz", "Base_Qw"],
}
frames, targets = [], []
for path in sorted(folder.glob("*.csv")):
    catheter_id, setting, _ = path.stem.split("-")
    X_run, y_run = read_recording(
        path,
        columns=columns,
        quat_order="xyzw",
        catheter=catheter_id,
        setting=setting,
        n_sweep=n_sweep[path.stem],
        valid="Status",
    )
    frames.append(X_run)
    targets.append(y_run)

# %%
# Each call returns one run; the runs are stacked with :func:`pandas.concat`
# and :func:`numpy.vstack`, in the same order. :func:`skcath.check_recordings`
# validates the result as every estimator does: it would name the column,
# run and row of any problem, such as a repeated time stamp or a sweep row
# after a motion row.
X = pd.concat(frames, ignore_index=True)
y = np.vstack(targets)
X, y = check_recordings(X, y)
X.head()

# %%
# The target read from the file is the simulator's, up to the six decimals
# written to the file, and the lost samples are NaN rows:
for run_id, sim in simulated.items():
    in_run = (X["run"] == run_id).to_numpy()
    lost = np.isnan(y[in_run]).any(axis=1)
    difference = np.nanmax(np.abs(y[in_run] - sim.y))
    print(f"{run_id}: {lost.sum()} lost samples, largest difference from the simulator {difference:.1e} mm")

# %%
# What the file holds and what is read
# ------------------------------------
#
# The tracker reports the tip sensor in its own frame, where the tip
# position also depends on where the catheter lies in the field. In the frame
# of the base sensor it only depends on how the bending section is bent: the
# neutral tip sits at the same place for both settings, and the eight spokes
# of each sweep leave from it.
fig, axes = plt.subplots(1, 2, figsize=(10, 4.6), layout="constrained")
for run_id, color in zip(simulated, ["tab:blue", "tab:orange"]):
    raw = pd.read_csv(folder / f"{run_id}.csv")
    in_run = (X["run"] == run_id).to_numpy()
    axes[0].plot(raw["Tip_X"], raw["Tip_Y"], lw=0.4, color=color, label=run_id)
    axes[1].plot(y[in_run, 0], y[in_run, 1], lw=0.4, color=color, label=run_id)
axes[0].set_title("In the file: tip sensor, tracker frame")
axes[0].set_xlabel("Tip_X (mm)")
axes[0].set_ylabel("Tip_Y (mm)")
axes[1].set_title("Read: tip in the base frame, y")
axes[1].set_xlabel("p_x (mm)")
axes[1].set_ylabel("p_y (mm)")
for ax in axes:
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
plt.show()

# %%
# Calibrating a backbone
# ----------------------
#
# The recordings are now ready for any estimator of skcath. A
# :class:`~skcath.backbones.PDLBackbone` calibrates on each run's sweep rows
# and estimates the tip of the motion rows from the motor angles alone; the
# per-run RMSE over the motion rows leaves out the lost samples.
backbone = PDLBackbone().fit(X)
calibration = backbone.calibrate(X)
nominal = calibration.nominal  # what backbone.predict(X) returns
print(calibration.table[["rmse_mm", "converged"]])
per_run_rmse(y, nominal, X)

# %%
# The measured and the nominal tip of the high-bend run over 40 s of its
# motion phase:
run_id = "C7-S10-R1"
in_run = (X["run"] == run_id).to_numpy() & (X["phase"] == "motion").to_numpy()
t = X.loc[in_run, "t"].to_numpy()
t = t - t[0]
window = t < 40
fig, axes = plt.subplots(3, 1, figsize=(10, 6.5), sharex=True, layout="constrained")
for i, ax in enumerate(axes):
    ax.plot(t[window], y[in_run][window, i], color="k", lw=1.2, label="measured, read from the file")
    ax.plot(t[window], nominal[in_run][window, i], color="tab:red", lw=1.2, label="PDL nominal")
    ax.set_ylabel(f"tip {'xyz'[i]} (mm)")
    ax.grid(alpha=0.3)
axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
axes[-1].set_xlabel("time since the end of the sweep (s)")
fig.suptitle(f"Run {run_id}")
plt.show()

# %%
# Other layouts are covered by the other options of
# :func:`~skcath.io.read_recording`: ``scale`` converts units (metres to
# millimetres, encoder counts to degrees), ``rate_hz`` builds the time of a
# file without time stamps, ``constants`` fills a channel the rig does not
# have, and ``tip_offset`` moves the tip sensor's position to the real tip.
# Files that already hold the tip in the base frame map it to ``p_x, p_y,
# p_z`` instead of the raw poses. The section
# :ref:`reading_recordings` of the data format page lists them all.

tmp.cleanup()  # remove the temporary folder and its files
