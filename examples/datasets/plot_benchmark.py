"""
================================
The simulated catheter benchmark
================================

:func:`~skcath.datasets.make_benchmark` generates recordings of a family of
tendon-driven catheters with the bench protocol: every run starts with an
8-ray outward-and-return sweep of the two bending motors, then continues with
a 100-step random walk. This example loads a small benchmark (one catheter,
each of the 17 shaft settings recorded once), follows one run with a bent
shaft from the motor angles to the tip position, and shows the hysteresis
of the tendon transmission and how it grows with the shaft bend. The physics
behind the data is described on the :doc:`simulator page </simulator>`.
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

from skcath.datasets import make_benchmark

data = make_benchmark(n_catheters=1, n_runs=1)
X, y = data.X, data.y
print(data.DESCR)

# %%
# Each run belongs to one shaft setting: straight (``S00``), or held bent in
# one of 8 directions at a low (``S01``-``S08``) or high (``S09``-``S16``)
# level. The more the shaft is bent, the larger the capstan wrap of the
# tendons through it.
data.runs[["run", "bend_level", "bend_direction_deg", "shaft_wrap_deg", "n_samples", "n_sweep"]]

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
# During the sweep the two motors move together along one direction of the
# ``(q1, q2)`` plane at a time, out to 60 degrees and back with pauses at
# both ends. The random walk then moves both motors with random steps inside
# ``|q| <= 60`` degrees. The drive torques follow the tendon loads: they
# grow with the bend, jump when the direction of motion reverses (friction)
# and carry a few N mm of noise.
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
# 0 to 60 degrees and back. We split each ray into its outward and return
# branches and measure the tip displacement from the tip position at neutral
# just before the ray. The helper below also averages each branch in bins
# of 2 degrees of :math:`\rho`, which removes most of the sensor noise.
def sweep_rays(run_X, run_y):
    """Split the sweep of one run into its rays (outward and return branches)."""
    sweep = (run_X["phase"] == "sweep").to_numpy()
    q = run_X[["q1", "q2"]].to_numpy()[sweep]
    tau = run_X[["tau1", "tau2"]].to_numpy()[sweep]
    p = run_y[sweep]
    rho = np.hypot(q[:, 0], q[:, 1])
    away = np.flatnonzero(rho > 0)
    rays = []
    for idx in np.split(away, np.flatnonzero(np.diff(away) > 1) + 1):
        at_end = idx[rho[idx] >= rho[idx].max() - 1e-9]
        out = idx[idx <= at_end[0]]
        ret = idx[idx >= at_end[-1]]
        psi = np.arctan2(q[at_end[0], 1], q[at_end[0], 0])
        p0 = p[max(0, idx[0] - 20) : idx[0]].mean(axis=0)  # at neutral before the ray
        direction = np.array([np.cos(psi), np.sin(psi)])
        rays.append(
            {
                "psi_deg": np.rad2deg(psi) % 360,
                "rho_out": rho[out],
                "rho_ret": rho[ret],
                "disp_out": np.linalg.norm(p[out] - p0, axis=1),
                "disp_ret": np.linalg.norm(p[ret] - p0, axis=1),
                # torque along the ray direction
                "tau_out": tau[out] @ direction,
                "tau_ret": tau[ret] @ direction,
            }
        )
    return rays


BINS = np.arange(0.0, 61.0, 2.0)


def binned(rho, value):
    """Mean of ``value`` in 2-degree bins of ``rho`` (NaN where a bin is empty)."""
    k = np.digitize(rho, BINS) - 1
    sums = np.bincount(k, weights=value, minlength=len(BINS))[: len(BINS) - 1]
    counts = np.bincount(k, minlength=len(BINS))[: len(BINS) - 1]
    with np.errstate(invalid="ignore"):
        return sums / counts


def loop_width(ray):
    """Largest gap (mm) between the binned return and outward branches."""
    gap = binned(ray["rho_ret"], ray["disp_ret"]) - binned(ray["rho_out"], ray["disp_out"])
    return np.nanmax(gap)


centres = 0.5 * (BINS[:-1] + BINS[1:])
ray = sweep_rays(run_X, run_y)[0]

fig, axes = plt.subplots(1, 2, figsize=(10, 4.3), layout="constrained")
ax = axes[0]
ax.plot(ray["rho_out"], ray["disp_out"], ".", ms=2, color="tab:blue", alpha=0.3)
ax.plot(ray["rho_ret"], ray["disp_ret"], ".", ms=2, color="tab:red", alpha=0.3)
ax.plot(centres, binned(ray["rho_out"], ray["disp_out"]), "-", color="tab:blue", lw=2, label="outward")
ax.plot(centres, binned(ray["rho_ret"], ray["disp_ret"]), "-", color="tab:red", lw=2, label="return")
ax.set_xlabel(r"motor-input magnitude $\rho = |q|$ (deg)")
ax.set_ylabel("tip displacement from neutral (mm)")
ax.set_title(f"Tip, ray at {ray['psi_deg']:.0f} deg (loop width {loop_width(ray):.1f} mm)")
ax.legend(loc="upper left")

ax = axes[1]
ax.plot(ray["rho_out"], ray["tau_out"], ".", ms=2, color="tab:blue", alpha=0.3)
ax.plot(ray["rho_ret"], ray["tau_ret"], ".", ms=2, color="tab:red", alpha=0.3)
ax.plot(centres, binned(ray["rho_out"], ray["tau_out"]), "-", color="tab:blue", lw=2, label="outward")
ax.plot(centres, binned(ray["rho_ret"], ray["tau_ret"]), "-", color="tab:red", lw=2, label="return")
ax.set_xlabel(r"motor-input magnitude $\rho = |q|$ (deg)")
ax.set_ylabel("drive torque along the ray (N mm)")
ax.set_title("Drive torque, same ray")
ax.legend(loc="upper left")
for ax in axes:
    ax.grid(alpha=0.3)
fig.suptitle(f"Outward and return branches of one sweep ray, run {run_id}")
plt.show()

# %%
# On the way out the tip lags the motor (play and dead zone of the tendon
# pair); on the way back it stays bent until the play has been crossed in
# the other direction, so the return branch lies above the outward one and
# the tip barely moves over the first degrees of the return. The torque
# shows the same reversal much more strongly: while the tendon is pulled
# through the bent shaft, sheath friction adds to its tension; once it is
# released, friction holds part of the tension back, so the torque drops
# steeply at the start of the return, before the tip has moved.
#
# Loop width and shaft bend
# -------------------------
#
# The play of the transmission grows with the capstan wrap of the tendons in
# the shaft, so loops widen from the straight shaft to the high bend. We
# compute the loop width of every ray of every run and average the 8 rays of
# each run.
rows = []
for run_id_k, level in zip(data.runs["run"], data.runs["bend_level"]):
    mask = (X["run"] == run_id_k).to_numpy()
    rays = sweep_rays(X[mask], y[mask])
    widths = [loop_width(r) for r in rays]
    diagonal = [round(r["psi_deg"]) % 90 != 0 for r in rays]
    rows.append((level, np.mean(widths), widths, diagonal))

levels = ["straight", "low", "high"]
fig, ax = plt.subplots(figsize=(6.5, 4.3), layout="constrained")
rng = np.random.default_rng(0)
for i, level in enumerate(levels):
    per_run = np.array([m for lv, m, *_ in rows if lv == level])
    per_ray = np.concatenate([w for lv, _, w, _ in rows if lv == level])
    on_diagonal = np.concatenate([d for lv, *_, d in rows if lv == level])
    jitter = rng.uniform(-0.25, 0.25, per_ray.size)
    ax.plot(i + jitter, per_ray, ".", color="0.6", ms=4, label="single ray" if i == 0 else None)
    jitter = rng.uniform(-0.1, 0.1, per_run.size)
    ax.plot(i + jitter, per_run, "o", color="tab:purple", ms=7, label="run (mean of 8 rays)" if i == 0 else None)
    ax.hlines(per_run.mean(), i - 0.3, i + 0.3, color="k", lw=2, label="level mean" if i == 0 else None)
    print(
        f"{level:>8}: {per_run.size} run(s), loop width {per_run.mean():.2f} mm; rays along a "
        f"motor axis {per_ray[~on_diagonal].mean():.2f} mm, diagonal rays {per_ray[on_diagonal].mean():.2f} mm"
    )
wraps = data.runs.groupby("bend_level")["shaft_wrap_deg"].first()
ax.set_xticks(range(3), [f"{lv}\n(wrap {wraps[lv]:.0f} deg)" for lv in levels])
ax.set_xlabel("shaft bend level")
ax.set_ylabel("loop width of the tip (mm)")
ax.set_title("Hysteresis loop width by shaft bend")
ax.grid(axis="y", alpha=0.3)
ax.legend(loc="upper left", fontsize="small")
plt.show()

# %%
# Rays that run diagonally in the ``(q1, q2)`` plane load both tendon pairs,
# each with its own play, so their loops are wider than those of rays along
# one motor axis: this is the spread of the single rays within a level.
# A model that calibrates on the sweep must therefore capture a hysteresis
# that depends on the shaft setting and on the direction of motion, not a
# single fixed loop.
