"""Residual pipeline on real recordings: the TEE-probe acquisitions.

Data: the recordings of a robotised transesophageal echocardiography (TEE)
probe with two bending motors, read at run time from a folder outside the
project (they may not be redistributed): ``--data``, else the environment
variable ``SKCATH_TEE_PROBE``, else ``../shared/data/tee-probe`` next to the
repository. For each motor (``motor1``, ``motor2``) the folder holds three
acquisitions ``motor{m}_current60_acq{a}.csv`` (``a = 1, 2, 3``). In every
acquisition only that motor moves, once through centre -> max -> min ->
centre, while an EM tracker records a sensor at the probe tip and one at the
probe base (quaternions scalar last, ``x, y, z, w``).

Conventions (the recordings lack what skcath's format expects):

- the motor encoder position is ``q1`` in raw **counts** (not converted: the
  counts-to-degrees factor is not documented), ``q2 = 0``; the motor current
  (raw units) is ``tau1``, ``tau2 = 0``;
- the sampling rate is unknown; ``t`` uses a nominal 10 Hz (no model uses
  ``t``);
- a TEE acquisition has no 8-ray calibration sweep. The first
  ``--n-sweep`` samples (default 10, under 1 % of an acquisition) are marked
  ``"sweep"`` only to satisfy the format: nothing calibrates on them, the
  residual learners run with ``use_context=False, frame="base"``, and all
  errors are over the ``"motion"`` rows that follow;
- the target is the tip position in the base sensor's frame,
  ``skcath.frames.tip_in_base_frame(..., quat_order="xyzw")``, computed by
  ``skcath.io.read_recording``. The script checks the quaternion order on
  the data: with the right order the axis of the tip sensor's rotation
  relative to the base sensor is normal to the plane in which the tip
  moves (angle printed for both orders).

Methods, all trained on acquisition 1 of a motor only and tested on its
acquisitions 2 and 3:

- ``polynomial``: a memoryless least-squares polynomial of the motor
  position, ``p = P(q)``
  (``skcath.backbones.PolynomialBackbone(degree, calibration="fit")``:
  standardised ``q``, all monomials up to the degree, linear least
  squares), its degree chosen by blocked cross-validation inside
  acquisition 1;
- ``polynomial+MLP``: the polynomial as the backbone (nominal tip
  ``b = P(q)``) and ``skcath.residuals.MLPResidual`` on top;
- ``polynomial+GRU``: the same with ``skcath.residuals.GRUResidual``.

The polynomial's degree (1-9) and the learners' ``use_torque`` (per motor
and learner, :data:`DEFAULT_GRID`) are chosen on acquisition 1 alone: its
motion rows are cut into 20 contiguous blocks, and each of two folds
(``skcath.model_selection.BlockKFold(2, n_blocks=20)``; the grid is a
``ParameterGrid``) hides the targets of every other block (set to NaN,
which the polynomial and the learners skip as tracker dropouts) and scores
the errors there, with the motor signals of the whole acquisition as input.
The other learner settings (:data:`BASE_LEARNER`, 200 epochs) were fixed
beforehand. The test acquisitions are never used for a choice.

Acquisition 3 of motor 2 is a copy of acquisition 1 (the script compares the
arrays); its row is reported and flagged ``leaks_training``, and left out of
the headline ratio.

Usage (from the repository root; about 5 CPU minutes with the defaults, one
thread)::

    .venv/bin/python benchmarks/bench_tee_probe.py
    .venv/bin/python benchmarks/bench_tee_probe.py --quick   # 2 epochs, 1 seed, no search
    .venv/bin/python benchmarks/bench_tee_probe.py --pi --no-search --seeds 0  # with PI rows

With ``--pi`` two methods are added: ``polynomial+PI``, the polynomial after a
Prandtl-Ishlinskii hysteresis with dead band and creep identified with it on
acquisition 1 (``PolynomialBackbone(degree, calibration="fit",
hysteresis="pi", max_play_deg=...)``, the largest threshold a third of half
the motor's range, as 20 deg is of the 60 deg rays of the simulated sweep),
and ``polynomial+PI+GRU``, the GRU after it with the settings of
``polynomial+GRU``. ``t`` is the nominal 10 Hz, so the creep's time
constant is in nominal seconds.

Results are printed as tables and written as CSV to ``--out`` (default
``<temp dir>/skcath_tee_probe``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation
from sklearn.model_selection import ParameterGrid
from sklearn.pipeline import Pipeline

from skcath import MOTOR_COLUMNS
from skcath.backbones import PolynomialBackbone
from skcath.frames import tip_in_base_frame
from skcath.io import read_recording
from skcath.metrics import per_run_rmse
from skcath.model_selection import BlockKFold
from skcath.residuals import GRUResidual, MLPResidual

REPO = Path(__file__).resolve().parents[1]
#: Folder used when neither ``--data`` nor ``SKCATH_TEE_PROBE`` is given.
DEFAULT_DATA = REPO.parent / "shared" / "data" / "tee-probe"
ENV_VAR = "SKCATH_TEE_PROBE"
MOTORS = (1, 2)
ACQUISITIONS = (1, 2, 3)
#: Nominal sampling rate (Hz); the recordings do not state theirs.
NOMINAL_RATE_HZ = 10.0

#: skcath name -> column of the TEE-probe CSV files.
COLUMNS = {
    "q1": "motor_position",
    "tau1": "current",
    "tip_position": ["tip_position_x", "tip_position_y", "tip_position_z"],
    "base_position": ["base_position_x", "base_position_y", "base_position_z"],
    "tip_orientation": [f"tip_orientation_{c}" for c in "xyzw"],
    "base_orientation": [f"base_orientation_{c}" for c in "xyzw"],
}
QUAT_ORDER = "xyzw"
METHODS = ("polynomial", "polynomial+MLP", "polynomial+GRU")
#: Methods added by ``--pi``: the polynomial after a Prandtl-Ishlinskii hysteresis
#: (``hysteresis="pi"``) identified with it on acquisition 1, alone and with the GRU.
PI_METHODS = ("polynomial+PI", "polynomial+PI+GRU")
#: Largest PI threshold as a share of half the motor's range in acquisition 1: the
#: default 20 deg of ``max_play_deg`` over the 60 deg rays of the simulated sweep.
PI_MAX_PLAY_SHARE = 20.0 / 60.0


def file_name(motor, acquisition):
    """Name of the CSV file of one acquisition."""
    return f"motor{motor}_current60_acq{acquisition}.csv"


def resolve_data_folder(path=None):
    """The data folder: ``path``, else ``$SKCATH_TEE_PROBE``, else :data:`DEFAULT_DATA`.

    Raises
    ------
    FileNotFoundError
        With a message naming the folder and how to point to it, if it or one
        of the six acquisition files is missing.
    """
    folder = Path(path or os.environ.get(ENV_VAR) or DEFAULT_DATA)
    if not folder.is_dir():
        raise FileNotFoundError(
            f"TEE-probe data folder {str(folder)!r} not found. The recordings are not "
            f"distributed with skcath; pass their folder with --data or set {ENV_VAR}."
        )
    names = [file_name(m, a) for m in MOTORS for a in ACQUISITIONS]
    missing = [name for name in names if not (folder / name).is_file()]
    if missing:
        raise FileNotFoundError(f"TEE-probe data folder {str(folder)!r} lacks {missing}.")
    return folder


# ---------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------
def read_acquisition(path, motor, acquisition, n_sweep=10):
    """One acquisition as a skcath recording (one run), via ``read_recording``.

    Parameters
    ----------
    path : path-like
        The acquisition's CSV file.
    motor, acquisition : int
        Ids; the run is ``"motor{motor}-acq{acquisition}"``, the setting
        ``"motor{motor}"``.
    n_sweep : int, default=10
        Leading samples marked ``"sweep"`` (the format needs a sweep; nothing
        calibrates on it here).

    Returns
    -------
    X : pandas.DataFrame
        Long-format recording: ``q1`` motor position (counts), ``tau1`` motor
        current (raw units), ``q2 = tau2 = 0``, ``t`` at the nominal rate (s).
    y : ndarray of shape (n_samples, 3)
        Tip position in the base sensor's frame (mm).
    """
    return read_recording(
        path,
        columns=COLUMNS,
        quat_order=QUAT_ORDER,
        constants={"q2": 0.0, "tau2": 0.0},
        catheter="tee-probe",
        setting=f"motor{motor}",
        run=f"motor{motor}-acq{acquisition}",
        rate_hz=NOMINAL_RATE_HZ,
        n_sweep=n_sweep,
    )


def same_samples(path_a, path_b):
    """Whether two acquisition files hold the same numbers (same shape, equal values)."""
    a = pd.read_csv(path_a).drop(columns="sample", errors="ignore").to_numpy(dtype=np.float64)
    b = pd.read_csv(path_b).drop(columns="sample", errors="ignore").to_numpy(dtype=np.float64)
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))


def quaternion_order_check(path):
    """Angle (deg) between the tip sensor's rotation axis and the normal of the tip's plane.

    For each quaternion order, the tip position in the base frame is computed
    and the normal of the plane it moves in is fitted (smallest principal
    axis); the rotation of the tip sensor relative to the base sensor, taken
    relative to the first sample, has a rotation axis (largest principal axis
    of the rotation vectors). A one-motor bend rotates the tip about the
    normal of its plane of motion, so the right order gives a small angle.

    Returns
    -------
    angles : dict
        ``{"xyzw": degrees, "wxyz": degrees}``.
    """
    frame = pd.read_csv(path)
    tip_p = frame[COLUMNS["tip_position"]].to_numpy()
    base_p = frame[COLUMNS["base_position"]].to_numpy()
    tip_q = frame[COLUMNS["tip_orientation"]].to_numpy()  # columns x, y, z, w
    base_q = frame[COLUMNS["base_orientation"]].to_numpy()
    angles = {}
    # the four columns as they are, read in either order (scipy wants x, y, z, w)
    for order, to_scipy in (("xyzw", [0, 1, 2, 3]), ("wxyz", [1, 2, 3, 0])):
        p = tip_in_base_frame(tip_p, base_p, base_q, quat_order=order)
        r_base = Rotation.from_quat(base_q[:, to_scipy])
        r_tip = Rotation.from_quat(tip_q[:, to_scipy])
        relative = r_base.inv() * r_tip
        rotvec = (relative * relative[0].inv()).as_rotvec()
        axis = np.linalg.svd(rotvec, full_matrices=False)[2][0]
        normal = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)[2][2]
        angles[order] = float(np.degrees(np.arccos(min(1.0, abs(axis @ normal)))))
    return angles


@dataclass
class Motor:
    """The three acquisitions of one motor, read and checked."""

    motor: int
    X: dict = field(default_factory=dict)  # acquisition -> recording
    y: dict = field(default_factory=dict)  # acquisition -> tip (mm)
    copy_of_training: dict = field(default_factory=dict)  # acquisition -> bool
    quaternion_angles: dict = field(default_factory=dict)


def load_motor(folder, motor, n_sweep=10):
    """Read acquisitions 1-3 of ``motor`` and flag those identical to acquisition 1."""
    folder = Path(folder)
    data = Motor(motor)
    train_path = folder / file_name(motor, 1)
    for a in ACQUISITIONS:
        path = folder / file_name(motor, a)
        data.X[a], data.y[a] = read_acquisition(path, motor, a, n_sweep=n_sweep)
        data.copy_of_training[a] = a != 1 and same_samples(train_path, path)
    data.quaternion_angles = quaternion_order_check(train_path)
    return data


# ---------------------------------------------------------------------------
# models and selection
# ---------------------------------------------------------------------------
#: Learner settings fixed for this data set (one short run of ~1,150-1,430
#: samples): windows overlap heavily so that an epoch has enough of them, and
#: the networks are half the default width.
BASE_LEARNER = dict(
    use_context=False,
    frame="base",
    window_s=10.0,
    burn_in_s=2.0,
    window_step_s=1.0,
    batch_size=32,
    module__hidden_size=64,
    n_threads=1,
)
#: The grid searched inside acquisition 1 (per motor and learner).
DEFAULT_GRID = {"max_epochs": [200], "use_torque": [True, False]}
#: Used without a search (``--no-search``; ``--quick`` with 2 epochs).
DEFAULT_CONFIG = {"max_epochs": 200, "use_torque": True}
#: The blocked cross-validation inside acquisition 1: 2 folds of 20 blocks.
BLOCKS = {"n_splits": 2, "n_blocks": 20}


def make_method(method, degree, config, seed, max_play=None):
    """The estimator of ``method``: the polynomial backbone, or a Pipeline with a residual.

    Only public estimators of skcath: ``PolynomialBackbone`` alone, or in a
    ``sklearn.pipeline.Pipeline`` before ``MLPResidual`` or ``GRUResidual``;
    the methods of :data:`PI_METHODS` give the backbone ``hysteresis="pi"``
    with ``max_play_deg=max_play`` (counts).
    """
    if method in PI_METHODS:
        backbone = PolynomialBackbone(degree, calibration="fit", hysteresis="pi",
                                      max_play_deg=max_play)
    else:
        backbone = PolynomialBackbone(degree, calibration="fit")
    if method in ("polynomial", "polynomial+PI"):
        return backbone
    cls = MLPResidual if method == "polynomial+MLP" else GRUResidual
    params = {**BASE_LEARNER, **config}
    if method == "polynomial+MLP":
        params["burn_in_s"] = 0.0  # no hidden state to warm up
    residual = cls(random_state=seed, **params)
    return Pipeline([("backbone", backbone), ("residual", residual)])


def motion_rmse(y_true, y_pred, X, rows=None):
    """3-D RMSE (mm) over the motion rows of one run (``rows``: extra row mask)."""
    y_true = np.array(y_true, dtype=np.float64)
    if rows is not None:
        y_true[~rows] = np.nan
    return float(per_run_rmse(y_true, y_pred, X).iloc[0])


def first_leg(X):
    """Rows of the first leg of a run's cycle: from its start to the largest ``q1``.

    Every acquisition starts at the centre and first moves to the motor's
    maximum; the first leg is where an unknown state before the recording
    (the probe's earlier history) shows most.

    Returns
    -------
    rows : ndarray of bool, shape (n_samples,)
    """
    q = X[MOTOR_COLUMNS[0]].to_numpy(dtype=np.float64)
    rows = np.zeros(len(X), dtype=bool)
    rows[: int(np.argmax(q)) + 1] = True
    return rows


def cv_rmse(method, X, y, degree, config, seed, folds):
    """Mean held-out RMSE (mm) of ``method`` over the blocked folds of one run.

    ``folds`` is a :class:`skcath.model_selection.BlockKFold`. The training
    targets of a fold's held-out rows are set to NaN; the input is the whole
    run, so that every model sees an unbroken time series.
    """
    scores = []
    for _, test in folds.split(X):
        held = np.zeros(len(X), dtype=bool)
        held[test] = True
        y_train = np.array(y, dtype=np.float64)
        y_train[held] = np.nan
        model = make_method(method, degree, config, seed).fit(X, y_train)
        scores.append(motion_rmse(y, model.predict(X), X, rows=held))
    return float(np.mean(scores))


def select_degree(X, y, degrees=range(1, 10), folds=None):
    """Degree of the polynomial with the lowest blocked-CV RMSE inside the training run.

    Returns
    -------
    degree : int
    table : pandas.DataFrame
        Columns ``degree, cv_rmse_mm``.
    """
    folds = BlockKFold(**BLOCKS) if folds is None else folds
    rows = [
        {"degree": d, "cv_rmse_mm": cv_rmse("polynomial", X, y, d, None, None, folds)}
        for d in degrees
    ]
    table = pd.DataFrame(rows)
    return int(table.loc[table["cv_rmse_mm"].idxmin(), "degree"]), table


def _settings(config):
    """Learner settings as one string, ``"key=value, ..."``."""
    return ", ".join(f"{k}={v}" for k, v in config.items())


def select_config(method, X, y, degree, grid, seed=0, folds=None):
    """Learner settings with the lowest blocked-CV RMSE inside the training run."""
    folds = BlockKFold(**BLOCKS) if folds is None else folds
    rows = []
    for config in ParameterGrid(grid):
        rows.append({**config, "cv_rmse_mm": cv_rmse(method, X, y, degree, config, seed, folds)})
    table = pd.DataFrame(rows)
    best = table.loc[table["cv_rmse_mm"].idxmin(), list(grid)].to_dict()
    best = {k: (v.item() if hasattr(v, "item") else v) for k, v in best.items()}
    return best, table


# ---------------------------------------------------------------------------
# the benchmark
# ---------------------------------------------------------------------------
def run_benchmark(
    folder,
    *,
    seeds=(0, 1, 2),
    grid=None,
    config=None,
    degrees=range(1, 10),
    n_sweep=10,
    motors=MOTORS,
    pi=False,
    log=print,
):
    """Train on acquisition 1 of each motor and test on its acquisitions 2 and 3.

    Parameters
    ----------
    folder : path-like
        Data folder (see :func:`resolve_data_folder`).
    seeds : sequence of int, default=(0, 1, 2)
        Seeds of the learners; results are reported per seed.
    grid : dict or None
        Learner grid searched inside acquisition 1 (per motor and learner);
        None uses ``config`` (or :data:`DEFAULT_CONFIG`) without a search.
    config : dict or None
        Learner settings when ``grid`` is None.
    degrees : iterable of int
        Polynomial degrees tried inside acquisition 1.
    n_sweep : int, default=10
        Leading samples of every acquisition marked ``"sweep"``.
    motors : sequence of int
        Motors to run.
    pi : bool, default=False
        Also run :data:`PI_METHODS` (the GRU with the settings chosen for
        ``polynomial+GRU``), with the largest threshold
        :data:`PI_MAX_PLAY_SHARE` of half the motor's range in acquisition 1.
    log : callable
        Progress messages.

    Returns
    -------
    results : pandas.DataFrame
        One row per motor, test acquisition, method and seed: ``motor,
        test_acquisition, leaks_training, n_motion, method, seed`` (the
        polynomial has ``seed`` -1), ``start_offset_mm`` (distance of the
        test acquisition's first tip position from acquisition 1's),
        ``rmse_mm`` (motion rows), ``first_leg_rmse_mm`` and
        ``rest_rmse_mm`` (motion rows up to the largest ``q1`` and after),
        ``train_rmse_mm`` (acquisition 1) and ``fit_s`` (training time).
    selection : pandas.DataFrame
        Chosen degree and learner settings per motor and method, with their
        cross-validation RMSE inside acquisition 1.
    checks : pandas.DataFrame
        Per motor: the quaternion-order angles and which acquisitions are
        copies of acquisition 1.
    """
    results, selection, checks = [], [], []
    for motor in motors:
        data = load_motor(folder, motor, n_sweep=n_sweep)
        X1, y1 = data.X[1], data.y[1]
        folds = BlockKFold(**BLOCKS)
        degree, degree_table = select_degree(X1, y1, degrees, folds)
        log(f"motor{motor}: polynomial degree {degree} (blocked CV in acq1: "
            + ", ".join(f"{r.degree}:{r.cv_rmse_mm:.2f}" for r in degree_table.itertuples())
            + " mm)")
        selection.append({"motor": motor, "method": "polynomial", "degree": degree,
                          "settings": "", "cv_rmse_mm": float(degree_table["cv_rmse_mm"].min())})
        checks.append({
            "motor": motor,
            "angle_xyzw_deg": data.quaternion_angles["xyzw"],
            "angle_wxyz_deg": data.quaternion_angles["wxyz"],
            "copies_of_acq1": ",".join(f"acq{a}" for a, c in data.copy_of_training.items() if c),
        })
        configs = {}
        for method in METHODS[1:]:
            if grid is None:
                configs[method] = dict(config or DEFAULT_CONFIG)
                continue
            t0 = time.perf_counter()
            best, table = select_config(method, X1, y1, degree, grid, seed=seeds[0], folds=folds)
            configs[method] = best
            selection.append({"motor": motor, "method": method, "degree": degree,
                              "settings": _settings(best),
                              "cv_rmse_mm": float(table["cv_rmse_mm"].min())})
            log(f"motor{motor}: {method} chose {best} in {time.perf_counter() - t0:.0f} s\n"
                + table.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
        fitted = {}
        q1 = X1[MOTOR_COLUMNS[0]].to_numpy(dtype=np.float64)
        max_play = PI_MAX_PLAY_SHARE * 0.5 * float(np.ptp(q1))
        configs["polynomial+PI+GRU"] = configs.get("polynomial+GRU")
        for method in METHODS + (PI_METHODS if pi else ()):
            method_seeds = [-1] if method in ("polynomial", "polynomial+PI") else list(seeds)
            for seed in method_seeds:
                t0 = time.perf_counter()
                model = make_method(method, degree, configs.get(method), seed,
                                    max_play).fit(X1, y1)
                fit_s = time.perf_counter() - t0
                fitted[method, seed] = model
                for a in ACQUISITIONS[1:]:
                    X, y = data.X[a], data.y[a]
                    y_pred = model.predict(X)
                    first = first_leg(X)
                    results.append({
                        "motor": motor,
                        "test_acquisition": a,
                        "leaks_training": data.copy_of_training[a],
                        "n_motion": int((X["phase"] == "motion").sum()),
                        "method": method,
                        "seed": seed,
                        "start_offset_mm": float(np.linalg.norm(y[0] - y1[0])),
                        "rmse_mm": motion_rmse(y, y_pred, X),
                        "first_leg_rmse_mm": motion_rmse(y, y_pred, X, rows=first),
                        "rest_rmse_mm": motion_rmse(y, y_pred, X, rows=~first),
                        "train_rmse_mm": motion_rmse(y1, model.predict(X1), X1),
                        "fit_s": fit_s,
                    })
            log(f"motor{motor}: {method} done")
    return pd.DataFrame(results), pd.DataFrame(selection), pd.DataFrame(checks)


def summarize(results):
    """Mean over seeds per motor, test acquisition and method, with the ratio to the polynomial."""
    keys = ["motor", "test_acquisition", "leaks_training", "method"]
    table = (
        results.groupby(keys, sort=False)
        .agg(rmse_mm=("rmse_mm", "mean"), rmse_sd_mm=("rmse_mm", "std"),
             n_seeds=("seed", "size"), train_rmse_mm=("train_rmse_mm", "mean"),
             first_leg_rmse_mm=("first_leg_rmse_mm", "mean"),
             rest_rmse_mm=("rest_rmse_mm", "mean"),
             start_offset_mm=("start_offset_mm", "first"),
             fit_s=("fit_s", "mean"))
        .reset_index()
    )
    poly = table[table["method"] == "polynomial"]
    base = poly.set_index(["motor", "test_acquisition"])["rmse_mm"]
    idx = pd.MultiIndex.from_frame(table[["motor", "test_acquisition"]])
    table["ratio_to_polynomial"] = table["rmse_mm"].to_numpy() / base.reindex(idx).to_numpy()
    return table


def headline(summary):
    """Mean ratio to the polynomial per learned method over the tests that do not leak."""
    clean = summary[~summary["leaks_training"] & (summary["method"] != "polynomial")]
    return clean.groupby("method", sort=False)["ratio_to_polynomial"].mean()


def _markdown(table):
    cols = list(table.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in table.itertuples(index=False):
        cells = [f"{v:.2f}" if isinstance(v, float) else str(v) for v in row]
        cells = ["" if c == "nan" else c for c in cells]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", help=f"data folder (default ${ENV_VAR} or {DEFAULT_DATA})")
    parser.add_argument("--out", default=str(Path(tempfile.gettempdir()) / "skcath_tee_probe"),
                        help="folder for the CSV results (default: %(default)s)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--n-sweep", type=int, default=10,
                        help="leading samples marked 'sweep' (default: %(default)s)")
    parser.add_argument("--epochs", type=int, nargs="+", default=DEFAULT_GRID["max_epochs"],
                        help="values of max_epochs in the search (default: %(default)s)")
    parser.add_argument("--no-search", action="store_true",
                        help=f"skip the search inside acq1, use {DEFAULT_CONFIG}")
    parser.add_argument("--quick", action="store_true",
                        help="2 epochs, seed 0, no search (a smoke run)")
    parser.add_argument("--pi", action="store_true",
                        help="also the polynomial after a Prandtl-Ishlinskii hysteresis, "
                             "alone and with the GRU")
    args = parser.parse_args(argv)
    try:
        folder = resolve_data_folder(args.data)
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    grid, config, seeds = {**DEFAULT_GRID, "max_epochs": args.epochs}, None, args.seeds
    if args.no_search:
        grid = None
    if args.quick:
        grid, config, seeds = None, {**DEFAULT_CONFIG, "max_epochs": 2}, [0]

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _machine import machine_lines

    t0, cpu0 = time.perf_counter(), time.process_time()
    results, selection, checks = run_benchmark(folder, seeds=seeds, grid=grid, config=config,
                                               n_sweep=args.n_sweep, pi=args.pi)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    summary = summarize(results)
    print()
    for line in machine_lines():
        print(line)
    print(f"data: {folder}; total {elapsed:.0f} s wall, {cpu:.0f} s CPU")
    print("\nQuaternion-order check (angle between rotation axis and plane normal, deg):")
    print(_markdown(checks))
    print("\nSelection inside acquisition 1:")
    print(_markdown(selection))
    print("\nTest RMSE of the 3-D tip in the base frame (mm), mean over seeds:")
    shown = summary[["motor", "test_acquisition", "leaks_training", "method", "rmse_mm",
                     "rmse_sd_mm", "n_seeds", "train_rmse_mm", "ratio_to_polynomial", "fit_s"]]
    print(_markdown(shown))
    print("\nThe same errors on the first leg of the cycle (start to the motor's maximum) "
          "and on the rest, and the distance (mm) of the first tip position from that of "
          "acquisition 1 at the same motor position:")
    print(_markdown(summary[["motor", "test_acquisition", "method", "start_offset_mm",
                             "first_leg_rmse_mm", "rest_rmse_mm"]]))
    print("\nHeadline (mean ratio to the polynomial over the tests that are not copies of "
          "the training acquisition; goal <= 0.45):")
    for method, ratio in headline(summary).items():
        print(f"  {method}: {ratio:.3f}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results.to_csv(out / "tee_probe_runs.csv", index=False)
    summary.to_csv(out / "tee_probe_summary.csv", index=False)
    selection.to_csv(out / "tee_probe_selection.csv", index=False)
    checks.to_csv(out / "tee_probe_checks.csv", index=False)
    print(f"\nCSV written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
