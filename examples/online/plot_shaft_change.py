"""
======================================
Detecting a shaft change during motion
======================================

Every skcath model is calibrated on the sweep of the run it is used on, for
the shaft configuration of that moment. If the shaft is repositioned later,
the calibration no longer holds, and nothing in the tip estimate says so.
:class:`~skcath.online.ShaftChangeDetector` watches the motor torques
instead: it fits, on the sweep, how each motor's torque depends on its angle
and direction of motion, and raises an alarm when the torques drift away from
that model. This example simulates a run whose shaft moves from the low to
the high bend level in the middle of the motion, and runs the detector one
sample at a time, as it would run on the drive. The method and its measured
delays and false-alarm rates are on the :doc:`shaft-change page
</shaft_change>`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# A run with a repositioned shaft
# -------------------------------
#
# :func:`~skcath.datasets.simulate_run` with ``setting_after`` moves the
# shaft to another setting ``change_after_s`` seconds into the motion phase:
# here from ``S01`` (low bend level, bent towards 0 deg) to ``S09`` (high
# level, same direction). The same seed without ``setting_after`` gives the
# same run with the shaft left alone; up to the change, the two are identical.
import matplotlib.pyplot as plt
import numpy as np

from skcath.datasets import simulate_run
from skcath.online import ShaftChangeDetector

changed = simulate_run(random_state=0, setting="S01", setting_after="S09", change_after_s=60.0)
unchanged = simulate_run(random_state=0, setting="S01")
t_change = changed.runs.loc[0, "change_time_s"]
print(changed.runs[["run", "setting", "setting_after", "n_sweep", "change_time_s"]])

# %%
# What changes in the torque
# --------------------------
#
# A higher bend level wraps the tendons further around the shaft, so the
# capstan friction ``exp(mu Theta)`` grows: pulling a tendon now takes more
# torque, releasing it less, and the dead zone and motor offsets move. The
# torque of motor 1 against its angle shows the sweep's loop (what the
# detector learns), and the motion before and after the change.
X = changed.X
t = X["t"].to_numpy()
sweep = (X["phase"] == "sweep").to_numpy()
after = t >= t_change
fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
ax.plot(X["q1"][sweep], X["tau1"][sweep], ".", ms=1.5, color="0.6", label="sweep")
before = ~sweep & ~after
ax.plot(X["q1"][before], X["tau1"][before], ".", ms=2, color="tab:blue", label="motion, before the change")
ax.plot(X["q1"][after], X["tau1"][after], ".", ms=2, color="tab:red", alpha=0.6, label="motion, after")
ax.set_xlabel("motor angle q1 (deg)")
ax.set_ylabel("drive torque tau1 (N mm)")
ax.set_title("Torque signature of motor 1 (S01, then S09)")
ax.grid(alpha=0.3)
ax.legend(markerscale=6)
plt.show()

# %%
# The detector in a live loop
# ---------------------------
#
# ``start`` fits the torque model on the sweep rows only. Then each motion
# sample goes through ``step``, which updates the CUSUM statistic of the
# normalised torque residuals and returns True when it crosses the
# threshold. The same loop runs on the unchanged run for comparison.


def live(data):
    """Run a fresh detector over a run's motion, one sample at a time."""
    X = data.X
    detector = ShaftChangeDetector().start(X[X["phase"] == "sweep"])
    motion = X[X["phase"] == "motion"]
    statistic, residual, alarms = [], [], []
    for k, (q1, q2, tau1, tau2) in enumerate(motion[["q1", "q2", "tau1", "tau2"]].to_numpy()):
        if detector.step(q1, q2, tau1, tau2):
            alarms.append(k)
        statistic.append(detector.statistic_)
        residual.append(detector.residual_.copy())
    return detector, motion["t"].to_numpy(), np.array(statistic), np.array(residual), alarms


detector, t_motion, statistic, residual, alarms = live(changed)
_, t_same, statistic_same, _, alarms_same = live(unchanged)
print(f"threshold {detector.threshold:g}, drift {detector.drift:g}")
print(f"sweep residual standard deviations (N mm): {np.round(detector.scale_, 2)}")
print(f"changed run: first alarm {detector.alarm_time_:.1f} s into the motion, "
      f"{t_motion[detector.alarm_index_] - t_change:.1f} s after the change")
print(f"unchanged run: {len(alarms_same)} alarm(s)")

# %%
# Residuals and statistic
# -----------------------
#
# Before the change, the normalised residuals scatter around zero (more
# widely than on the sweep, because the motion is faster); the CUSUM
# statistic rises and falls back. After the change, the residual of one motor
# keeps a sign, the statistic climbs steadily and crosses the threshold. The
# unchanged run (grey) stays below it.
fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True, layout="constrained")
for i, color in enumerate(["tab:blue", "tab:orange"]):
    axes[0].plot(t_motion, residual[:, i], lw=0.6, color=color, label=f"motor {i + 1}")
axes[0].set_ylabel("normalised residual z")
axes[0].legend(loc="upper left")
axes[1].plot(t_same, statistic_same, color="0.6", lw=1, label="unchanged run")
axes[1].plot(t_motion, statistic, color="tab:red", lw=1.2, label="changed run")
axes[1].axhline(detector.threshold, color="k", ls=":", label="threshold")
for k in alarms:
    axes[1].plot(t_motion[k], statistic[k], "kv", ms=8)
axes[1].set_ylabel("CUSUM statistic G")
axes[1].set_xlabel("time in the run (s)")
axes[1].legend(loc="upper left")
for ax in axes:
    ax.axvline(t_change, color="tab:green", lw=2, alpha=0.6)
    ax.grid(alpha=0.3)
axes[0].set_title("Shaft moved from S01 to S09 at the green line; alarms marked with triangles")
plt.show()

# %%
# The whole run at once
# ---------------------
#
# For evaluation, ``detect`` runs the same computation over arrays and
# returns the statistic of every sample and the alarm indices; the numbers
# are those of the live loop.
motion = X[X["phase"] == "motion"]
result = detector.detect(motion[["q1", "q2"]], motion[["tau1", "tau2"]])
print(f"alarms at motion samples {result.alarms.tolist()}; same as the live loop: "
      f"{result.alarms.tolist() == alarms and np.array_equal(result.statistic, statistic)}")
