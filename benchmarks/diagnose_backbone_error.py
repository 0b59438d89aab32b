"""Where the backbone's motion error comes from: a diagnosis with the simulator's truth.

For one catheter (C1) of ``make_benchmark(mechanism=..., n_catheters=1,
n_runs=1)`` the script recomputes, from the simulator's own functions (it
changes nothing in them), the quantities that no column of ``X`` shows: the
motor offsets and tendon gains of every sample, the transmission's output
``v`` (the hysteresis), the effective input after the section's slow creep
and lag, and the torsional wind-up. It then calibrates the backbone
(``hysteresis=None``, one core) on each run's sweep and scores it on the
motion rows, removing one cause of error after the other (the rays are
always found from the motor angles, as with a hysteresis model):

- ``q``: the motor angles (the benchmark), also with ``hysteresis="play"``
  and ``"pi"`` (identified on the sweep as the backbones do);
- ``-hys``: the motor angles less the transmission's true lag ``u - v``
  (``u`` the motor input less its offsets, ``v`` the transmission's output);
- ``-creep``: less the lag behind ``v`` after the slow tendon creep too;
- ``-lag``: less the lag behind the section's input after its first-order
  lag too (``lagged``, what the section bends by);
- ``-off``: ``lagged`` plus the offsets' mean over the sweep (the offsets'
  drift during the motion removed);
- ``-noi``: as ``-off``, the sweep references and the score noise-free
  (``y_true``);
- ``-gain``: as ``-noi``, the tips recomputed with the tendon gains' mean
  over the sweep (no gain drift);
- ``-wind``: as ``-gain``, the tips recomputed without the torsional
  wind-up: what is left is the backbone's own geometry, on and between the
  sweep's rays and beyond their amplitude.

Each row prints the mean per-run motion RMSE (mm), its ratio to the first
and the mean sweep RMSE of the calibration (mm). For the rows ``q``, ``q pi``,
``-off`` and ``-wind`` the motion rows are also split (RMSE pooled over the
rows of each part, and the part's share of the rows) by where
they lie against the sweep (in the angles the backbone was given): near a
ray (within a quarter of the rays' spacing in direction) or between rays, and
inside or beyond the sweep's amplitude on the nearest ray. The simulator's
tip does not depend on the motor torques; load acts on it only through the
transmission (the width of the loops grows with both motors' inputs) and
the slow creep, which the rows -hys and -creep remove.

Diagnosis only: the truth it reads is not available to an estimator, nor
to the public API (the script reads the simulator's private functions, the
one exception to the benchmarks' use of the public API in
``tests/test_layout.py``).

Usage (from the repository root)::

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/diagnose_backbone_error.py --mechanism play --max-runs 4
    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/diagnose_backbone_error.py --max-runs 17 --no-identified
    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/diagnose_backbone_error.py --mechanism dahl_creep \
        --unit rate_gain=0

``--unit FIELD=VALUE ...`` changes fields of the unit C1 (its runs stay those
of C1): which property of the simulated unit a gap comes from.
"""

import argparse
import dataclasses

import numpy as np
import pandas as pd

from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.datasets import MECHANISMS, benchmark_catheter, make_benchmark
# the simulator's truth, which no public function returns (tests/test_layout.py names these modules)
from skcath.datasets._benchmark import benchmark_specs
from skcath.datasets._simulator import (
    _creep_and_lag, _draw_run, _lag, _mechanics, _mounted, _padded, _transmission, check_run_variation,
)
from skcath.metrics import per_run_rmse
from skcath.sweep import find_rays

BACKBONES = {"PCC": PCCBackbone, "PDL": PDLBackbone}


def simulator_truth(cat, mechanism, runs, random_state=0):
    """Per run of unit ``cat``: motor angles, offsets, transmission output, section input, gains, wind-up."""
    specs = [s for s in benchmark_specs([cat], 1, random_state) if s.run in runs]
    draws = [_draw_run(s, check_run_variation(None)) for s in specs]
    v, phi, windup = _transmission(_padded([d["u"] for d in draws]), specs,
                                   [d["cfg"] for d in draws], mechanism)
    truth = {}
    for j, (spec, d) in enumerate(zip(specs, draws)):
        n = len(d["q"])
        lagged = _creep_and_lag(cat, v[:n, j])
        # the slow creep of _creep_and_lag alone, without the section's lag
        crept = v[:n, j] - cat.slow_creep_gain * _lag(v[:n, j], cat.slow_creep_tau)
        truth[spec.run] = {"cat": cat, "cfg": d["cfg"], "q": d["q"], "u": d["u"], "v": v[:n, j],
                           "lagged": lagged, "crept": crept, "phi": phi[:n, j], "windup": windup[:n, j],
                           "gain": d["gain_scale"], "offsets": d["offsets"], "n_sweep": d["n_sweep"]}
    return truth


def _tips(tr, gain, windup):
    """Noise-free tips (mm, base frame) of a run with the given gains and wind-up."""
    _, _, p_k, _ = _mechanics(tr["cat"], tr["cfg"], tr["lagged"], tr["phi"], windup, gain)
    return _mounted(tr["cat"], p_k)


def variants(data, truth):
    """The rows of the ladder: (name, angles given, sweep references, target scored against)."""
    X, y, y_true = data.X, data.y, data.y_true
    out = [("q", X[["q1", "q2"]].to_numpy(), X[["ref_x", "ref_y", "ref_z"]].to_numpy(), y)]
    lag_hys, lag_creep, lag_all, q_off, y_gain, y_wind = ([] for _ in range(6))
    for run, tr in truth.items():
        s = slice(None, tr["n_sweep"])
        q_off.append(tr["lagged"] + tr["offsets"][s].mean(axis=0))
        lag_hys.append(tr["q"] - (tr["u"] - tr["v"]))
        lag_creep.append(tr["q"] - (tr["u"] - tr["crept"]))
        lag_all.append(tr["q"] - (tr["u"] - tr["lagged"]))
        gain = np.broadcast_to(tr["gain"][s].mean(axis=0), tr["gain"].shape)
        y_gain.append(_tips(tr, gain, tr["windup"]))
        y_wind.append(_tips(tr, gain, np.zeros_like(tr["windup"])))
    check = np.concatenate([truth[r]["q"] for r in truth])
    if not np.array_equal(check, X[["q1", "q2"]].to_numpy()):
        raise RuntimeError("the recomputed motor angles are not the benchmark's")

    def with_q(qs, ref=None):
        return np.concatenate(qs), (X[["ref_x", "ref_y", "ref_z"]].to_numpy() if ref is None else ref)

    out += [("-hys", *with_q(lag_hys), y), ("-creep", *with_q(lag_creep), y),
            ("-lag", *with_q(lag_all), y), ("-off", *with_q(q_off), y),
            ("-noi", *with_q(q_off, y_true), y_true)]
    y_gain, y_wind = np.concatenate(y_gain), np.concatenate(y_wind)
    out += [("-gain", *with_q(q_off, y_gain), y_gain), ("-wind", *with_q(q_off, y_wind), y_wind)]
    return out


def calibrate(backbone, X, q_eff, ref):
    """Nominal tips (mm) of every row and mean sweep RMSE (mm), each run calibrated in the angles ``q_eff``.

    The rays are found from the motor angles, as the backbones do with a
    hysteresis model; the calibration reads the angles ``q_eff`` and the
    sweep references ``ref``.
    """
    q = X[["q1", "q2"]].to_numpy()
    sweep = (X["phase"] == "sweep").to_numpy()
    nominal, sweep_rmse = np.empty((len(X), 3)), []
    for run, idx in X.groupby("run", observed=True).indices.items():
        s = idx[sweep[idx]]
        rays = find_rays(q[s], n_rays=backbone.n_rays, run=run)
        params, info = backbone._calibrate(q_eff[s], ref[s], rays, q[s])
        nominal[idx] = backbone._evaluate(q_eff[idx], params)
        sweep_rmse.append(info["rmse_mm"])
    return nominal, float(np.mean(sweep_rmse))


def where(X, q_all, spacing_deg=45.0):
    """Per row: angular distance (deg) to the nearest sweep ray and rho over that ray's amplitude."""
    near = np.empty(len(X))
    beyond = np.empty(len(X))
    for _, idx in X.groupby("run", observed=True).indices.items():
        part = X.iloc[idx]
        q = q_all[idx]
        sweep = (part["phase"] == "sweep").to_numpy()
        center = q[sweep][:20].mean(axis=0)
        d = q - center
        rho, psi = np.hypot(d[:, 0], d[:, 1]), np.degrees(np.arctan2(d[:, 1], d[:, 0]))
        far = sweep & (rho > 0.5 * rho[sweep].max())
        ray = np.round(psi[far] / spacing_deg).astype(int) % int(360 / spacing_deg)
        dirs = np.array([np.degrees(np.angle(np.exp(1j * np.radians(psi[far][ray == k])).mean()))
                         for k in np.unique(ray)])
        amps = np.array([rho[far][ray == k].max() for k in np.unique(ray)])
        gap = np.abs((psi[:, None] - dirs[None] + 180.0) % 360.0 - 180.0)
        k = gap.argmin(axis=1)
        near[idx] = gap[np.arange(len(idx)), k]
        beyond[idx] = rho / amps[k]
    return near, beyond


def split(X, q_eff, target, nominal, spacing_deg=45.0):
    """RMSE (mm) and share of the motion rows near/between rays and inside/beyond the sweep."""
    near, beyond = where(X, q_eff, spacing_deg)
    motion = (X["phase"] == "motion").to_numpy()
    err2 = np.sum((nominal - target) ** 2, axis=1)
    ok = motion & np.isfinite(err2)
    cells = {"near ray": near <= spacing_deg / 4, "between": near > spacing_deg / 4,
             "inside": beyond <= 1.0, "beyond": beyond > 1.0}
    return {name: (float(np.sqrt(err2[ok & m].mean())) if (ok & m).any() else np.nan,
                   float((ok & m).sum() / ok.sum())) for name, m in cells.items()}


def _assignment(text):
    """``("field", value)`` from ``"field=value"`` (a float)."""
    name, sep, value = text.partition("=")
    if not sep:
        raise SystemExit(f"--unit: expected FIELD=VALUE; got {text!r}.")
    return name, float(value)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mechanism", choices=MECHANISMS, default="play")
    parser.add_argument("--max-runs", type=int, default=4)
    parser.add_argument("--backbone", choices=list(BACKBONES), default="PDL")
    parser.add_argument("--random-state", type=int, default=0)
    parser.add_argument("--no-identified", dest="identified", action="store_false",
                        help='skip the rows of hysteresis="play" and "pi" (the slow ones)')
    parser.add_argument("--unit", nargs="+", metavar="FIELD=VALUE", default=[],
                        help="change fields of the unit C1 (e.g. rate_gain=0 creep_gain=0)")
    args = parser.parse_args(argv)
    cat = benchmark_catheter(1, args.random_state)
    if args.unit:
        # a changed unit runs the runs of C1 (not cached: a diagnosis only)
        cat = dataclasses.replace(cat, **dict(_assignment(a) for a in args.unit))
        data = make_benchmark(mechanism=args.mechanism, catheters=[cat], n_runs=1,
                              random_state=args.random_state, cache=False)
    else:
        data = make_benchmark(mechanism=args.mechanism, n_catheters=1, n_runs=1,
                              random_state=args.random_state)
    runs = list(data.X["run"].unique()[: args.max_runs])
    keep = data.X["run"].isin(runs).to_numpy()
    data.X, data.y, data.y_true = data.X[keep], data.y[keep], data.y_true[keep]
    truth = simulator_truth(cat, args.mechanism, set(runs), args.random_state)
    truth = {r: truth[r] for r in runs}
    rows = []
    ladder = variants(data, truth)
    X = data.X
    for name, q_eff, ref, target in ladder:
        options = (None, "play", "pi") if name == "q" and args.identified else (None,)
        for hysteresis in options:
            backbone = BACKBONES[args.backbone](hysteresis=hysteresis, n_jobs=1).fit(X)
            if hysteresis is None:
                nominal, sweep_rmse = calibrate(backbone, X, q_eff, ref)
            else:
                calibration = backbone.calibrate(X)
                nominal, sweep_rmse = calibration.nominal, float(calibration.table["rmse_mm"].mean())
            row = {"row": name if hysteresis is None else f"q {hysteresis}",
                   "motion RMSE (mm)": float(per_run_rmse(target, nominal, X).mean()),
                   "sweep RMSE (mm)": sweep_rmse}
            if name == "q" and hysteresis is None:
                row["vs y_true"] = float(per_run_rmse(data.y_true, nominal, X).mean())
            if hysteresis in (None, "pi") and name in ("q", "-off", "-wind"):
                for cell, (rmse, share) in split(X, q_eff, target, nominal).items():
                    row[f"{cell} (share)"] = f"{rmse:.2f} ({share:.2f})"
            rows.append(row)
            print(row, flush=True)
    table = pd.DataFrame(rows).set_index("row")
    table.insert(1, "ratio", table["motion RMSE (mm)"] / table["motion RMSE (mm)"].iloc[0])
    changed = f", changed: {' '.join(args.unit)}" if args.unit else ""
    print(f"{args.backbone}, catheter C1{changed}, mechanism {args.mechanism}, runs {len(runs)}")
    print(table.to_string(na_rep="", float_format="{:.3f}".format))

if __name__ == "__main__":
    main()
