"""How well the data tell the quaternion order: fit_quat_order on the default benchmark.

The raw EM sensor poses of ``make_benchmark()`` (4 catheters x 17 shaft
settings x 3 runs; base quaternions stored scalar first) are handed to
:func:`skcath.frames.fit_quat_order` with the base quaternion columns in each
layout (``stored``: the four columns as w, x, y, z, or the same numbers
rewritten as x, y, z, w), and read as each declared order. ``read_recordings``
raises when the order that fits is not the declared one; a declared order is
right when it equals the stored layout.

Tables printed:

1. **all runs**, per catheter: the spread of the neutral tip direction (RMS
   angle, degrees) read in the declared order and in the other, their ratio
   (declared / other: above ``MIN_SPREAD_RATIO`` the declared order is
   flagged, below its inverse the declared order is confirmed, between the
   two the data cannot tell), and whether the check flags it.
2. **fewer runs**: ``--draws`` random subsets of ``k`` shaft settings per
   catheter, with one run per setting or all three; for each ``k``, the share
   of draws in which a wrong declared order is caught, the right one flagged
   (a false alarm), or the data cannot tell, and the smallest ratio of a wrong
   order.
3. **one run**: the neutral visits of one run's sweep (the sweep returns to
   neutral between its rays) taken as separate groups, as a single file
   without other runs would offer them.
4. with ``--tee DIR``: the six recordings of a real TEE probe (one motor moves
   per file; base sensor nearly static; quaternion columns x, y, z, w), read
   as ``tests/test_io.py`` reads them, as one catheter.

Usage::

    .venv/bin/python benchmarks/bench_quat_order.py [--draws 50] [--settings 1 2 3 5 17] [--tee DIR]
"""

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from _machine import machine_lines
from skcath.datasets import make_benchmark
from skcath.frames import MIN_SPREAD_RATIO, QUAT_ORDERS, fit_quat_order, neutral_rows
from skcath.io import read_recording

TIP = ["tip_px", "tip_py", "tip_pz"]
BASE = ["base_px", "base_py", "base_pz"]
QUAT_WXYZ = ["base_qw", "base_qx", "base_qy", "base_qz"]


def neutral_data():
    """The neutral rows of the default benchmark and their raw poses, both quaternion layouts."""
    data = make_benchmark()
    rows = neutral_rows(data.X)
    X = data.X.loc[rows].reset_index(drop=True)
    sensors = data.sensors.loc[rows].reset_index(drop=True)
    quats = {order: sensors[[f"base_q{c}" for c in order]].to_numpy() for order in QUAT_ORDERS}
    return X, sensors[TIP].to_numpy(), sensors[BASE].to_numpy(), quats


def verdicts(X, tip, base, quats, keep=None):
    """One row per (stored layout, declared order): spreads, ratio, flagged."""
    keep = np.ones(len(X), dtype=bool) if keep is None else keep
    rows = []
    for stored in QUAT_ORDERS:
        fit = fit_quat_order(X[keep], tip[keep], base[keep], quats[stored][keep])
        for declared in QUAT_ORDERS:
            other = next(o for o in QUAT_ORDERS if o != declared)
            rows.append({
                "stored": stored, "declared": declared, "right": stored == declared,
                "runs": fit.n_runs, "spread declared": fit.spread[declared],
                "spread other": fit.spread[other],
                "ratio": fit.spread[declared] / fit.spread[other],
                "fits": fit.fitting or "cannot tell",
                "flagged": fit.fitting not in (None, declared),
            })
    return rows


def table_all_runs(X, tip, base, quats):
    """Table 1: every catheter with all its runs."""
    rows = []
    for catheter in pd.unique(X["catheter"]):
        for row in verdicts(X, tip, base, quats, (X["catheter"] == catheter).to_numpy()):
            rows.append({"catheter": catheter, **row})
    return pd.DataFrame(rows)


def table_fewer_runs(X, tip, base, quats, settings, draws, seed):
    """Table 2: random subsets of k settings per catheter, one run each or all runs."""
    rng = np.random.default_rng(seed)
    rows = []
    for per_setting in ("1", "all"):
        for k in settings:
            found = []
            for catheter in pd.unique(X["catheter"]):
                mine = X["catheter"] == catheter
                names = pd.unique(X.loc[mine, "setting"])
                for _ in range(draws if k < len(names) else 1):
                    chosen = rng.choice(names, size=k, replace=False)
                    keep = mine & X["setting"].isin(chosen)
                    if per_setting == "1":
                        first = X.loc[keep].groupby("setting")["run"].transform("first")
                        keep &= X["run"] == first.reindex(X.index)
                    found += verdicts(X, tip, base, quats, keep.to_numpy())
            frame = pd.DataFrame(found)
            wrong, right = frame[~frame["right"]], frame[frame["right"]]
            rows.append({
                "runs per setting": per_setting, "settings": k, "checks": len(wrong),
                "wrong caught": wrong["flagged"].mean(), "right flagged": right["flagged"].mean(),
                "cannot tell": (frame["fits"] == "cannot tell").mean(),
                "min ratio wrong": wrong["ratio"].min(), "max ratio right": right["ratio"].max(),
            })
    return pd.DataFrame(rows)


def table_one_run(X, tip, base, quats):
    """Table 3: the neutral visits of each single run as groups."""
    t = X["t"].to_numpy()
    runs = X["run"].to_numpy()
    new_visit = np.r_[True, (runs[1:] != runs[:-1]) | (np.diff(t) > 0.15)]
    visit = np.cumsum(new_visit)
    rows = []
    for run in pd.unique(runs):
        keep = runs == run
        X_visits = X.loc[keep].assign(run=[f"{run}/{v}" for v in visit[keep]])
        kept = {order: q[keep] for order, q in quats.items()}
        for row in verdicts(X_visits, tip[keep], base[keep], kept):
            rows.append({"run": run, **row})
    frame = pd.DataFrame(rows)
    return frame.groupby("right").agg(
        checks=("flagged", "size"), flagged=("flagged", "mean"),
        cannot_tell=("fits", lambda f: (f == "cannot tell").mean()),
        median_ratio=("ratio", "median"), min_ratio=("ratio", "min"), max_ratio=("ratio", "max"),
        median_visits=("runs", "median"),
    )


def table_tee(folder):
    """Table 4: the six TEE-probe recordings as one catheter's runs."""
    parts = []
    for motor in (1, 2):
        for acq in (1, 2, 3):
            path = Path(folder) / f"motor{motor}_current60_acq{acq}.csv"
            raw = pd.read_csv(path)
            groups = {s: [f"{s}_position_{a}" for a in "xyz"] for s in ("tip", "base")}
            X, _ = read_recording(
                path, quat_order="xyzw", catheter="tee-probe", setting="current60", rate_hz=10.0,
                phase="sweep", constants={f"q{3 - motor}": 0.0, f"tau{3 - motor}": 0.0},
                columns={f"q{motor}": "motor_position", f"tau{motor}": "current",
                         "tip_position": groups["tip"], "base_position": groups["base"],
                         "base_orientation": [f"base_orientation_{c}" for c in "xyzw"]},
            )
            parts.append((X, raw[groups["tip"]].to_numpy(), raw[groups["base"]].to_numpy(),
                          raw[[f"base_orientation_{c}" for c in "xyzw"]].to_numpy()))
    X = pd.concat([p[0] for p in parts], ignore_index=True)
    tip, base = (np.concatenate([p[i] for p in parts]) for i in (1, 2))
    stored = np.concatenate([p[3] for p in parts])
    quats = {"xyzw": stored, "wxyz": stored[:, [3, 0, 1, 2]]}
    return pd.DataFrame(verdicts(X, tip, base, quats))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=50, help="random subsets per catheter and k")
    parser.add_argument("--settings", type=int, nargs="+", default=[1, 2, 3, 5, 17])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tee", help="folder of the TEE recordings (motor*_current60_acq*.csv)")
    args = parser.parse_args()
    for line in machine_lines():
        print(line)
    print(f"MIN_SPREAD_RATIO = {MIN_SPREAD_RATIO:g}")
    X, tip, base, quats = neutral_data()
    print(f"neutral rows: {len(X)} of {X['run'].nunique()} runs")
    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 20)
    print("\n1. all runs of each catheter (spreads in degrees)")
    print(table_all_runs(X, tip, base, quats).round(3).to_string(index=False))
    print(f"\n2. fewer runs: {args.draws} random subsets of k settings per catheter")
    print(table_fewer_runs(X, tip, base, quats, args.settings, args.draws, args.seed)
          .round(3).to_string(index=False))
    print("\n3. one run: the neutral visits of its sweep as groups")
    print(table_one_run(X, tip, base, quats).round(3).to_string())
    if args.tee:
        print("\n4. TEE probe: six recordings of one probe, base sensor nearly static")
        print(table_tee(args.tee).round(3).to_string(index=False))


if __name__ == "__main__":
    main()
