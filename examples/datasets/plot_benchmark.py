"""
================================
The simulated catheter benchmark
================================

:func:`~skcath.datasets.make_benchmark` generates recordings of a family of
tendon-driven catheters with the bench protocol: every run starts with an
8-ray outward-and-return sweep of the two bending motors, then continues with
a 100-step random walk. This example loads a small benchmark (two catheters,
each of the 17 shaft settings recorded once), follows one run with a bent
shaft from the motor angles to the tip position, and measures the hysteresis
of the tendon transmission and how it changes with the shaft bend. The
options are listed in :doc:`/simulated_benchmark`, and the physics behind the
data is described in the :doc:`simulator study </studies/simulator>`.
"""

# Authors: The skcath developers
# SPDX-License-Identifier: BSD-3-Clause

# %%
# Load a small benchmark
# ----------------------
#
# The benchmark is generated on the first call (a few seconds) and cached in
# the data folder (``SKCATH_DATA``, else ``~/skcath_data``) for later calls.
# ``X`` holds one row per sample at 10 Hz in the long format
# (:doc:`/data_format`); ``y`` is the tip position measured by the EM
# tracker, expressed in the frame of the sensor at the base of the bending
# section (mm).
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from skcath.datasets import make_benchmark

data = make_benchmark(n_catheters=2, n_runs=1)
X, y = data.X, data.y
print(data.DESCR)

# %%
# Each run belongs to one shaft setting: straight (``S00``), or held bent in
# one of 8 directions at a low (``S01``-``S08``) or high (``S09``-``S16``)
# level. The more the shaft is bent, the larger the capstan wrap of the
# tendons through it. The runs of the first catheter:
columns = ["run", "bend_level", "bend_direction_deg", "shaft_wrap_deg", "n_samples", "n_sweep"]
data.runs.loc[data.runs["catheter"] == "C1", columns]

# %%
# We follow the first run recorded with the shaft at the high bend level.
run_id = data.runs.loc[data.runs["bend_level"] == "high", "run"].iloc[0]
in_run = (X["run"] == run_id).to_numpy()
run_X, run_y = X[in_run], y[in_run]
is_sweep = (run_X["phase"] == "sweep").to_numpy()
t = run_X["t"].to_numpy()
t_switch = t[is_sweep].max()
print(f"{run_id}: {len(run_X)} samples, sweep until t = {t_switch:.1f} s")

# %%
# Tip trajectory
# --------------
#
# The sweep traces 8 spokes from the neutral tip position; the random walk
# then covers the workspace between them. The base-sensor frame is tilted
# with respect to the axis of the bending section, so the neutral tip does
# not lie on the z axis of this frame.
fig, axes = plt.subplots(1, 2, figsize=(10, 4.8), layout="constrained")
for ax, (i, j) in zip(axes, [(0, 1), (0, 2)]):
    ax.plot(run_y[~is_sweep, i], run_y[~is_sweep, j], lw=0.5, color="tab:orange", alpha=0.7, label="random walk")
    ax.plot(run_y[is_sweep, i], run_y[is_sweep, j], lw=0.8, color="tab:blue", label="sweep")
    ax.plot(*run_y[0, [i, j]], "k*", ms=12, label="neutral (t = 0)")
    ax.set_xlabel(f"tip {'xyz'[i]} in base frame (mm)")
    ax.set_ylabel(f"tip {'xyz'[j]} in base frame (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
axes[0].set_title("Top view (x-y)")
axes[1].set_title("Side view (x-z)")
fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=3)
fig.suptitle(f"Measured tip position, run {run_id}")
plt.show()

# %%
# Motor angles and torques
# ------------------------
#
# During the sweep the motors move along one direction of the ``(q1, q2)``
# plane at a time: out to the motor-input magnitude :math:`|q| = 60` degrees
# at constant speed, straight back without a pause, then a rest at neutral
# before the next ray. Rays along a motor axis move one motor; diagonal rays
# move both, each to about 42 degrees. The random walk then moves both motors
# with fast random steps inside ``|q| <= 60`` degrees. The drive torques
# follow the tendon loads: they grow with the bend, change abruptly where
# the motion reverses at the end of a ray (the friction in the sheath turns
# around) and carry a few N mm of noise.
fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True, layout="constrained")
for name, color in [("1", "tab:blue"), ("2", "tab:red")]:
    axes[0].plot(t, run_X[f"q{name}"], lw=0.6, color=color, label=f"$q_{name}$")
    axes[1].plot(t, run_X[f"tau{name}"], lw=0.4, color=color, label=rf"$\tau_{name}$")
for ax in axes:
    ax.axvspan(0, t_switch, color="0.92", zorder=0)
    ax.axvline(t_switch, color="k", ls="--", lw=1)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
axes[0].text(t_switch / 2, 66, "sweep", ha="center")
axes[0].text((t_switch + t[-1]) / 2, 66, "random walk", ha="center")
axes[0].set_ylim(-75, 78)
axes[0].set_ylabel("motor angle (deg)")
axes[1].set_ylabel("drive torque (N mm)")
axes[1].set_xlabel("time (s)")
fig.suptitle(f"Motor channels of run {run_id}")
plt.show()


# %%
# A hysteresis loop
# -----------------
#
# Along one sweep ray the motor-input magnitude :math:`\rho = |q|` goes from
# 0 to 60 degrees and back. We split each ray into its outward and its return
# branch, both ordered from neutral to the end of the ray, and measure the
# tip displacement from the tip position at neutral just before the ray.
# Three numbers describe the loop of a ray:
#
# * the **backlash** (deg): at equal tip displacement, how many motor degrees
#   the outward branch is behind the return branch, averaged at 30, 50 and
#   70 % of the ray's tip excursion;
# * the **gap** (mm): at equal motor angle, how much further the tip is on
#   the return branch, averaged at :math:`\rho` = 20, 30, 40 and 50 degrees;
# * the **torque gap** (N mm): at the same motor angles, how much higher the
#   drive torque along the ray is on the outward branch.
#
# The arrows in the figure mark the backlash at half the excursion and the
# gap at :math:`\rho` = 50 degrees.
FRACTIONS = (0.3, 0.5, 0.7)
RHO_LEVELS = (20.0, 30.0, 40.0, 50.0)


def sweep_rays(run_X, run_y):
    """Split the sweep of one run into its rays (outward and return branches)."""
    sweep = (run_X["phase"] == "sweep").to_numpy()
    q = run_X[["q1", "q2"]].to_numpy()[sweep]
    tau = run_X[["tau1", "tau2"]].to_numpy()[sweep]
    p = run_y[sweep]
    rho = np.hypot(q[:, 0], q[:, 1])
    edges = np.flatnonzero(np.diff(np.r_[0, (rho > 0).astype(int), 0]))
    rays = []
    for start, stop in zip(edges[::2], edges[1::2]):
        i = np.arange(start, stop)
        peak = i[np.argmax(rho[i])]
        out = np.r_[start - 1, i[i <= peak]]  # from neutral to the end of the ray
        ret = np.r_[stop, i[i >= peak][::-1]]  # the return, also from neutral to the end
        p0 = p[max(0, start - 20) : start].mean(axis=0)  # at neutral before the ray
        direction = q[peak] / rho[peak]
        rays.append(
            {
                "psi_deg": np.rad2deg(np.arctan2(direction[1], direction[0])) % 360,
                "rho_out": rho[out],
                "rho_ret": rho[ret],
                "disp_out": np.linalg.norm(p[out] - p0, axis=1),
                "disp_ret": np.linalg.norm(p[ret] - p0, axis=1),
                "tau_out": tau[out] @ direction,  # torque along the ray direction
                "tau_ret": tau[ret] @ direction,
            }
        )
    return rays


def near(rho, value, levels):
    """Mean of ``value`` over the samples within 1 degree of each of ``levels``."""
    return np.array([value[np.abs(rho - lv) < 1.0].mean() for lv in levels])


def rho_at(rho, disp, level):
    """Motor angle at which a branch first reaches a tip displacement (NaN if it starts beyond)."""
    j = np.argmax(disp >= level)
    return np.interp(level, disp[j - 1 : j + 1], rho[j - 1 : j + 1]) if j > 0 else np.nan


def loop_measures(ray):
    """Backlash (deg), gap (mm), torque gap (N mm) and tip excursion (mm) of one ray."""
    excursion = max(ray["disp_out"].max(), ray["disp_ret"].max())
    levels = [f * excursion for f in FRACTIONS]
    backlash = [rho_at(ray["rho_out"], ray["disp_out"], d) - rho_at(ray["rho_ret"], ray["disp_ret"], d) for d in levels]
    gap = near(ray["rho_ret"], ray["disp_ret"], RHO_LEVELS) - near(ray["rho_out"], ray["disp_out"], RHO_LEVELS)
    torque_gap = near(ray["rho_out"], ray["tau_out"], RHO_LEVELS) - near(ray["rho_ret"], ray["tau_ret"], RHO_LEVELS)
    return {
        "backlash_deg": np.nanmean(backlash),
        "gap_mm": gap.mean(),
        "torque_gap_Nmm": torque_gap.mean(),
        "excursion_mm": excursion,
    }


BINS = np.arange(0.0, 61.0, 2.0)
centres = 0.5 * (BINS[:-1] + BINS[1:])


def binned(rho, value):
    """Mean of ``value`` in 2-degree bins of ``rho``, to draw a branch without the sensor noise."""
    k = np.digitize(rho, BINS) - 1
    sums = np.bincount(k, weights=value, minlength=len(BINS))[: len(BINS) - 1]
    counts = np.bincount(k, minlength=len(BINS))[: len(BINS) - 1]
    with np.errstate(invalid="ignore"):
        return sums / counts


ray = sweep_rays(run_X, run_y)[0]
measures = loop_measures(ray)
print(
    f"ray at {ray['psi_deg']:.0f} deg of run {run_id}: backlash {measures['backlash_deg']:.1f} deg, "
    f"gap {measures['gap_mm']:.1f} mm, torque gap {measures['torque_gap_Nmm']:.1f} N mm, "
    f"tip excursion {measures['excursion_mm']:.1f} mm"
)

fig, axes = plt.subplots(1, 2, figsize=(10, 4.5), layout="constrained")
for ax, key, ylabel in [
    (axes[0], "disp", "tip displacement from neutral (mm)"),
    (axes[1], "tau", "drive torque along the ray (N mm)"),
]:
    for branch, color, label in [("out", "tab:blue", "outward"), ("ret", "tab:red", "return")]:
        rho, value = ray[f"rho_{branch}"], ray[f"{key}_{branch}"]
        ax.plot(rho, value, ".", ms=2, color=color, alpha=0.3)
        ax.plot(centres, binned(rho, value), "-", color=color, lw=2, label=label)
    ax.set_xlabel(r"motor-input magnitude $\rho = |q|$ (deg)")
    ax.set_ylabel(ylabel)
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)

# the backlash at half the excursion, and the gap at rho = 50 deg
half = 0.5 * measures["excursion_mm"]
rho_ret, rho_out = (rho_at(ray[f"rho_{b}"], ray[f"disp_{b}"], half) for b in ("ret", "out"))
axes[0].annotate("", (rho_out, half), (rho_ret, half), arrowprops={"arrowstyle": "<->", "lw": 1.5})
axes[0].text(0.5 * (rho_ret + rho_out), half - 0.6, "backlash", ha="center", va="top")
low, high = (near(ray[f"rho_{b}"], ray[f"disp_{b}"], [50.0])[0] for b in ("out", "ret"))
axes[0].annotate("", (50.0, high), (50.0, low), arrowprops={"arrowstyle": "<->", "lw": 1.5})
axes[0].text(50.8, 0.5 * (low + high), "gap", va="center")
axes[0].set_title(f"Tip: backlash {measures['backlash_deg']:.1f} deg, gap {measures['gap_mm']:.1f} mm")
axes[1].set_title(f"Drive torque: torque gap {measures['torque_gap_Nmm']:.1f} N mm")
fig.suptitle(f"Outward and return branches of the sweep ray at {ray['psi_deg']:.0f} deg, run {run_id}")
plt.show()

# %%
# On the way out the tip lags the motor: the slack of the tendon pair and the
# friction along the sheath must be taken up before the section bends. On
# the way back the tip stays bent, so the return branch lies above the
# outward one, and back at neutral it has not quite returned to where it
# started: the friction elements that need the longest travel to slip still
# hold part of the excursion. The torque shows the reversal much more
# sharply: while the tendon is pulled through the bent shaft, sheath friction
# adds to its tension; once it is released, friction holds part of the
# tension back, so the torque drops steeply at the start of the return,
# before the tip has moved.
#
# Loops and shaft bend
# --------------------
#
# We measure every ray of every run and average the 8 rays of each run.
rows = []
for run_id_k, level in zip(data.runs["run"], data.runs["bend_level"]):
    mask = (X["run"] == run_id_k).to_numpy()
    for ray_k in sweep_rays(X[mask], y[mask]):
        diagonal = round(ray_k["psi_deg"]) % 90 != 0
        rows.append({"run": run_id_k, "bend_level": level, "diagonal": diagonal, **loop_measures(ray_k)})
rays = pd.DataFrame(rows)
per_run = rays.groupby(["bend_level", "run"]).mean(numeric_only=True).drop(columns="diagonal")

levels = ["straight", "low", "high"]
summary = per_run.groupby("bend_level").mean().loc[levels]
summary["backlash_axis_deg"] = rays[~rays["diagonal"]].groupby("bend_level")["backlash_deg"].mean()
summary["backlash_diagonal_deg"] = rays[rays["diagonal"]].groupby("bend_level")["backlash_deg"].mean()
summary.insert(0, "n_runs", per_run.groupby("bend_level").size())
print(summary.round(1).to_string())

wraps = data.runs.groupby("bend_level")["shaft_wrap_deg"].first()
panels = [
    ("backlash_deg", "backlash (deg)", "Backlash, motor degrees"),
    ("gap_mm", "gap at equal motor angle (mm)", "Gap, tip millimetres"),
    ("torque_gap_Nmm", "torque gap (N mm)", "Torque gap"),
]
fig, axes = plt.subplots(1, 3, figsize=(11, 4.3), layout="constrained")
rng = np.random.default_rng(0)
for ax, (key, ylabel, title) in zip(axes, panels):
    for i, level in enumerate(levels):
        single = rays.loc[rays["bend_level"] == level, key].to_numpy()
        means = per_run.loc[level, key].to_numpy()
        ax.plot(i + rng.uniform(-0.25, 0.25, single.size), single, ".", color="0.65", ms=3,
                label="single ray" if i == 0 else None)
        ax.plot(i + rng.uniform(-0.1, 0.1, means.size), means, "o", color="tab:purple", ms=5,
                label="run (mean of 8 rays)" if i == 0 else None)
        ax.hlines(means.mean(), i - 0.3, i + 0.3, color="k", lw=2, label="level mean" if i == 0 else None)
    ax.set_xticks(range(3), [f"{lv}\n{wraps[lv]:.0f} deg" for lv in levels])
    ax.set_xlim(-0.5, 2.5)
    ax.set_xlabel("bend level and wrap of the shaft")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=3)
fig.suptitle("Hysteresis of the sweep rays by shaft bend level")
plt.show()

# %%
# The friction in the sheath grows with the capstan wrap of the tendons, so
# the loop widens **in motor degrees** from the straight shaft to the high
# bend, by about 4.5 degrees per level on average: the no-load play of each
# tendon pair scales with the pair's own wrap (from simulator version 5). The
# torque gap depends strongly on the unit (the two clusters of runs are the
# two catheters) and changes little with the level: a wide no-load play
# leaves part of the friction elements between their branches, so the
# friction utilisation swings less on a ray. The gap **in millimetres**
# does not grow either: the same friction also compresses the transmission
# of a bent shaft (the friction elements lag further behind the motor, and
# the tendons lose part of their pull), so each motor degree moves the tip
# less, as the shrinking tip excursion of a ray shows (``excursion_mm``), and
# the wider backlash gives no wider gap at the tip. To see hysteresis grow
# with the shaft bend, measure it in motor degrees.
#
# Within a level, part of the spread of the single rays comes from their
# direction: a diagonal ray moves both motors, so both tendon pairs must
# cross their friction, and the load of each pair widens the friction of the
# other. In motor degrees its backlash is wider than that of a ray along one
# motor axis (``backlash_diagonal_deg`` against ``backlash_axis_deg`` in the
# table). A model that calibrates on the sweep must therefore capture a
# hysteresis that depends on the shaft setting and on the direction of
# motion, not a single fixed loop.
