"""
==================================
Steering the tip along a circle
==================================

A fitted tip model says where the tip is; :mod:`skcath.control` turns it
into motor commands. This example fits a small model (a PDL backbone with
the play identified on the sweep, no learned residual, so that it runs in
seconds), then drives a simulated catheter of another unit along a circle
with four controllers: the inverse of a PCC backbone in open loop (what a
robot without a learned model commands), the feedforward inverse of the
fitted model, the same closed on the streamed estimate, and closed on the
tracker (the bound a tracker in the loop gives). See :doc:`/steering`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# A small model and a rig
# -----------------------
#
# The model is fitted on one simulated unit; the rig is another unit
# (``catheter=2``) in a shaft setting, its tracker on so that the last
# controller can read it.
import warnings

import matplotlib.pyplot as plt
import numpy as np
from sklearn.pipeline import Pipeline

from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.control import FeedbackController, FeedforwardController, UnreachableTargetWarning
from skcath.datasets import SimulatedCatheter, circle_task, make_benchmark, run_task, task_scores
from skcath.residuals import NoResidual

bench = make_benchmark(n_catheters=1, n_runs=1)
X, y = bench.X, np.asarray(bench.y)
backbone = PDLBackbone(hysteresis="play").fit(X)
model = Pipeline([("backbone", backbone), ("residual", NoResidual().fit(backbone.transform(X), y))])
pcc = Pipeline([("backbone", PCCBackbone().fit(X))])

rig = SimulatedCatheter(catheter=2, setting="S05", tracker=True, random_state=0)
sweep = rig.reset()
task = circle_task(sweep, speed_mm_s=5.0, n_laps=1)
print(f"circle of {task.duration_s:.0f} s at {task.rate_hz:g} Hz")

# %%
# Four controllers, one task
# --------------------------
#
# Every controller starts on the rig's sweep and returns one motor command
# per sample, never faster than 60 deg/s. ``latency=1`` (the default) says
# that the rig's record of a sample comes back one command late.
controllers = {
    "PCC inverse, open loop": FeedforwardController(pcc, rate_limit=60.0),
    "feedforward": FeedforwardController(model, rate_limit=60.0),
    "closed on the estimate": FeedbackController(model, rate_limit=60.0),
    "closed on the tracker": FeedbackController(model, close_on="tracker", rate_limit=60.0),
}
results = {}
with warnings.catch_warnings():
    warnings.simplefilter("ignore", UnreachableTargetWarning)
    for name, controller in controllers.items():
        results[name] = run_task(rig, controller, task)
        scores = task_scores(results[name])
        print(f"{name:24s} true tip error RMS {scores['rms_mm']:5.2f} mm, p95 {scores['p95_mm']:5.2f} mm")

# %%
# The target and the true tip
# ---------------------------
#
# The tip's path seen from above the base frame (x, y). The PCC inverse
# misses the circle by its model error and by the play it does not
# compensate; the fitted model's inverse compensates the play; the tracker
# in the loop removes most of what the model gets wrong.
fig, axes = plt.subplots(1, 4, figsize=(13, 3.6), sharex=True, sharey=True)
scored = task.scored
for ax, (name, result) in zip(axes, results.items()):
    ax.plot(*task.target[scored, :2].T, "k--", lw=1, label="target")
    ax.plot(*result.tip[scored, :2].T, lw=1.2, label="true tip")
    ax.set_title(name, fontsize=9)
    ax.set_xlabel("x (mm)")
    ax.set_aspect("equal")
axes[0].set_ylabel("y (mm)")
axes[0].legend(fontsize=8)
fig.tight_layout()
plt.show()
