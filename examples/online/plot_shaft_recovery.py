"""
================================================
Recovering from a shaft change without a tracker
================================================

When the shaft is repositioned, the backbone's calibration from the tracked
sweep no longer holds. The answer is a new sweep; with the tracker off, the
sweep gives the motor angles and torques of the new configuration but no tip.
:class:`~skcath.online.MotorRecalibration` learns, on tracked sweeps of
*other* catheters in several shaft settings, how a calibration changes when
the sweep's torque loops change, and
:meth:`OnlineEstimator.resweep <skcath.online.OnlineEstimator.resweep>` uses
it to renew the calibration from the motors alone. This example uses the
backbone alone (no residual network, to stay quick); the measurement with
the GRU residual on the held-out catheters is on the :doc:`shaft-change page
</shaft_change>`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Tracked sweeps of other catheters
# ---------------------------------
#
# The recalibration is fitted on the sweeps of catheters C2 and C3 of the
# simulated benchmark, one run in each of the 17 shaft settings. It pairs the
# runs of one catheter, and chooses its ridge penalty by holding out one
# catheter at a time.
import matplotlib.pyplot as plt
import numpy as np
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone
from skcath.datasets import benchmark_catheter, make_benchmark, simulate_run
from skcath.online import MotorRecalibration, OnlineEstimator

bench = make_benchmark(n_catheters=3, n_runs=1, cache=False)
X = bench.X
others = (X["phase"] == "sweep").to_numpy() & (X["catheter"] != "C1").to_numpy()
recalibration = MotorRecalibration().fit(X[others])
print(f"penalty {recalibration.alpha_:g}, {recalibration.n_pairs_} pairs; held-out catheter: "
      f"{recalibration.cv_rmse_[recalibration.alpha_]:.1f} mm error on a change of "
      f"{recalibration.change_rmse_:.1f} mm")

# %%
# A run of a new catheter whose shaft moves
# -----------------------------------------
#
# Catheter C1, which the recalibration has not seen, starts in setting S05
# with a tracked sweep; 30 s into the motion its shaft moves to S13, and it
# sweeps again (``resweep=True``). Three ways to go on after the re-sweep:
# keep everything (stale), re-sweep the motors alone with the recalibration,
# or re-sweep with the tracker (the bound).
run = simulate_run(catheter=benchmark_catheter(1), setting="S05", setting_after="S13",
                   change_after_s=30.0, resweep=True, random_state=1)
R = run.X
first = R[((R["run"] == "run-0") & (R["phase"] == "sweep")).to_numpy()]
after = (R["run"] == "run-0/after").to_numpy()
resweep = R[after & (R["phase"] == "sweep").to_numpy()]
motion = after & (R["phase"] == "motion").to_numpy()
samples = R.loc[motion, ["q1", "q2", "tau1", "tau2"]].to_numpy()
tip = np.asarray(run.y)[motion]

pipe = Pipeline([("backbone", PDLBackbone().fit(first))])
motor_only = resweep.drop(columns=["ref_x", "ref_y", "ref_z"])  # the tracker is off
ways = {
    "stale": OnlineEstimator(pipe).start(first),
    "motors alone, recalibrated": OnlineEstimator(pipe).start(first).resweep(
        motor_only, recalibration=recalibration),
    "tracked re-sweep": OnlineEstimator(pipe).start(resweep),
}

# %%
# The tip error after the re-sweep
# --------------------------------
#
# Each estimator steps through the motion after the re-sweep, one sample at
# a time. The recalibrated backbone is closer to the tracked one than the
# stale calibration.
t = R.loc[motion, "t"].to_numpy()
fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
for (name, est), colour in zip(ways.items(), ["tab:red", "tab:blue", "tab:green"]):
    error = np.linalg.norm(np.array([est.step(*s).copy() for s in samples]) - tip, axis=1)
    rmse = np.sqrt(np.nanmean(error**2))
    ax.plot(t - t[0], error, color=colour, lw=1, label=f"{name}: {rmse:.1f} mm RMSE")
ax.set_xlabel("time since the end of the re-sweep (s)")
ax.set_ylabel("tip error of the backbone (mm)")
ax.set_ylim(bottom=0)
ax.grid(alpha=0.3)
ax.legend()
plt.show()
