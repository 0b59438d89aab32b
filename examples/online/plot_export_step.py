"""
===========================================
The whole step in ONNX, run by onnxruntime
===========================================

A controller written in C++ cannot import skcath. ``export`` writes the
whole step of a started :class:`~skcath.online.OnlineEstimator` as one ONNX
graph: the play in front of the backbone, the backbone with the run's
calibration, the step features, the network with the run's sweep frame and
context, the clip. The graph takes one motor sample and the stream state
and returns the tip and the next state. This example exports it, steps it
in a loop with onnxruntime alone and compares it with ``predict``. See
:doc:`/deploying` (*Exporting the whole step*) for the inputs and outputs.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# A fitted pipeline and a started estimator
# -----------------------------------------
#
# A small PDL (with the play of ``hysteresis="play"``) + GRU pipeline,
# trained briefly; ``start`` takes the sweep of a held-out run.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.online import OnlineEstimator, export, export_io
from skcath.residuals import GRUResidual

data = make_benchmark(n_catheters=1, n_runs=1)
X, y = data.X, np.asarray(data.y)
train = X["setting"].isin(["S02", "S08", "S13"]).to_numpy()
pipe = Pipeline([
    ("backbone", PDLBackbone(hysteresis="play")),
    ("residual", GRUResidual(max_epochs=2, module__hidden_size=32, n_threads=1, random_state=0)),
])
pipe.fit(X[train], y[train])

run = X[(X["setting"] == "S06").to_numpy()]
is_motion = (run["phase"] == "motion").to_numpy()
est = OnlineEstimator(pipe).start(run[~is_motion])

# %%
# Export
# ------
#
# ``export(est, path)`` writes the whole step; ``export(pipe, path)`` would
# write the network alone. The names and shapes are those a C++ caller
# declares.
path = Path(tempfile.mkdtemp()) / "whole_step.onnx"
export(est, path)
inputs, outputs = export_io(est)
print("inputs:", inputs)
print("outputs:", outputs)
print(f"{path.stat().st_size / 1e3:.0f} kB")

# %%
# The loop, with onnxruntime alone
# --------------------------------
#
# Nothing of skcath or torch runs here: one ``session.run`` per sample, the
# state fed back. ``reset=True`` on the first sample starts from the state
# right after ``start``; ``valid`` says whether ``step`` would accept the
# sample.
import onnxruntime as ort

options = ort.SessionOptions()
options.intra_op_num_threads = 1
session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])

samples = run.loc[is_motion, list(est.channels_)].to_numpy()
state = np.zeros(inputs["state"])
reset = np.array([True])
tips = np.empty((len(samples), 3))
for k, sample in enumerate(samples):
    tip, state, valid = session.run(None, {"sample": sample[None], "state": state, "reset": reset})
    reset = np.array([False])
    tips[k] = tip[0]

# %%
# Against ``predict``
# -------------------
#
# The graph computes in float64 what the estimator's step computes, so it
# matches ``predict`` (float32) to its rounding.
offline = pipe.predict(run)[is_motion]
print(f"largest difference to predict: {np.abs(tips - offline).max():.1e} mm")

t = run.loc[is_motion, "t"].to_numpy()
t = t - t[0]
window = t < 60
fig, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
for i, axis in enumerate("xyz"):
    axes[0].plot(t[window], offline[window, i], color=f"C{i}", lw=2.5, alpha=0.4)
    axes[0].plot(t[window], tips[window, i], color=f"C{i}", lw=0.8, label=f"{axis} (graph)")
axes[0].set_ylabel("tip (mm)")
axes[0].legend(loc="upper right", fontsize=8)
axes[0].set_title("exported step (thin) and predict (wide)")
axes[1].semilogy(t[window], np.abs(tips - offline).max(axis=1)[window] + 1e-12)
axes[1].set_ylabel("|graph - predict| (mm)")
axes[1].set_xlabel("time in the run (s)")
fig.tight_layout()
plt.show()
