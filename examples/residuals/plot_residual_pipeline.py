"""
===================================
A GRU residual on top of a backbone
===================================

A geometric backbone follows the motor angles at once, but the tip of a
tendon-driven catheter lags behind them, by an amount that depends on the
motor history. :class:`~skcath.residuals.GRUResidual` learns this error of the
backbone from the history of the motor angles and torques and from a context
encoded from the run's calibration sweep. This example composes it with
:class:`~skcath.backbones.PDLBackbone` in a scikit-learn
:class:`~sklearn.pipeline.Pipeline`, trains it on some shaft settings of one
simulated catheter and evaluates it on settings it has never seen, against
the backbone alone. The model is described on the :doc:`residuals page
</residuals>`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Training and held-out settings
# ------------------------------
#
# We load one catheter of the simulated benchmark, each of its 17 shaft
# settings recorded once. Four settings are held out, two at the low and two
# at the high bend level; the pipeline is trained on the 13 others. Holding
# out whole settings is what the estimator faces in use: every time the shaft
# is moved, the transmission changes, and only the new sweep tells the model
# how.
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse, per_run_rmse
from skcath.residuals import GRUResidual, NoResidual

data = make_benchmark(n_catheters=1, n_runs=1)
X, y = data.X, data.y

held_out = ["S03", "S07", "S11", "S15"]
test = X["setting"].isin(held_out).to_numpy()
X_train, y_train = X[~test], y[~test]
X_test, y_test = X[test], y[test]
print(f"{X_train['run'].nunique()} training runs, {X_test['run'].nunique()} held-out runs")

# %%
# Two pipelines
# -------------
#
# Both pipelines start with the backbone, whose ``transform`` calibrates each
# run on its own sweep and appends the nominal tip ``b_x, b_y, b_z`` to the
# recordings. The baseline ends with :class:`~skcath.residuals.NoResidual`,
# which returns the nominal tip unchanged; the other ends with the GRU, which
# adds a learned correction to it.
#
# The GRU is trained here far more briefly than by default, so that this
# example runs in seconds: 10 epochs instead of 40, a hidden state of 32
# units instead of 128, and one run per training setting instead of the
# three of the full benchmark. Every
# network parameter is a constructor argument (``module__hidden_size``) and,
# inside a pipeline, a parameter of the pipeline
# (``residual__module__hidden_size``), so a grid search can reach it.
# ``n_threads=1`` keeps torch on one CPU thread and ``random_state`` makes
# the fit repeatable.
baseline = Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())])
gru = Pipeline(
    [
        ("backbone", PDLBackbone()),
        ("residual", GRUResidual(max_epochs=10, module__hidden_size=32, n_threads=1, random_state=0)),
    ]
)
print({name: gru.get_params()[name] for name in ["residual__max_epochs", "residual__module__hidden_size"]})

baseline.fit(X_train, y_train)
gru.fit(X_train, y_train)

# %%
# The learner is a :class:`skorch.NeuralNetRegressor`, so its ``history``
# records the training loss of every epoch: the mean squared error of the
# predicted residual, in units of the residual's standard deviation on the
# training data (predicting no correction at all scores 1 or more).
history = gru["residual"].history
fig, ax = plt.subplots(figsize=(5, 3.2), layout="constrained")
ax.plot(history[:, "epoch"], history[:, "train_loss"], "o-")
ax.set_xlabel("epoch")
ax.set_ylabel("normalised training loss")
ax.set_title("GRU residual: training loss")
ax.grid(alpha=0.3)
plt.show()

# %%
# Error on the held-out settings
# ------------------------------
#
# ``predict`` needs, for every held-out run, its sweep rows (they calibrate
# the backbone and give the context) and the motor angles and torques of its
# motion rows; the measured tip of the motion rows is only used to score.
# The score is the RMSE of every run over its motion rows.
predictions = {"PDL": baseline.predict(X_test), "PDL + GRU": gru.predict(X_test)}
rmse = pd.DataFrame({name: per_run_rmse(y_test, p, X_test) for name, p in predictions.items()})
rmse["ratio"] = rmse["PDL + GRU"] / rmse["PDL"]
print(rmse.round(2).to_string())
for name, p in predictions.items():
    print(f"{name:>9}: mean per-run RMSE {mean_per_run_rmse(y_test, p, X_test):.2f} mm")

# %%
# Tip error over time
# -------------------
#
# The tip error of one held-out run at the high bend level, over its whole
# motion phase (top) and over 40 s of it (bottom). The backbone's error comes
# in long swings: after each reversal of the motors the tip stays behind
# while the nominal tip moves on. The GRU, which sees the motor history,
# removes a good part of these swings.
run_id = rmse.index[-1]
in_run = (X_test["run"] == run_id).to_numpy()
motion = (X_test.loc[in_run, "phase"] == "motion").to_numpy()
t = X_test.loc[in_run, "t"].to_numpy()[motion]
t = t - t[0]
errors = {name: np.linalg.norm(p[in_run][motion] - y_test[in_run][motion], axis=1) for name, p in predictions.items()}
colors = {"PDL": "tab:red", "PDL + GRU": "tab:green"}

fig, axes = plt.subplots(2, 1, figsize=(10, 6), layout="constrained")
zoom = (t >= 60) & (t < 100)
for name, error in errors.items():
    label = f"{name} (RMSE {rmse.loc[run_id, name]:.1f} mm)"
    axes[0].plot(t, error, color=colors[name], lw=0.7, label=label)
    axes[1].plot(t[zoom], error[zoom], color=colors[name], lw=1.2, label=label)
axes[0].axvspan(60, 100, color="0.9", zorder=0)
axes[0].set_title(f"Held-out run {run_id}: whole motion phase (shaded: bottom panel)")
axes[1].set_title("40 s of the motion phase")
for ax in axes:
    ax.set_ylabel("tip error (mm)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
axes[1].set_xlabel("time since the end of the sweep (s)")
plt.show()

# %%
# Even with this short training the GRU lowers the error on every held-out
# setting. With the default parameters (40 epochs, 128 hidden units) and all
# three repeats of every training setting, the GRU halves the backbone's
# error on this catheter, from 9.25 to 4.58 mm when each of the 16 bent
# settings is held out in turn; the full results, for all four catheters and
# for the :class:`~skcath.residuals.MLPResidual` ablation, are on the
# :doc:`residuals page </residuals>`. To choose between backbones and
# residual learners by cross-validation, see
# :ref:`sphx_glr_auto_examples_model_selection_plot_grid_search.py`.
