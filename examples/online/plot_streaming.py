"""
==============================================
Streaming tip estimation, one sample at a time
==============================================

On the catheter drive the motor angles and torques arrive one sample at a
time, and the tip estimate is wanted for every sample as it arrives, not for
a whole recording afterwards. :class:`~skcath.online.OnlineEstimator` runs a
fitted pipeline this way: ``start`` calibrates the backbone on the run's
sweep and encodes the sweep context once, then ``step`` turns one motor
sample into one tip position, carrying the GRU's state from call to call.
This example fits a small PDL + GRU pipeline, streams a held-out run through
it in a live-style loop (with a dropout of the torque readings on the way),
checks the result against ``Pipeline.predict``, looks at the time one step
takes, and streams a run whose shaft is repositioned during the motion with
a change alarm in the loop. See :doc:`/deploying` for the interface, the bad-input policy
and the export of the network.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# A fitted pipeline
# -----------------
#
# Any fitted pipeline of a backbone and a residual learner can be streamed.
# This one is trained briefly (3 epochs, 32 hidden units, on six shaft
# settings of one simulated catheter) so that the example runs in seconds;
# streaming does not depend on how well the model is trained.
import time

import matplotlib.pyplot as plt
import numpy as np
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.online import OnlineEstimator, ShaftChangeDetector, export_io
from skcath.residuals import GRUResidual

data = make_benchmark(n_catheters=1, n_runs=1)
X, y = data.X, np.asarray(data.y)
train = X["setting"].isin(["S02", "S04", "S08", "S10", "S13", "S16"]).to_numpy()
pipe = Pipeline(
    [
        ("backbone", PDLBackbone()),
        ("residual", GRUResidual(max_epochs=3, module__hidden_size=32, n_threads=1, random_state=0)),
    ]
)
pipe.fit(X[train], y[train])

# %%
# Calibration: the sweep
# ----------------------
#
# A new run starts with its sweep, recorded with the EM tracker. ``start``
# takes exactly those rows: it calibrates the backbone on them, fits the
# sweep frame and encodes the context ``z``. After that, the tracker is no
# longer needed.
run = X[(X["setting"] == "S06").to_numpy()]
y_run = y[(X["setting"] == "S06").to_numpy()]
is_motion = (run["phase"] == "motion").to_numpy()
sweep = run[~is_motion]

est = OnlineEstimator(pipe, on_invalid="hold").start(sweep)
print(f"run {est.run_}: {len(sweep)} sweep samples, context z = {np.round(est.context_, 2)}")
print(f"motor angles accepted within {est.q_limit_:.0f} deg of {np.round(est.q_neutral_, 1) + 0.0} deg")

# %%
# The live loop
# -------------
#
# Here the motion samples come from the recording; on the drive they would
# come from the motor controller at 10 Hz. Each call to ``step`` returns the
# tip (mm, base frame) for one sample; passing ``out`` reuses one buffer so
# that the loop allocates nothing. Three samples lose their torque reading
# (NaN): with ``on_invalid="hold"`` the last accepted torque stands in for
# it, the step goes on, and ``n_held_`` counts the event (with the default
# ``"raise"``, ``step`` would raise a ``ValueError`` instead and leave the
# state as it was).
samples = run.loc[is_motion, ["q1", "q2", "tau1", "tau2"]].to_numpy()
samples_live = samples.copy()
samples_live[[400, 401, 402], 2] = np.nan  # a torque dropout

tips = np.empty((len(samples_live), 3))
latency_us = np.empty(len(samples_live))
buffer = np.empty(3)
for k, (q1, q2, tau1, tau2) in enumerate(samples_live):
    t0 = time.perf_counter()
    est.step(q1, q2, tau1, tau2, out=buffer)
    latency_us[k] = (time.perf_counter() - t0) * 1e6
    tips[k] = buffer  # e.g. send to the display
print(f"{est.n_steps_} steps, {est.n_held_} with a held value")
print(f"step latency: median {np.median(latency_us):.1f} us, 99th percentile {np.percentile(latency_us, 99):.1f} us")

# %%
# The same as ``predict``
# -----------------------
#
# On the samples without a dropout, streaming gives what ``predict`` gives
# for the whole run at once. The step path evaluates the float32 weights in
# float64, so the difference is the float32 rounding of ``predict`` itself,
# a few 1e-6 mm at most (:doc:`/deploying` gives the tolerances). Around
# the dropout, the held torque changes the estimate slightly.
offline = pipe.predict(run)[is_motion]
clean = np.ones(len(samples), dtype=bool)
clean[400:] = False
print(f"largest difference to predict before the dropout: {np.abs(tips[clean] - offline[clean]).max():.1e} mm")
print(f"largest difference over the dropout and after:    {np.abs(tips[~clean] - offline[~clean]).max():.3f} mm")

# %%
# What the estimator saw and what it returned
# -------------------------------------------
#
# Top: the streamed tip against the tracked tip (not used by the estimator)
# over one minute of the run. Bottom: the time of each step on this machine.
t = run.loc[is_motion, "t"].to_numpy()
t = t - t[0]
window = (t >= 20) & (t < 80)
fig, axes = plt.subplots(2, 1, figsize=(9, 6), layout="constrained")
for j, (axis, color) in enumerate(zip("xyz", ["tab:blue", "tab:orange", "tab:green"])):
    axes[0].plot(t[window], y_run[is_motion][window, j], color=color, lw=2, alpha=0.35)
    axes[0].plot(t[window], tips[window, j], color=color, lw=1, label=f"{axis}")
axes[0].set_xlabel("time since the end of the sweep (s)")
axes[0].set_ylabel("tip position (mm)")
axes[0].set_title("Streamed estimate (thin) and tracked tip (wide, pale)")
axes[0].legend(ncol=3, loc="upper right")
axes[1].hist(latency_us, bins=np.linspace(0, np.percentile(latency_us, 99.5), 60), color="0.4")
axes[1].axvline(np.median(latency_us), color="tab:red", label=f"median {np.median(latency_us):.0f} us")
axes[1].set_xlabel("time of one step (us), backbone included")
axes[1].set_ylabel("steps")
axes[1].legend()
plt.show()

# %%
# A change alarm in the loop
# --------------------------
#
# The estimate is only as good as the sweep it was calibrated on: once the
# shaft is repositioned, the backbone's calibration and the context are
# stale. A :class:`~skcath.online.ShaftChangeDetector` passed as
# ``detector`` is started on the same sweep and stepped with the same
# samples; ``shaft_changed_`` is True on the sample that raises the alarm
# (:doc:`/shaft_change`). Here the same run is simulated with its shaft moved
# to another setting during the motion (``make_benchmark(...,
# shaft_change=True)``, whose ``runs`` table says when and to which setting).
changed = make_benchmark(n_catheters=1, n_runs=1, shaft_change=True)
info = changed.runs.set_index("setting").loc["S06"]
run_c = changed.X[(changed.X["setting"] == "S06").to_numpy()]
y_c = np.asarray(changed.y)[(changed.X["setting"] == "S06").to_numpy()]
motion_c = (run_c["phase"] == "motion").to_numpy()
t_c = run_c.loc[motion_c, "t"].to_numpy()
change_at = info["change_time_s"] - t_c[0]  # the runs table counts from the start of the run
t_c = t_c - t_c[0]

est_c = OnlineEstimator(pipe, detector=ShaftChangeDetector()).start(run_c[~motion_c])
tips_c = np.empty((motion_c.sum(), 3))
alarm_at = None
for k, (q1, q2, tau1, tau2) in enumerate(run_c.loc[motion_c, ["q1", "q2", "tau1", "tau2"]].to_numpy()):
    est_c.step(q1, q2, tau1, tau2, out=tips_c[k])
    if est_c.shaft_changed_ and alarm_at is None:
        alarm_at = t_c[k]  # on the drive: stop, and ask for a new sweep
print(f"shaft moved to {info['setting_after']} at {change_at:.1f} s of motion; "
      f"alarm at {'none' if alarm_at is None else f'{alarm_at:.1f} s'}")

error = np.linalg.norm(tips_c - y_c[motion_c], axis=1)
fig, ax = plt.subplots(figsize=(9, 3.5), layout="constrained")
ax.plot(t_c, error, color="0.3", lw=1)
ax.axvline(change_at, color="tab:orange", ls="--", label="shaft repositioned")
if alarm_at is not None:
    ax.axvline(alarm_at, color="tab:red", label="alarm")
ax.set_xlabel("time since the end of the sweep (s)")
ax.set_ylabel("tip error (mm)")
ax.set_title("Streamed estimate of a run whose shaft moves, with the change alarm")
ax.legend(loc="upper left")
plt.show()

# %%
# A new motion segment and the exported network
# ---------------------------------------------
#
# ``reset`` starts a new motion sequence from a zero GRU state, as right
# after ``start``; a new sweep (after the shaft has moved) needs a new
# ``start``. To run the network outside Python, :func:`skcath.online.export`
# writes one GRU step as ONNX or TorchScript, with the run's sweep frame and
# context as inputs; these are its inputs and outputs:
est.reset()
inputs, outputs = export_io(pipe)
print("inputs:", inputs)
print("outputs:", outputs)
