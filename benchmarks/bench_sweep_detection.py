"""The sweep found from the motor angles against the true one, and PDL+GRU on both.

Every run of the simulated benchmark is written to its own CSV file the way a
rig without phase marks exports it (``t``, ``q1``, ``q2``, ``tau1``, ``tau2``
and the tracked tip ``p_x, p_y, p_z``; no ``phase`` and no reference
columns), then read back with :func:`skcath.io.read_recordings` twice, from a
manifest: once with the true ``n_sweep`` of every run and once with
``n_sweep="auto"`` (:func:`skcath.sweep.find_sweep_end`). The table gives,
per catheter, the runs and the largest difference between the detected and
the true sweep length (samples and seconds), for

- the default benchmark, ``make_benchmark()`` (204 runs);
- the runs with a shaft change and a re-sweep,
  ``make_benchmark(shaft_change=True, resweep=True)``: the part before the
  change (``"<run>"``, 204 runs) and the part after it (``"<run>/after"``,
  204 runs), which starts with the re-sweep.

Unless every detected end equals the true one (the recordings read are then
identical), the evaluation protocol's PDL and PDL+GRU (quick schedule,
settings held out within each catheter, ``S00`` never evaluated) runs on the
default benchmark read both ways, and the second table compares their mean
per-run RMSE per catheter (``--no-protocol`` skips it).

``--instruments`` prints only the detection on the simulated instruments of
one and three motors and on the two-motor runs at 40 Hz (one run per
setting of each catheter, ``make_benchmark(n_runs=1, n_motors=...)`` and
``make_benchmark(n_runs=1, rate_hz=40.0)``). ``--noise`` prints only the
detection on the two-motor runs of ``make_benchmark(n_runs=1)`` with white
noise of standard deviation 0.01, 0.05 and 0.2 degrees added to the motor
angles (seed 0).

Usage (from the repository root)::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sweep_detection.py
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sweep_detection.py --no-protocol
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sweep_detection.py --instruments
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sweep_detection.py --noise

The benchmark comes from the cache (``$SKCATH_DATA``, else ``~/skcath_data``;
generated on the first call). The tables are printed in Markdown.
"""

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from skcath.datasets import make_benchmark
from skcath.io import read_recordings
from skcath.protocol import QUICK, compute_tables, run_protocol
from skcath.sweep import find_sweep_end

_TARGET = ("p_x", "p_y", "p_z")


def _write_files(data, folder):
    """One CSV file per run without phase or reference columns; the manifest rows."""
    X = data.X
    channels = [c for c in X.columns if c[0] in "qt" and c != "phase"]
    rows = []
    for k, (run, idx) in enumerate(X.groupby("run", observed=True, sort=False).indices.items()):
        part = X.iloc[idx]
        table = part[channels].copy()
        table[list(_TARGET)] = data.y[idx]
        path = Path(folder) / f"run{k:04d}.csv"
        table.to_csv(path, index=False)
        rows.append({"path": str(path), "catheter": str(part["catheter"].iloc[0]),
                     "setting": str(part["setting"].iloc[0]), "run": str(run),
                     "n_sweep": int((part["phase"] == "sweep").sum())})
    return pd.DataFrame(rows)


def _read_both(data):
    """The recordings read with the true n_sweep and with n_sweep="auto", and the manifest."""
    with tempfile.TemporaryDirectory() as folder:
        manifest = _write_files(data, folder)
        true = read_recordings(manifest=manifest, progress=False)
        auto = read_recordings(manifest=manifest.assign(n_sweep="auto"), progress=False)
    return true, auto, manifest


def _sweep_lengths(X):
    """Sweep samples and the time of the last sweep sample of every run."""
    sweep = X[X["phase"] == "sweep"].groupby("run", observed=True, sort=False)
    return sweep.size(), sweep["t"].max()


def _detection_rows(label, true, auto, subset=None):
    """Rows of the detection table, per catheter, for the runs kept by ``subset``."""
    n_true, _ = _sweep_lengths(true[0])
    n_auto, _ = _sweep_lengths(auto[0])
    t = true[0]["t"].to_numpy()
    dt = pd.Series(np.diff(t, prepend=np.nan), index=true[0].index)
    step = dt[true[0]["phase"] == "sweep"].groupby(true[0]["run"], observed=True).median()
    runs = true[0].drop_duplicates("run").set_index("run")["catheter"].astype(str)
    table = pd.DataFrame({"catheter": runs, "diff": (n_auto - n_true).reindex(runs.index)})
    table["diff_s"] = table["diff"] * step.reindex(runs.index)
    if subset is not None:
        table = table[subset(table.index.to_series())]
    rows = []
    for catheter, part in table.groupby("catheter", sort=True):
        rows.append({"runs": label, "catheter": catheter, "n": len(part),
                     "exact": int((part["diff"] == 0).sum()),
                     "max_samples": int(part["diff"].abs().max()),
                     "max_s": float(part["diff_s"].abs().max()),
                     "min_diff": int(part["diff"].min()), "max_diff": int(part["diff"].max())})
    return rows


def _print_detection(rows):
    print("| runs | catheter | runs | exact | max abs(detected - true) (samples) "
          "| (s) | detected - true, range (samples) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['runs']} | {r['catheter']} | {r['n']} | {r['exact']} | "
              f"{r['max_samples']} | {r['max_s']:.1f} | {r['min_diff']} to {r['max_diff']} |")


def _protocol_rmse(X, y, n_jobs):
    """Mean per-run RMSE (mm) of PDL and PDL+GRU per catheter, quick schedule."""
    schedule = dataclasses.replace(QUICK, variants=("PDL+GRU",))
    result = run_protocol(X, y, schedule=schedule, exclude_settings="S00", n_jobs=n_jobs)
    return compute_tables(result, n_bootstrap=10)["table_1"], result.elapsed


def _instrument_rows():
    """Detection on the simulated instruments of one and three motors, and at 40 Hz.

    One run per setting of the four catheters (``n_runs=1``), each run's
    motor angles and times passed to :func:`find_sweep_end` directly.
    """
    rows = []
    for label, kwargs in (("1 motor, 10 Hz", {"n_motors": 1}), ("3 motors, 10 Hz", {"n_motors": 3}),
                          ("2 motors, 40 Hz", {"rate_hz": 40.0})):
        data = make_benchmark(n_runs=1, **kwargs)
        rate = kwargs.get("rate_hz", 10.0)
        diffs, rays = [], set()
        for _, part in data.X.groupby("run", observed=True, sort=False):
            end = find_sweep_end(part.drop(columns="phase"))
            diffs.append(end.n_sweep - int((part["phase"] == "sweep").sum()))
            rays.add(end.n_rays)
        diffs = np.asarray(diffs)
        rows.append((label, len(diffs), int((diffs == 0).sum()), int(np.abs(diffs).max()),
                     float(np.abs(diffs).max() / rate), sorted(rays)))
    print("| instrument | runs | exact | max abs(detected - true) (samples) | (s) | rays found |")
    print("|---|---|---|---|---|---|")
    for label, n, exact, worst, worst_s, rays in rows:
        print(f"| {label} | {n} | {exact} | {worst} | {worst_s:.1f} | {rays} |")


def _noise_rows(sigmas=(0.01, 0.05, 0.2), random_state=0):
    """Detection on two-motor runs with white encoder noise added to the motor angles (deg)."""
    data = make_benchmark(n_runs=1)
    rng = np.random.default_rng(random_state)
    print("| noise sigma (deg) | runs | exact | max abs(detected - true) (samples) | (s) "
          "| detected - true, range (samples) |")
    print("|---|---|---|---|---|---|")
    for sigma in sigmas:
        diffs = []
        for run, part in data.X.groupby("run", observed=True, sort=False):
            q = part[["q1", "q2"]].to_numpy() + rng.normal(0.0, sigma, (len(part), 2))
            end = find_sweep_end(q, part["t"].to_numpy(), run=run)
            diffs.append(end.n_sweep - int((part["phase"] == "sweep").sum()))
        diffs = np.asarray(diffs)
        worst = int(np.abs(diffs).max())
        print(f"| {sigma:g} | {len(diffs)} | {int((diffs == 0).sum())} | {worst} | "
              f"{worst / 10.0:.1f} | {diffs.min()} to {diffs.max()} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-protocol", action="store_true",
                        help="skip the PDL+GRU comparison")
    parser.add_argument("--n-jobs", type=int, default=1, help="models trained in parallel")
    parser.add_argument("--instruments", action="store_true",
                        help="only the detection on one and three motors and at 40 Hz")
    parser.add_argument("--noise", action="store_true",
                        help="only the detection with encoder noise added to the motor angles")
    args = parser.parse_args(argv)
    if args.instruments:
        _instrument_rows()
        return
    if args.noise:
        _noise_rows()
        return

    start = time.perf_counter()
    default = make_benchmark()
    true, auto, _ = _read_both(default)
    rows = _detection_rows("default", true, auto)
    changed = make_benchmark(shaft_change=True, resweep=True)
    c_true, c_auto, _ = _read_both(changed)
    after = lambda runs: runs.str.endswith("/after")  # noqa: E731
    rows += _detection_rows("shaft change, before", c_true, c_auto, lambda r: ~after(r))
    rows += _detection_rows("shaft change, re-sweep", c_true, c_auto, after)
    print(f"\nDetected sweep ends ({time.perf_counter() - start:.0f} s, reading included)\n")
    _print_detection(rows)

    identical = all(
        a[0].equals(b[0]) and np.array_equal(a[1], b[1], equal_nan=True)
        for a, b in ((true, auto), (c_true, c_auto))
    )
    print(f"\nRecordings read with n_sweep='auto' identical to those with the true n_sweep: "
          f"{identical}")
    if identical or args.no_protocol:
        return
    print("\nPDL and PDL+GRU (quick schedule, settings held out), mean per-run RMSE (mm)\n")
    rmse_true, s_true = _protocol_rmse(*true, args.n_jobs)
    rmse_auto, s_auto = _protocol_rmse(*auto, args.n_jobs)
    print("| method | catheter | true n_sweep | n_sweep='auto' | relative difference |")
    print("|---|---|---|---|---|")
    for method in ("PDL", "PDL+GRU"):
        for catheter in rmse_true.columns:
            a, b = rmse_true.loc[method, catheter], rmse_auto.loc[method, catheter]
            print(f"| {method} | {catheter} | {a:.3f} | {b:.3f} | {100 * (b - a) / a:+.2f} % |")
    print(f"\nprotocol wall time: {s_true:.0f} s (true), {s_auto:.0f} s (auto)")


if __name__ == "__main__":
    main()
