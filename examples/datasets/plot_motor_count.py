"""
=========================================
Instruments of one, two and three motors
=========================================

Tendon-driven instruments do not all have two motors. The simulator records
three kinds (``n_motors`` of :func:`~skcath.datasets.make_benchmark` and
:func:`~skcath.datasets.simulate_run`): one motor pulling one tendon pair
that bends the section in a single plane, the benchmark's two motors with two
pairs at 90 degrees, and three motors each pulling a single tendon, the
tendons at 120 degrees around the section. This example simulates one
catheter of each, fits the memoryless
:class:`~skcath.backbones.PolynomialBackbone` of the motor angles and a
:class:`~skcath.residuals.GRUResidual` on top of it, and compares their tip
errors on shaft settings held out of training. The instruments are
described on the :doc:`simulator page </studies/simulator>`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Three instruments
# -----------------
#
# The three benchmarks have one catheter unit each, recorded once in each of
# the 17 shaft settings. The unit is the same in the three (its section,
# friction and drive train); only its tendons differ. The recordings have
# one motor angle and one torque column per motor, ``q1 .. qN`` and
# ``tau1 .. tauN``.
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from sklearn.pipeline import Pipeline

from skcath import motor_columns
from skcath.backbones import PolynomialBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse
from skcath.residuals import GRUResidual, NoResidual

MOTORS = (1, 2, 3)
data = {n: make_benchmark(n_catheters=1, n_runs=1, n_motors=n) for n in MOTORS}
for n, bench in data.items():
    motors, torques = motor_columns(bench.X)
    print(f"{n} motor(s): columns {', '.join(motors + torques)}; {len(bench.X)} samples; "
          f"noise floor {bench.noise_floor:.2f} mm")

# %%
# The calibration sweep of each instrument
# ----------------------------------------
#
# Every run starts with a sweep that moves the motors out and back along a
# few rays from neutral, at constant speed, and goes on with a random walk.
# One motor sweeps to both signs of its one axis; two motors along 8 rays of
# their plane; three motors along 6 rays: towards each tendon (pull it, pay
# out the two others) and between two tendons (pull both, pay out the
# third). The three-tendon drive pays out a released tendon by three
# quarters of what the geometry asks, so that it stays taut.
fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True, layout="constrained")
for ax, (n, bench) in zip(axes, data.items()):
    X = bench.X
    run = X["run"].cat.categories[0]
    rows = ((X["run"] == run) & (X["phase"] == "sweep")).to_numpy()
    motors, _ = motor_columns(X)
    for motor in motors:
        ax.plot(X.loc[rows, "t"], X.loc[rows, motor], label=motor)
    ax.set_ylabel("angle (deg)")
    ax.set_title(f"{n} motor(s): the sweep of run {run}", fontsize=10)
    ax.legend(loc="upper right", fontsize=8, ncol=3)
axes[-1].set_xlabel("time (s)")
plt.show()

# %%
# A polynomial backbone and a GRU residual
# ----------------------------------------
#
# The geometric backbones PCC and PDL model two bending motors; the
# polynomial backbone fits the tip as a polynomial of the motor angles of
# any number of motors, calibrated on each run's sweep. The GRU learns the
# backbone's error from the history of the motor angles and torques and a
# context encoded from the sweep. Four settings are held out, two at the low
# and two at the high bend level. The GRU is trained briefly (15 epochs, 32
# hidden units instead of 40 and 128) so that the example runs in about a
# minute.
held_out = ["S03", "S07", "S11", "S15"]


def pipelines():
    """The backbone alone and the backbone with a small GRU residual."""
    gru = GRUResidual(max_epochs=15, module__hidden_size=32, n_threads=1, random_state=0)
    return {
        "polynomial": Pipeline([("backbone", PolynomialBackbone()), ("residual", NoResidual())]),
        "polynomial + GRU": Pipeline([("backbone", PolynomialBackbone()), ("residual", gru)]),
    }


scores = {}
for n, bench in data.items():
    X, y = bench.X, bench.y
    test = X["setting"].isin(held_out).to_numpy()
    for name, pipe in pipelines().items():
        pipe.fit(X[~test], y[~test])
        scores[n, name] = mean_per_run_rmse(y[test], pipe.predict(X[test]), X[test])
table = pd.Series(scores).unstack()
table.index.name = "motors"
print("mean per-run RMSE on the held-out settings (mm)")
print(table.round(2).to_string())

# %%
# The error of each instrument
# ----------------------------
#
# The polynomial of the motor angles cannot follow the hysteresis of the
# tendons: the tip of the same motor angles differs between the outward and
# the return move. The GRU, which sees the motor history, removes part of
# that error on every instrument: about half of it with one motor, less
# with two and three motors after this short training.
fig, ax = plt.subplots(figsize=(6, 3.4), layout="constrained")
width = 0.38
x = np.arange(len(MOTORS))
for k, name in enumerate(table.columns):
    bars = ax.bar(x + (k - 0.5) * width, table[name], width, label=name)
    ax.bar_label(bars, fmt="%.2f", fontsize=8)
ax.set_xticks(x, [f"{n} motor(s)" for n in MOTORS])
ax.set_ylabel("mean per-run RMSE (mm)")
ax.set_title("Tip error on held-out shaft settings")
ax.legend()
plt.show()
