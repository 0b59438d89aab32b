"""Detection delay and false alarms of the shaft-change detector.

On the simulated benchmark (``--n-catheters`` catheters x 17 shaft settings x
``--n-runs`` runs), this script

1. loads the default benchmark, whose shaft stays in its setting for the
   whole run (``make_benchmark()``, from the cache when it is there), and
   generates the same runs with the shaft repositioned 30-90 s into the
   motion (``make_benchmark(shaft_change=True, cache=False)``: same motor
   trajectories and noise, another setting from the change on);
2. starts a :class:`ShaftChangeDetector` on every run's own sweep and runs it
   over the motion (``detect``), for every threshold of ``--thresholds``;
3. counts, per catheter group, the false alarms per hour of motion with an
   unchanged shaft (unchanged runs, and changed runs before their change; the
   statistic restarts after each alarm), and on changed runs the detection
   rate (an alarm after the change, before the run ends: 74 s or more) and
   the delay from the change to the first alarm after it (s);
4. picks the default threshold on catheter ``C1`` only (the smallest
   threshold of the grid without a false alarm on C1) and reports catheters
   ``C2``-``C4`` as held out, with a breakdown by catheter and, for the
   held-out catheters, by kind of change.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_shaft_change.py
    .venv/bin/python benchmarks/bench_shaft_change.py --model static --drift 1.0

The tables are printed in Markdown.
"""

import argparse
import time

import numpy as np
import pandas as pd
from _machine import machine_lines

from skcath.datasets import make_benchmark, shaft_settings
from skcath.online import ShaftChangeDetector

DEFAULT_THRESHOLDS = (20, 30, 45, 60, 75, 90, 110, 130, 160, 200, 250)


def _runs(data):
    """Per run: id, catheter, motion arrays, motion times, and the sweep frame."""
    X = data.X
    for run, rows in X.groupby("run", observed=True, sort=False):
        sweep = (rows["phase"] == "sweep").to_numpy()
        motion = rows[~sweep]
        yield (
            str(run),
            str(rows["catheter"].iloc[0]),
            rows[sweep],
            motion[["q1", "q2"]].to_numpy(),
            motion[["tau1", "tau2"]].to_numpy(),
            motion["t"].to_numpy(),
        )


def _evaluate(data, thresholds, params, changed, scales):
    """One row per (run, threshold): alarms before / after the change, delay.

    For unchanged runs, appends to ``scales`` the catheter, the sweep residual
    standard deviations ``scale_`` (N mm) and the standard deviations of the
    normalised motion residuals.
    """
    info = data.runs.set_index("run")
    rows = []
    for run, catheter, sweep, q, tau, t in _runs(data):
        detector = ShaftChangeDetector(**params).start(sweep)
        t_change = info.loc[run, "change_time_s"] if changed else np.inf
        if not changed:  # how the motion residuals compare with the sweep's
            z = detector.detect(q, tau).residual
            scales.append((catheter, *detector.scale_, *z.std(axis=0)))
        for h in thresholds:
            alarms = detector.set_params(threshold=h).detect(q, tau).alarms
            t_alarm = t[alarms]
            before = t_alarm < t_change
            after = t_alarm[~before]
            rows.append(
                {
                    "run": run,
                    "catheter": catheter,
                    "threshold": h,
                    "hours_unchanged": (min(t_change, t[-1] + 0.1) - t[0]) / 3600.0,
                    "false_alarms": int(before.sum()),
                    "detected": bool(len(after)) if changed else np.nan,
                    "delay_s": (after[0] - t_change) if len(after) else np.nan,
                }
            )
    return pd.DataFrame(rows)


def _change_kind(runs):
    """Kind of each run's shaft change: a new bend level, or a new direction (deg apart)."""
    table = {s.name: s for s in shaft_settings()}
    kinds = []
    for before, after in zip(runs["setting"], runs["setting_after"]):
        a, b = table[before], table[after]
        if a.level != b.level:
            kinds.append(f"level {a.level} -> {b.level}")
        else:
            angle = abs((b.direction_deg - a.direction_deg + 180.0) % 360.0 - 180.0)
            kinds.append(f"same level, direction {angle:.0f} deg apart")
    return pd.Series(kinds, index=runs["run"])


def _summary(same, changed):
    """ROC-style table: one row per threshold."""
    fa = pd.concat([same, changed])
    out = []
    for h, group in fa.groupby("threshold"):
        hours = group["hours_unchanged"].sum()
        det = changed[changed["threshold"] == h]
        delays = det["delay_s"].dropna()
        out.append(
            {
                "threshold": h,
                "detection rate": det["detected"].mean(),
                "median delay s": delays.median(),
                "p90 delay s": delays.quantile(0.9),
                "false alarms / h": group["false_alarms"].sum() / hours,
                "unchanged runs with an alarm": (same[same["threshold"] == h]["false_alarms"] > 0).mean(),
            }
        )
    return pd.DataFrame(out)


def _markdown(df, floatfmt=".2f"):
    return df.to_markdown(index=False, floatfmt=floatfmt)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-catheters", type=int, default=4)
    parser.add_argument("--n-runs", type=int, default=3)
    parser.add_argument("--thresholds", type=float, nargs="+", default=DEFAULT_THRESHOLDS)
    parser.add_argument("--drift", type=float, default=1.5)
    parser.add_argument("--model", choices=("hysteresis", "static"), default="hysteresis")
    parser.add_argument("--tuning-catheter", default="C1")
    args = parser.parse_args()

    for line in machine_lines():
        print(line)
    start = time.perf_counter()
    same_data = make_benchmark(n_catheters=args.n_catheters, n_runs=args.n_runs)
    changed_data = make_benchmark(
        n_catheters=args.n_catheters, n_runs=args.n_runs, shaft_change=True, cache=False
    )
    t_data = time.perf_counter() - start
    params = {"drift": args.drift, "model": args.model}
    start = time.perf_counter()
    scales = []
    same = _evaluate(same_data, args.thresholds, params, changed=False, scales=scales)
    changed = _evaluate(changed_data, args.thresholds, params, changed=True, scales=scales)
    t_detect = time.perf_counter() - start
    n_samples = sum(int((d.X["phase"] == "motion").sum()) for d in (same_data, changed_data))
    print(
        f"\ndata: {t_data:.1f} s; detection: {t_detect:.1f} s for {len(args.thresholds)} thresholds "
        f"x {same['run'].nunique() + changed['run'].nunique()} runs "
        f"({n_samples:,} motion samples per threshold)"
    )
    print(f"detector: drift={args.drift}, model={args.model!r}; other parameters at their defaults\n")
    scales = pd.DataFrame(scales, columns=["catheter", "s1", "s2", "z1", "z2"])
    sweep_sd = scales[["s1", "s2"]].to_numpy().ravel()
    motion_sd = scales[["z1", "z2"]].to_numpy().ravel()
    print(
        f"unchanged runs: sweep residual sd s_i (N mm) median {np.median(sweep_sd):.2f} "
        f"[{sweep_sd.min():.2f}, {sweep_sd.max():.2f}]; sd of the normalised motion residual z_i "
        f"median {np.median(motion_sd):.2f} [{motion_sd.min():.2f}, {motion_sd.max():.2f}]; by catheter: "
        + ", ".join(
            f"{c} {np.median(g[['z1', 'z2']].to_numpy()):.2f}" for c, g in scales.groupby("catheter")
        )
        + "\n"
    )

    tune = args.tuning_catheter
    for label, mask_same, mask_changed in (
        (f"{tune} (threshold chosen here)", same["catheter"] == tune, changed["catheter"] == tune),
        (f"held out: all catheters but {tune}", same["catheter"] != tune, changed["catheter"] != tune),
    ):
        s, c = same[mask_same], changed[mask_changed]
        hours = s[s["threshold"] == args.thresholds[0]]["hours_unchanged"].sum()
        hours += c[c["threshold"] == args.thresholds[0]]["hours_unchanged"].sum()
        print(
            f"### {label}: {c['run'].nunique()} changed runs, {s['run'].nunique()} unchanged runs, "
            f"{hours:.1f} h of motion with an unchanged shaft\n"
        )
        print(_markdown(_summary(s, c)))
        print()

    tuning = _summary(same[same["catheter"] == tune], changed[changed["catheter"] == tune])
    clean = tuning[tuning["false alarms / h"] == 0]
    chosen = clean["threshold"].min() if len(clean) else tuning["threshold"].max()
    print(f"chosen threshold (smallest without a false alarm on {tune}): {chosen:g}\n")

    per_catheter = []
    for catheter in sorted(same["catheter"].unique()):
        s, c = same[same["catheter"] == catheter], changed[changed["catheter"] == catheter]
        row = _summary(s, c)
        row = row[row["threshold"] == chosen].drop(columns="threshold")
        per_catheter.append(row.assign(catheter=catheter + (" (tuning)" if catheter == tune else "")))
    per_catheter = pd.concat(per_catheter)
    print(f"### threshold {chosen:g}, by catheter\n")
    print(_markdown(per_catheter[["catheter", *per_catheter.columns[:-1]]]))
    print()

    kinds = _change_kind(changed_data.runs)
    held = changed[(changed["catheter"] != tune) & (changed["threshold"] == chosen)].copy()
    held["kind"] = kinds.loc[held["run"]].to_numpy()
    by_kind = (
        held.groupby("kind")
        .agg(runs=("run", "size"), detection_rate=("detected", "mean"), median_delay_s=("delay_s", "median"))
        .reset_index()
    )
    print(f"### held out, threshold {chosen:g}, by kind of change\n")
    print(_markdown(by_kind))


if __name__ == "__main__":
    main()
