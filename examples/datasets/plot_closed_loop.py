"""
====================================
Steering a simulated catheter
====================================

:class:`~skcath.datasets.SimulatedCatheter` is a run of the simulated
benchmark whose motion a controller drives one sample at a time. This
example performs the run's calibration sweep, builds a circle task inside
the workspace the sweep reached, and steers the tip along it with a naive
open-loop controller: it commands the motor angles of the sweep sample whose
tracked tip is nearest the target. The hysteresis of the tendons, which the
controller ignores, shows as the gap between the target and the true tip.
The rig, the tasks and their scores are described in
:ref:`simulated_catheter`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# The rig and its sweep
# ---------------------
#
# Unit 5 of the benchmark's seed (the default benchmark holds units 1-4) in
# the shaft setting S06, with the play mechanism, at 10 Hz. ``reset``
# performs the run's 8-ray sweep and returns its rows, with the tracked tip
# in ``ref_x``, ``ref_y``, ``ref_z`` (mm, base frame).
import matplotlib.pyplot as plt
import numpy as np

from skcath.datasets import SimulatedCatheter, circle_task, run_task, task_scores

rig = SimulatedCatheter(catheter=5, setting="S06", mechanism="play", random_state=0)
sweep = rig.reset()
print(f"{len(sweep)} sweep rows, {len(sweep) / rig.rate_hz:.0f} s")


# %%
# A controller
# ------------
#
# A controller has ``start(sweep)`` and ``step(target, obs)``, which returns
# the motor angles (deg) for the sample the target is given for. This one
# looks the target up among the swept tips.
class SweepLookup:
    def start(self, sweep):
        self.tips = sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()
        self.q = sweep[["q1", "q2"]].to_numpy()

    def step(self, target, obs):
        return self.q[np.argmin(np.linalg.norm(self.tips - target, axis=1))]


# %%
# The circle task
# ---------------
#
# A circle at 5 mm/s on the surface the sweep reached, after an unscored
# lead-in from the neutral tip. ``run_task`` resets the rig, starts the
# controller and steps both; the true tip of each sample is scored against
# its target.
task = circle_task(sweep, speed_mm_s=5.0, n_laps=1)
result = run_task(rig, SweepLookup(), task)
scores = task_scores(result)
print({k: round(v, 2) for k, v in scores.items() if np.isfinite(v)})

tips = sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()
fig, (ax, ax_err) = plt.subplots(1, 2, figsize=(10, 4.2))
ax.plot(tips[:, 0], tips[:, 1], ".", ms=1, color="0.8", label="sweep (tracked)")
ax.plot(*task.target[task.scored, :2].T, "k--", label="target")
ax.plot(*result.tip[task.scored, :2].T, color="C3", label="true tip")
ax.set(xlabel="x (mm)", ylabel="y (mm)", title="Base frame, seen along z", aspect="equal")
ax.legend(loc="best", fontsize=8)
ax_err.plot(result.t - result.t[0], result.error, color="C3")
ax_err.axvspan(0, (~task.scored).sum() / task.rate_hz, color="0.9", label="lead-in (not scored)")
ax_err.set(xlabel="time (s)", ylabel="tip error (mm)", title=f"RMS {scores['rms_mm']:.1f} mm")
ax_err.legend(loc="upper right", fontsize=8)
fig.tight_layout()
plt.show()
