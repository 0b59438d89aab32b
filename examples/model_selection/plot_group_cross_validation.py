"""
==============================================
Cross-validation that holds out shaft settings
==============================================

A tip estimator is calibrated on a sweep and then used on motion it has never
seen, in a shaft configuration it has never seen: every time the shaft is
moved, the tendons respond differently. Its evaluation has to hold out the
same things. This example shows why splitting the rows of the recordings at
random would flatter a learned model, draws the folds of the three splitters
of :mod:`skcath.model_selection`, and passes them as ``cv=`` to
:func:`~sklearn.model_selection.cross_validate` with the run-weighted score
:data:`~skcath.metrics.run_rmse_scorer`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Why random row splits leak
# --------------------------
#
# We load two catheters of the simulated benchmark, each of their 17 shaft
# settings recorded once (34 runs), and compute the error of the
# per-direction backbone on every row. A learned residual is trained to
# predict this error.
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.colors import ListedColormap
from sklearn.model_selection import cross_validate
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import run_rmse_scorer
from skcath.model_selection import LeaveOneCatheterOut, LeaveOneSettingOut, SettingGroupKFold
from skcath.residuals import MLPResidual, NoResidual

data = make_benchmark(n_catheters=2, n_runs=1)
X, y = data.X, data.y
error = y - PDLBackbone().fit(X).predict(X)

# %%
# The samples of one run are far from independent. The autocorrelation of
# the backbone error along the motion phase of a run, averaged over the
# runs, is 0.99 between neighbouring samples of the 10 Hz recording and stays
# above 0.5 for more than a second: the error is the slowly changing lag of
# the tendon transmission, not noise.
#
# Split the rows of the data set at random into 5 folds, and a test row's
# previous and next samples are both in the training set 64 % of the time,
# and at least one of them 96 % of the time. A model can then score well by
# recalling the error of the neighbouring samples, which says nothing about a
# new run. The shaft setting adds a second level: the runs of one setting
# share the shaft configuration, and with it how the tendons respond, so a
# repeat of the held-out setting in the training set would tell the model
# what it cannot know about a new configuration. Hence the unit to hold out
# is the setting, with all its runs.
lags = np.arange(0, 51)
autocorrelation = []
for run in X["run"].unique():
    rows = ((X["run"] == run) & (X["phase"] == "motion")).to_numpy()
    e = error[rows] - error[rows].mean(axis=0)
    autocorrelation.append([np.sum(e[: len(e) - k] * e[k:]) / np.sum(e * e) for k in lags])
autocorrelation = np.mean(autocorrelation, axis=0)

fig, ax = plt.subplots(figsize=(7, 3.8), layout="constrained")
ax.plot(lags / 10.0, autocorrelation, "o-", ms=3)
ax.axvline(0.1, color="tab:red", ls="--", lw=1)
ax.annotate(
    f"neighbouring sample: {autocorrelation[1]:.2f}",
    (0.1, autocorrelation[1]),
    (0.8, 0.85),
    arrowprops={"arrowstyle": "->"},
)
ax.set_xlabel("lag (s)")
ax.set_ylabel("autocorrelation")
ax.set_title("Backbone error along a run, averaged over 34 runs")
ax.grid(alpha=0.3)
plt.show()

# %%
# Three splitters
# ---------------
#
# The splitters of :mod:`skcath.model_selection` read the ``catheter`` and
# ``setting`` columns of ``X``; their ``groups`` argument is ignored. A run
# belongs to one catheter and one setting, so its rows, sweep and motion,
# always stay together.
#
# * :class:`~skcath.model_selection.LeaveOneSettingOut` holds out one setting
#   of one catheter and trains on the **same catheter's** other settings
#   (the paper's protocol: a model per catheter).
# * :class:`~skcath.model_selection.SettingGroupKFold` holds out groups of
#   settings within each catheter, ``n_splits`` folds per catheter: fewer
#   fits for a quicker estimate.
# * :class:`~skcath.model_selection.LeaveOneCatheterOut` holds out a whole
#   catheter and trains on all the others: does the model carry over to a
#   new device?
#
# ``exclude_settings=("S00",)`` never tests the straight shaft, which stays
# in training. The figure shows, for every fold (rows), which runs (columns)
# train the model and which are held out.
splitters = {
    "LeaveOneSettingOut": LeaveOneSettingOut(exclude_settings=("S00",)),
    "SettingGroupKFold(n_splits=2)": SettingGroupKFold(n_splits=2, exclude_settings=("S00",)),
    "LeaveOneCatheterOut": LeaveOneCatheterOut(exclude_settings=("S00",)),
}
runs = data.runs["run"].to_numpy()
run_position = pd.Series(np.arange(len(runs)), index=runs)[X["run"].astype(str)].to_numpy()


def fold_matrix(cv):
    """0: run not used, 1: training run, 2: held-out run; one row per fold."""
    matrix = np.zeros((cv.get_n_splits(X), len(runs)), dtype=int)
    for k, (train, test) in enumerate(cv.split(X)):
        matrix[k, np.unique(run_position[train])] = 1
        matrix[k, np.unique(run_position[test])] = 2
    return matrix


cmap = ListedColormap(["0.93", "tab:blue", "tab:orange"])
fig, axes = plt.subplots(
    3, 1, figsize=(10, 9.5), layout="constrained", height_ratios=[32, 4, 2], sharex=True
)
for ax, (name, cv) in zip(axes, splitters.items()):
    matrix = fold_matrix(cv)
    ax.imshow(matrix, cmap=cmap, vmin=0, vmax=2, aspect="auto", interpolation="none")
    ax.set_title(f"{name}: {len(matrix)} folds", loc="left")
    ax.set_ylabel("fold")
    ax.set_yticks(np.arange(len(matrix)), np.arange(1, len(matrix) + 1), fontsize="x-small")
    ax.axvline(16.5, color="k", lw=1)
axes[-1].set_xticks(np.arange(len(runs)), data.runs["setting"], rotation=90, fontsize="small")
axes[-1].set_xlabel("run: shaft setting (catheter C1 left of the black line, C2 right)")
handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(k)) for k in range(3)]
fig.legend(handles, ["not used", "training", "held out"], loc="outside lower center", ncols=3)
plt.show()

# %%
# Cross-validating a pipeline
# ---------------------------
#
# A splitter is passed as ``cv=`` like any scikit-learn splitter, here to
# :func:`~sklearn.model_selection.cross_validate`. The score is
# :data:`~skcath.metrics.run_rmse_scorer`: the mean per-run RMSE (mm) over the
# motion rows of the held-out runs, negated as scikit-learn scorers are
# (greater is better). We compare the backbone alone with the backbone
# corrected by an :class:`~skcath.residuals.MLPResidual`, trained very briefly
# (5 epochs, 32 hidden units) so that the example runs in seconds; the
# default trains for 40 epochs.
pipelines = {
    "PDL": Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())]),
    "PDL + MLP": Pipeline(
        [
            ("backbone", PDLBackbone()),
            ("residual", MLPResidual(max_epochs=5, module__hidden_size=32, n_threads=1, random_state=0)),
        ]
    ),
}
cv = splitters["SettingGroupKFold(n_splits=2)"]
scores = {
    name: cross_validate(pipe, X, y, cv=cv, scoring=run_rmse_scorer, return_indices=True)
    for name, pipe in pipelines.items()
}
for name, result in scores.items():
    print(f"{name:>9}: {-result['test_score'].mean():.2f} mm mean per-run RMSE, folds {-result['test_score'].round(2)}")

# %%
# Each fold's score, with the settings it held out. The scores differ more
# from fold to fold, and above all from catheter to catheter, than from one
# pipeline to the other: compare pipelines fold by fold, on the same
# held-out runs, rather than by their spread.
held_out = [
    f"{X['catheter'].iloc[test[0]]}\n"
    + " ".join(s[1:] for s in pd.unique(X["setting"].iloc[test].astype(str)))
    for test in scores["PDL"]["indices"]["test"]
]
positions = np.arange(len(held_out))
fig, ax = plt.subplots(figsize=(10, 4.2), layout="constrained")
for k, (name, color) in enumerate([("PDL", "tab:red"), ("PDL + MLP", "tab:purple")]):
    ax.bar(positions + (k - 0.5) * 0.38, -scores[name]["test_score"], 0.38, color=color, alpha=0.8, label=name)
ax.set_xticks(positions, held_out, fontsize="small")
ax.set_xlabel("fold: catheter and held-out settings (S..)")
ax.set_ylabel("mean per-run RMSE (mm)")
ax.set_title("SettingGroupKFold: score of every fold")
ax.legend(loc="lower right")
ax.grid(axis="y", alpha=0.3)
plt.show()

# %%
# The same pipeline across catheters
# ----------------------------------
#
# With :class:`~skcath.model_selection.LeaveOneCatheterOut` the residual is
# trained on one catheter and tested on the bent settings of the other. The
# backbone is still calibrated on every held-out run's own sweep; only the
# learned correction has to carry over.
across = cross_validate(pipelines["PDL + MLP"], X, y, cv=splitters["LeaveOneCatheterOut"], scoring=run_rmse_scorer)


def per_catheter(result):
    """Mean score of the folds of each catheter (two equal folds each), in mm."""
    return -result["test_score"].reshape(2, -1).mean(axis=1)


pd.DataFrame(
    {
        "PDL alone": per_catheter(scores["PDL"]),
        "PDL + MLP, settings held out": per_catheter(scores["PDL + MLP"]),
        "PDL + MLP, catheter held out": -across["test_score"],
    },
    index=pd.Index(["C1", "C2"], name="tested catheter"),
).round(2)

# %%
# Trained on the other catheter, the correction makes the estimate worse
# than the backbone alone, on both catheters. Within a catheter, a held-out
# setting still shares the catheter's own tendons and friction with the
# training settings; across catheters it does not, and what the residual
# learned about one transmission misleads it on another. This is why the
# learned models are trained, or at least fine-tuned, on the catheter they
# are used with (see *Two-stage training* on the :doc:`residuals page
# </residuals>`, which also has the results of the default, much longer
# training, held out setting by setting on all four catheters).
