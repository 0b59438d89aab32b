"""
==================================
Choosing a backbone and a residual
==================================

The backbone and the residual learner are steps of one scikit-learn
:class:`~sklearn.pipeline.Pipeline`, so the choice between them is a
parameter search like any other. This example runs
:class:`~sklearn.model_selection.GridSearchCV` over the two backbones of
:mod:`skcath.backbones` and three residual steps, the backbone alone
(:class:`~skcath.residuals.NoResidual`), the per-step
:class:`~skcath.residuals.MLPResidual` and the recurrent
:class:`~skcath.residuals.GRUResidual`, with shaft settings held out by
:class:`~skcath.model_selection.SettingGroupKFold`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Data and folds
# --------------
#
# We use one catheter of the simulated benchmark, in its straight setting and
# the 8 settings at the high bend level, one run each. The splitter holds out
# the bent settings in two groups of four, so every candidate is fitted twice
# on five runs and scored on the four others; the straight setting
# (``S00``) is only used for training. Why whole settings are held out is
# explained in
# :ref:`sphx_glr_auto_examples_model_selection_plot_group_cross_validation.py`.
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from sklearn.model_selection import GridSearchCV
from sklearn.pipeline import Pipeline

from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import run_rmse_scorer
from skcath.model_selection import SettingGroupKFold
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

data = make_benchmark(n_catheters=1, n_runs=1)
keep = data.X["setting"].isin(["S00", "S09", "S10", "S11", "S12", "S13", "S14", "S15", "S16"]).to_numpy()
X, y = data.X[keep], data.y[keep]
cv = SettingGroupKFold(n_splits=2, exclude_settings=("S00",))
for k, (train, test) in enumerate(cv.split(X)):
    print(f"fold {k + 1}: held out {sorted(X['setting'].iloc[test].unique())}")

# %%
# The grid
# --------
#
# Pipeline steps are parameters of the pipeline, so the grid lists the
# estimators themselves. The learners are trained very briefly here, 5
# epochs with 32 hidden units, so that the search takes seconds; their
# defaults train for 40 epochs with 128 units (GRU). With ``refit=True``
# the best candidate is fitted again on all the data, ready to predict.
pipe = Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())])
tiny = {"max_epochs": 5, "module__hidden_size": 32, "n_threads": 1, "random_state": 0}
param_grid = {
    "backbone": [PCCBackbone(), PDLBackbone()],
    "residual": [NoResidual(), MLPResidual(**tiny), GRUResidual(**tiny)],
}
search = GridSearchCV(pipe, param_grid, cv=cv, scoring=run_rmse_scorer, refit=True)
search.fit(X, y)

# %%
# The results
# -----------
#
# ``cv_results_`` has one row per candidate. The scores are negated mean
# per-run RMSEs (greater is better), so we turn them back into millimetres,
# and we name each candidate by its classes.
results = pd.DataFrame(search.cv_results_)
table = pd.DataFrame(
    {
        "backbone": [type(b).__name__.removesuffix("Backbone") for b in results["param_backbone"]],
        "residual": [type(r).__name__.removesuffix("Residual") for r in results["param_residual"]],
        "RMSE (mm)": -results["mean_test_score"],
        "std (mm)": results["std_test_score"],
        "fold 1 (mm)": -results["split0_test_score"],
        "fold 2 (mm)": -results["split1_test_score"],
        "fit time (s)": results["mean_fit_time"],
        "rank": results["rank_test_score"],
    }
)
table.sort_values("rank").round(2)

# %%
# ``best_params_`` holds the winning estimators themselves:
print("best:", {step: type(estimator).__name__ for step, estimator in search.best_params_.items()})
print(f"best score: {-search.best_score_:.2f} mm")

# %%
# The mean RMSE of every candidate, with the two folds as dots:
residuals = ["No", "MLP", "GRU"]
colors = {"PCC": "tab:blue", "PDL": "tab:red"}
positions = np.arange(len(residuals))
width = 0.38
fig, ax = plt.subplots(figsize=(7, 4.2), layout="constrained")
for k, backbone in enumerate(["PCC", "PDL"]):
    rows = table[table["backbone"] == backbone].set_index("residual").loc[residuals]
    x = positions + (k - 0.5) * width
    ax.bar(x, rows["RMSE (mm)"], width, color=colors[backbone], alpha=0.75, label=backbone)
    for fold in ["fold 1 (mm)", "fold 2 (mm)"]:
        ax.plot(x, rows[fold], "k.", ms=6)
ax.set_xticks(positions, ["none", "MLP", "GRU"])
ax.set_xlabel("residual learner")
ax.set_ylabel("mean per-run RMSE over held-out runs (mm)")
ax.set_title("Grid search: score of every candidate (dots: folds)")
ax.legend(title="backbone", loc="lower left")
ax.grid(axis="y", alpha=0.3)
plt.show()

# %%
# PDL is the better backbone with any residual step, and both learners
# lower the error of either backbone. Even with this short training the
# GRU, which carries the motor history in its state, gains the most; the
# MLP, which only sees the current step and its difference from the last
# one, gains less. A learner does not make up for the weaker backbone: the
# corrected PCC stays behind PDL alone. In the table, the fit time of the
# backbone alone is the calibration of the training runs, and the learners
# add their training (the first learner fitted also pays for starting
# torch); the times are wall-clock and depend on the machine.
#
# The search refitted the best pipeline on all nine runs; it predicts the
# tip of any run of this catheter from its sweep and its motor signals.
best = search.best_estimator_
print([type(step).__name__ for _, step in best.steps])
print(f"tip estimates of run C1-S12-R1: {best.predict(X[X['setting'] == 'S12']).shape}")

# %%
# With the default training and the full protocol (each of the 16 bent
# settings held out in turn, three runs per setting), PDL + GRU reaches
# about half the error of PDL alone; see the :doc:`residuals page
# </residuals>`.
