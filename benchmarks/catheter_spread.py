"""Which catheter parameters drive the per-catheter backbone error of the simulator.

The paper's four catheter units (one disposable family) differ little in
their PDL backbone error (6.5-7.4 mm); the units that
:func:`skcath.datasets.sample_catheter` draws differ much more. This script
measures that unit-to-unit spread on many simulated units and relates it to
the parameters of each unit:

1. **Units.** ``--n-catheters`` units are drawn exactly as the benchmark
   draws them (``skcath.datasets.benchmark_catheter`` with
   ``--random-state`` and ``--unit-spread``), numbered ``C5``, ``C6``, ... so
   that they never coincide with ``C1``-``C4`` of the benchmark of the same
   seed. Each unit is simulated with
   ``make_benchmark(catheters=[unit], n_runs=--n-runs)``, i.e. in the
   benchmark's runs of that unit and its tracker field; the runs of the 16
   bent shaft settings are scored (the straight setting is not, as in
   ``bench_backbones.py``). ``C1``-``C4`` are simulated too, with the
   benchmark's three runs per setting, as reference: with ``--random-state
   0`` their runs are those of the default benchmark.
2. **Backbone error.** PCC and PDL are calibrated on each run's own sweep and
   scored on its motion rows exactly as ``bench_backbones.py`` does; a unit's
   error is the mean of its per-run RMSE (mm). The tip excursion ``tip_rms``
   (RMS distance of the measured tip from its mean over the motion rows, mm)
   is averaged the same way, and so is the ratio of the two.
3. **Drivers.** Every unit is described by 50 features: its scalar
   parameters, the magnitudes of the zero-mean ones (and the signed value
   where the sign has a meaning: ``split_bias``, ``twist``), norms of the
   small vectors, mean and relative spread of the four tendon gains, and the
   base-sensor mount. The per-unit PDL error is related to them by
   Spearman's rank correlation and by a ridge fit on the standardised
   features (coefficients in mm per standard deviation of the feature;
   leave-one-catheter-out R^2 of the ridge on all features and on the ``k``
   features with the largest absolute Spearman correlation, chosen inside
   each fold); the table is ranked by absolute Spearman correlation (the
   parameters are drawn independently). Ten parameters that the ``play`` mechanism and the backbones
   never use (the Bouc-Wen and Dahl constants, the torque chain) are kept as
   negative controls (column ``control``).
4. **One at a time.** For ``C1`` and ``C2`` of the benchmark (run ``R1`` of
   each bent setting), every physical feature in turn is set to the family's
   mid-range value ``m`` with ``dataclasses.replace`` on the unit, on the
   same runs (the changed unit keeps its name, and so its runs); the
   largest changes of the unit's PDL error are printed. ``m``
   is the median over 4000 draws of ``sample_catheter`` (for the mean gain,
   the four gains are scaled to the family's median mean gain; for the gain
   spread, the four gains are set to their own mean).
5. **Narrowing.** The drawn units are simulated again with the drivers
   (``--drivers``, else the top ``--n-drivers`` of the ranking) pulled
   towards ``m``, ``x -> m + f (x - m)`` with ``f = --narrow-factor``, one
   more driver at a time. For a parameter drawn from ``U(a, b)`` or
   ``N(m, s^2)`` this is exactly a draw from the range narrowed to ``f``
   times its width (``s`` times ``f``), so the table predicts the
   per-catheter spread of a family with those ranges narrowed.

The spread table also gives ``P(sd4<=paper)``: the share of random sets of
four units whose standard deviation is at most that of the paper's four
units. Everything is deterministic given ``--random-state``; ``--n-jobs``
only spreads the units over worker processes (joblib, loky). The header
names the simulator sources used (folder, ``SIMULATOR_VERSION`` and a hash
of the files), so a table can be tied to the simulator that produced it.

Usage (from the repository root)::

    nice -n 10 .venv/bin/python benchmarks/catheter_spread.py
    nice -n 10 .venv/bin/python benchmarks/catheter_spread.py --drivers split_bias,gain_mean,mu
    .venv/bin/python benchmarks/catheter_spread.py --drivers-only   # tables 1-3 only (2 CPU-minutes)

Cost: about 1.4 s of one CPU per unit and pass (16 runs: simulation and both
backbones) on an idle machine, about twice that on a busy one. The default
(48 units, 3 drivers) makes 1 + 3 passes over the units, one over C1-C4 (3
runs each) and 2 x 37 one-at-a-time passes over C1 and C2: about 280 unit
passes, 7 CPU-minutes, 4 wall-clock minutes with ``--n-jobs 2`` on an idle
2-core machine; ``--drivers-only`` stops after 60 unit passes (1.5 CPU-minutes).
"""

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import pandas as pd
from _machine import machine_lines, source_digest
from joblib import Parallel, delayed
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr
from sklearn.feature_selection import SelectKBest
from sklearn.linear_model import RidgeCV
from sklearn.metrics import r2_score
from sklearn.model_selection import LeaveOneOut, cross_val_predict
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

import skcath.datasets
from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.datasets import benchmark_catheter, make_benchmark, sample_catheter
from skcath.metrics import per_run_rmse

#: Per-catheter backbone RMSE of the paper's real units (mm).
PAPER = {"PCC": [7.4, 9.0, 8.3, 7.7], "PDL": [6.9, 7.4, 7.2, 6.5]}
N_REFERENCE = 4  # C1-C4 of the benchmark
N_REFERENCE_RUNS = 3  # runs per setting of the default benchmark
N_FAMILY_DRAWS = 4000  # draws of sample_catheter that define the mid-range values
#: Ridge penalties on the standardised features: at least 1, since there are about as
#: many features as units and an unpenalised fit would interpolate the noise.
ALPHAS = np.logspace(0, 4, 17)


# --------------------------------------------------------------------------- features
def _scalar(field, *, absolute=False, scale=1.0):
    """Feature of one scalar field (its magnitude if ``absolute``), and its shrink."""
    def get(cat):
        value = scale * getattr(cat, field)
        return abs(value) if absolute else value

    def shrink(cat, f, mid):
        value = getattr(cat, field)
        return dataclasses.replace(cat, **{field: mid[field] + f * (value - mid[field])})

    return get, shrink


def _vector(field, index=slice(None), *, scale=1.0, sign=1.0):
    """Norm (or signed single element) of a vector field, and its element-wise shrink."""
    def get(cat):
        part = np.asarray(getattr(cat, field), dtype=float)[index]
        return sign * scale * (np.linalg.norm(part) if np.ndim(part) else part)

    def shrink(cat, f, mid):
        value = np.array(getattr(cat, field), dtype=float)
        value[index] = mid[field][index] + f * (value[index] - mid[field][index])
        return dataclasses.replace(cat, **{field: value})

    return get, shrink


def _gain_mean(cat):
    return float(np.rad2deg(np.mean(cat.gains)))


def _shrink_gain_mean(cat, f, mid):
    """Scale the four gains so that their mean moves towards the family's median mean."""
    mean = np.mean(cat.gains)
    target = mid["gain_mean"] + f * (mean - mid["gain_mean"])
    return dataclasses.replace(cat, gains=cat.gains * (target / mean))


def _gain_spread(cat):
    return float(np.std(cat.gains) / np.mean(cat.gains))


def _shrink_gain_spread(cat, f, mid):
    """Pull the four gains towards their own mean (the mean gain is kept)."""
    mean = np.mean(cat.gains)
    return dataclasses.replace(cat, gains=mean + f * (cat.gains - mean))


def _mount_tilt(cat):
    """Angle between the section axis and the base sensor's z axis (deg)."""
    z = Rotation.from_rotvec(cat.mount_rotvec).apply([0.0, 0.0, 1.0])
    return float(np.rad2deg(np.arccos(np.clip(z[2], -1.0, 1.0))))


_DEG = float(np.rad2deg(1.0))

#: name -> (unit, getter, shrink or None). Phases of the routing harmonics and
#: the spin of the mount are left out: they have no mid-range value.
FEATURES = {
    "length": ("mm", *_scalar("length")),
    "tip_length": ("mm", *_scalar("tip_length")),
    "split_fraction": ("-", *_scalar("split_fraction")),
    "split_bias": ("-", *_scalar("split_bias")),
    "|split_bias|": ("-", *_scalar("split_bias", absolute=True)),
    "split_slope": ("1/rad", *_scalar("split_slope")),
    "max_bend": ("deg", *_scalar("max_bend", scale=_DEG)),
    "twist": ("rad/rad", *_scalar("twist")),
    "|twist|": ("rad/rad", *_scalar("twist", absolute=True)),
    "|coupling|": ("-", *_vector("coupling")),
    "|rest_bend|": ("deg", *_vector("rest_bend", scale=_DEG)),
    "gain_mean": ("deg/deg", _gain_mean, _shrink_gain_mean),
    "gain_spread": ("-", _gain_spread, _shrink_gain_spread),
    "|offsets|": ("deg", *_vector("offsets")),
    "mu": ("-", *_scalar("mu")),
    "play_w0": ("deg", *_scalar("play_w0")),
    "play_growth_base": ("deg/deg", *_scalar("play_growth_base")),
    "play_growth_scale": ("deg/deg", *_scalar("play_growth_scale")),
    "play_asym": ("-", *_scalar("play_asym")),
    "cross_load": ("-", *_scalar("cross_load")),
    "wrap_routing": ("-", *_scalar("wrap_routing")),
    "dead_zone0": ("deg", *_scalar("dead_zone0")),
    "dead_zone_growth": ("deg/rad", *_scalar("dead_zone_growth")),
    "route_a1": ("rad", *_scalar("route_a1")),
    "|route_a3|": ("rad", *_scalar("route_a3", absolute=True)),
    "|route_b3|": ("-", *_scalar("route_b3", absolute=True)),
    "route_shift": ("rad/rad", *_scalar("route_shift")),
    "windup": ("deg", *_scalar("windup", scale=_DEG)),
    "slow_creep_gain": ("-", *_scalar("slow_creep_gain")),
    "slow_creep_tau": ("s", *_scalar("slow_creep_tau")),
    "tip_lag": ("s", *_scalar("tip_lag")),
    "offset_shift": ("deg/rad", *_scalar("offset_shift")),
    "gain_shift": ("1/rad", *_scalar("gain_shift")),
    "gain_loss": ("-", *_scalar("gain_loss")),
    "rest_shift": ("rad/rad", *_scalar("rest_shift")),
    "coupling_shift": ("1/rad", *_scalar("coupling_shift")),
    "twist_shift": ("1/rad", *_scalar("twist_shift")),
    "mount_depth": ("mm", *_vector("mount_position", 2, sign=-1.0)),
    "mount_lateral": ("mm", *_vector("mount_position", slice(0, 2))),
    "mount_tilt": ("deg", _mount_tilt, None),
    # not used by the play mechanism or by the backbones: negative controls
    "bw_kappa": ("-", *_scalar("bw_kappa")),
    "rate_gain": ("-", *_scalar("rate_gain")),
    "rate_speed": ("deg/s", *_scalar("rate_speed")),
    "creep_gain": ("-", *_scalar("creep_gain")),
    "creep_tau": ("s", *_scalar("creep_tau")),
    "pulley_radius": ("mm", *_scalar("pulley_radius")),
    "pretension": ("N", *_scalar("pretension")),
    "stiffness": ("N/deg", *_scalar("stiffness")),
    "motor_friction": ("N mm", *_scalar("motor_friction")),
    "motor_viscous": ("N mm s/deg", *_scalar("motor_viscous")),
}
CONTROLS = ("bw_kappa", "rate_gain", "rate_speed", "creep_gain", "creep_tau", "pulley_radius",
            "pretension", "stiffness", "motor_friction", "motor_viscous")


def feature_table(catheters):
    """One row of features per catheter unit."""
    return pd.DataFrame(
        [{name: float(get(c)) for name, (_, get, _) in FEATURES.items()} for c in catheters],
        index=[c.name for c in catheters],
    )


def family_mid(random_state, unit_spread):
    """Mid-range value of every parameter: the median over many draws of the family."""
    root = np.random.SeedSequence([random_state, 10**6 + 1])
    draws = [sample_catheter(seed, unit_spread=unit_spread) for seed in root.spawn(N_FAMILY_DRAWS)]
    mid = {}
    for field in dataclasses.fields(draws[0]):
        values = [getattr(c, field.name) for c in draws]
        if field.name != "name":
            mid[field.name] = np.median(np.asarray(values, dtype=float), axis=0)
    mid["gain_mean"] = float(np.median([np.mean(c.gains) for c in draws]))
    return mid


# --------------------------------------------------------------------------- scoring
def score_runs(unit, n_runs, random_state):
    """Per-run PCC and PDL RMSE and tip excursion (mm) of one unit's bent-setting runs.

    The unit is recorded in the benchmark's runs of the unit with its name
    (``n_runs`` per setting); the runs of the straight setting are left out.
    ``tip_rms`` is the RMS distance of the measured tip from its mean position
    over the motion rows of the run: how far the tip travels.
    """
    data = make_benchmark(n_runs=n_runs, random_state=random_state, catheters=[unit], cache=False)
    bent = data.runs[data.runs["bend_level"] != "straight"]
    rows = data.X["run"].isin(bent["run"]).to_numpy()
    X, y = data.X[rows].reset_index(drop=True), data.y[rows]
    out = bent[["run", "catheter", "repeat"]].set_index("run")
    for name, est in (("PCC", PCCBackbone(n_jobs=1)), ("PDL", PDLBackbone(n_jobs=1))):
        nominal = est.fit(X).predict(X)
        out[name] = per_run_rmse(y, nominal, X).loc[out.index]
    motion = (X["phase"] == "motion").to_numpy()
    tip = pd.DataFrame(y[motion], columns=["x", "y", "z"])
    tip["run"] = X["run"].to_numpy()[motion]
    out["tip_rms"] = tip.groupby("run", observed=True)[["x", "y", "z"]].var(ddof=0).sum(axis=1).pow(0.5)
    return out


def score_units(jobs, random_state, n_jobs):
    """Per-run scores of several units, each given as ``(unit, n_runs)``, in parallel."""
    tables = Parallel(n_jobs=n_jobs)(
        delayed(score_runs)(unit, n_runs, random_state) for unit, n_runs in jobs
    )
    return pd.concat(tables)


def per_unit(table):
    """Mean over the runs of each unit (mm)."""
    return table.groupby("catheter", sort=False)[["PCC", "PDL", "tip_rms"]].mean()


def spread(values, random_state=0, n_draws=20000):
    """Mean, standard deviation, coefficient of variation and range of per-unit errors (mm).

    ``P(sd4<=paper)`` is the share of ``n_draws`` random sets of four of the
    units (without replacement) whose standard deviation is at most that of
    the paper's four units (0.39 mm for PDL).
    """
    values = np.asarray(values, dtype=float)
    sd = values.std(ddof=1)
    rng = np.random.default_rng(random_state)
    fours = np.argsort(rng.random((n_draws, len(values))), axis=1)[:, :4]
    return {"mean": values.mean(), "sd": sd, "cv_%": 100 * sd / values.mean(),
            "p10": np.percentile(values, 10), "p90": np.percentile(values, 90),
            "min": values.min(), "max": values.max(),
            "P(sd4<=paper)": np.mean(values[fours].std(axis=1, ddof=1) <= np.std(PAPER["PDL"], ddof=1))}


# --------------------------------------------------------------------------- drivers
def _abs_spearman(X, y):
    rho = np.array([spearmanr(x, y).statistic for x in X.T])
    return np.abs(np.nan_to_num(rho))


def rank_drivers(features, target):
    """Spearman correlation and standardised ridge coefficient of every feature.

    Ranked by absolute Spearman correlation: the parameters of a unit are drawn
    independently, so the univariate association is the effect of each one
    with the others averaged over the family.
    """
    rows = []
    for name in features:
        res = spearmanr(features[name], target)
        rows.append({"feature": name, "unit": FEATURES[name][0], "spearman": res.statistic,
                     "p": res.pvalue})
    table = pd.DataFrame(rows).set_index("feature")
    ridge = make_pipeline(StandardScaler(), RidgeCV(alphas=ALPHAS)).fit(features, target)
    table["ridge_mm_per_sd"] = ridge[-1].coef_
    table["control"] = [name in CONTROLS for name in table.index]
    table = table.reindex(table["spearman"].abs().sort_values(ascending=False).index)
    table.insert(0, "rank", np.arange(1, len(table) + 1))
    return table, float(ridge[-1].alpha_)


def loco_r2(features, target, ks):
    """Leave-one-catheter-out R^2 of the ridge on all features and on the top-k (in fold)."""
    out = {}
    for k in (*ks, "all"):
        steps = [StandardScaler()]
        if k != "all":
            steps.append(SelectKBest(_abs_spearman, k=k))
        model = make_pipeline(*steps, RidgeCV(alphas=ALPHAS))
        pred = cross_val_predict(model, features.to_numpy(), target, cv=LeaveOneOut())
        out[f"top {k}" if k != "all" else f"all {features.shape[1]}"] = r2_score(target, pred)
    return pd.Series(out, name="LOCO R^2")


# --------------------------------------------------------------------------- main
def _print(title, frame, digits=2):
    print(f"\n### {title}\n")
    print(frame.round(digits).to_markdown() if hasattr(frame, "to_markdown") else frame)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-catheters", type=int, default=48, help="units drawn (C5, C6, ...)")
    parser.add_argument("--n-runs", type=int, default=1, help="runs per bent setting of a drawn unit")
    parser.add_argument("--n-drivers", type=int, default=3,
                        help="top drivers (by |Spearman|) narrowed in the last table")
    parser.add_argument("--drivers", default=None,
                        help="comma-separated features to narrow instead of the top --n-drivers")
    parser.add_argument("--narrow-factor", type=float, default=0.3,
                        help="factor f of x -> m + f (x - m) for the narrowed family")
    parser.add_argument("--drivers-only", action="store_true",
                        help="stop after the driver ranking (no one-at-a-time, no narrowing)")
    parser.add_argument("--n-jobs", type=int, default=1)
    parser.add_argument("--random-state", type=int, default=0)
    parser.add_argument("--unit-spread", type=float, default=0.35,
                        help="unit_spread of the drawn family (1: simulator version 5; default 0.35)")
    args = parser.parse_args()
    if args.n_catheters < 8 or args.n_runs < 1 or args.n_drivers < 1:
        parser.error("--n-catheters must be >= 8, --n-runs and --n-drivers >= 1")
    if not (0.0 <= args.narrow_factor <= 1.0 and 0.0 <= args.unit_spread <= 1.0):
        parser.error("--narrow-factor and --unit-spread must be in [0, 1]")
    # features with a mid-range value; |x| is left out where x itself is a feature (same change)
    shrinkable = [f for f, (_, _, shrink) in FEATURES.items() if shrink is not None and f not in CONTROLS
                  and not (f.startswith("|") and f.strip("|") in FEATURES)]
    chosen = None if args.drivers is None else args.drivers.split(",")
    if chosen is not None and not set(chosen) <= set(shrinkable):
        parser.error(f"--drivers must be among {shrinkable}; got {args.drivers!r}")
    pd.set_option("display.width", 140)
    start = time.perf_counter()
    print("\n".join(machine_lines()))
    print(f"arguments: {vars(args)}")
    simulator = skcath.datasets
    print(f"simulator: {Path(simulator.__file__).parent}, SIMULATOR_VERSION {simulator.SIMULATOR_VERSION}, "
          f"sha1 of its sources {source_digest(simulator)}")

    n_total = N_REFERENCE + args.n_catheters
    units = {f"C{k}": benchmark_catheter(k, args.random_state, unit_spread=args.unit_spread)
             for k in range(1, n_total + 1)}
    names = list(units)
    reference, drawn = names[:N_REFERENCE], names[N_REFERENCE:]
    n_runs = {name: N_REFERENCE_RUNS if name in reference else args.n_runs for name in names}

    # 1-2. per-unit backbone error
    runs = score_units([(units[n], n_runs[n]) for n in names], args.random_state, args.n_jobs)
    errors = per_unit(runs)
    errors["PDL / tip_rms"] = errors["PDL"] / errors["tip_rms"]
    ref = errors.loc[reference].copy()
    per_repeat = runs[runs["catheter"].isin(reference)].pivot_table(
        index="catheter", columns="repeat", values="PDL", aggfunc="mean")
    for r in per_repeat.columns:
        ref[f"PDL R{r}"] = per_repeat[r]
    ref["PDL sd of repeats"] = per_repeat.std(axis=1, ddof=1)
    ref["paper PCC"] = PAPER["PCC"]
    ref["paper PDL"] = PAPER["PDL"]
    _print(f"Reference units C1-C4 (benchmark random_state={args.random_state}, "
           f"{N_REFERENCE_RUNS} runs x 16 bent settings): mean over runs (mm)", ref)

    err = errors.loc[drawn]
    rs = args.random_state
    summary = pd.DataFrame({
        f"drawn units (n={len(drawn)}), PCC": spread(err["PCC"], rs),
        f"drawn units (n={len(drawn)}), PDL": spread(err["PDL"], rs),
        f"drawn units (n={len(drawn)}), tip_rms": spread(err["tip_rms"], rs),
        f"drawn units (n={len(drawn)}), PDL / tip_rms": spread(err["PDL / tip_rms"], rs),
        "C1-C4, PDL": spread(ref["PDL"], rs),
        "paper C1-C4, PDL": spread(PAPER["PDL"], rs),
    }).T
    _print("Spread over units of the per-unit means (mm; the ratio PDL / tip_rms has no unit)", summary)
    # noise in a unit's mean from the run draws alone: repeat-to-repeat sd of the
    # reference units, scaled to the number of runs of a drawn unit
    noise_sd = float(np.sqrt(np.mean(ref["PDL sd of repeats"] ** 2)) / np.sqrt(args.n_runs))
    print(f"\nrun-to-run noise of a unit's PDL mean over 16 x {args.n_runs} run(s): about "
          f"{noise_sd:.2f} mm sd (from the C1-C4 repeats), i.e. "
          f"{100 * noise_sd / err['PDL'].mean():.1f} % of the mean")
    rho = spearmanr(err["PDL"], err["tip_rms"]).statistic
    print(f"Spearman correlation of the per-unit PDL RMSE with the per-unit tip_rms: {rho:.3f}")

    # 3. drivers
    features = feature_table([units[n] for n in drawn])
    target = err["PDL"].to_numpy()
    ranking, alpha = rank_drivers(features, target)
    _print(f"Drivers of the per-unit PDL RMSE (rank by |Spearman|; ridge alpha {alpha:.3g})",
           ranking, 3)
    _print("Leave-one-catheter-out R^2 of the ridge (top k by |Spearman|, chosen in fold)",
           loco_r2(features, target, ks=(1, 2, 3, 5, 10)).to_frame(), 3)
    print(f"\nnoise ceiling: R^2 <= {1 - noise_sd**2 / target.var(ddof=1):.2f} "
          "(share of the per-unit variance that is not run noise)")

    if args.drivers_only:
        _print("Per-unit means of the drawn units (mm)", err.T, 2)
        print(f"\ntotal time {time.perf_counter() - start:.0f} s")
        return

    # 4. one at a time on C1 and C2: every physical feature in turn at mid-range
    mid = family_mid(args.random_state, args.unit_spread)
    drivers = chosen or [f for f in ranking.index if f in shrinkable][: args.n_drivers]
    one = ["C1", "C2"]
    base = per_unit(runs[runs["catheter"].isin(one) & (runs["repeat"] == 1)])
    jobs, labels = [], []
    for name in one:
        for feature in shrinkable:
            cat = FEATURES[feature][2](units[name], 0.0, mid)
            jobs.append((cat, 1))  # run R1 of every setting
            labels.append((name, feature, FEATURES[feature][1](units[name]), FEATURES[feature][1](cat)))
    moved = Parallel(n_jobs=args.n_jobs)(
        delayed(score_runs)(unit, n, args.random_state) for unit, n in jobs
    )
    rows = []
    for (name, feature, before, after), table in zip(labels, moved):
        rows.append({"unit": name, "feature": feature, "value": before, "mid-range": after,
                     "PDL change": table["PDL"].mean() - base.loc[name, "PDL"],
                     "PCC change": table["PCC"].mean() - base.loc[name, "PCC"],
                     "tip_rms change": table["tip_rms"].mean() - base.loc[name, "tip_rms"]})
    scan = pd.DataFrame(rows)
    scan["|PDL change|"] = scan["PDL change"].abs()
    for name in one:
        part = scan[scan["unit"] == name].sort_values("|PDL change|", ascending=False).head(8)
        _print(f"One at a time: {name} (run R1 of the 16 bent settings: PDL {base.loc[name, 'PDL']:.2f} mm, "
               f"tip_rms {base.loc[name, 'tip_rms']:.2f} mm) with one feature at the family's mid-range "
               "value; the 8 largest PDL changes (mm)",
               part.drop(columns=["unit", "|PDL change|"]).set_index("feature"), 3)
    _print("One at a time: PDL change (mm) of C1 and C2 for the narrowed drivers",
           scan[scan["feature"].isin(drivers)].pivot(index="feature", columns="unit", values="PDL change")
           .reindex(drivers), 3)

    # 5. narrowed family: drivers pulled towards mid-range, one more at a time
    f = args.narrow_factor
    rows = {"as drawn": spread(err["PDL"], rs)}
    for k in range(1, len(drivers) + 1):
        jobs = []
        for name in drawn:
            cat = units[name]
            for d in drivers[:k]:
                cat = FEATURES[d][2](cat, f, mid)
            jobs.append((cat, args.n_runs))
        narrowed = per_unit(score_units(jobs, args.random_state, args.n_jobs))
        rows[" + ".join(drivers[:k])] = spread(narrowed["PDL"], rs)
    _print(f"Predicted per-unit PDL RMSE spread with the drivers' ranges narrowed to {f:g} of their width "
           f"(x -> m + {f:g} (x - m); same {len(drawn)} units and runs; mm)", pd.DataFrame(rows).T)
    print("\nmid-range values m: " + ", ".join(
        f"{d} {FEATURES[d][1](FEATURES[d][2](units[drawn[0]], 0.0, mid)):.4g} {FEATURES[d][0]}"
        for d in drivers))

    _print("Per-unit means of the drawn units (mm)", err.T, 2)
    print(f"\ntotal time {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
