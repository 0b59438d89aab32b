"""Training throughput and fold wall time of the residual learners (GRU, MLP).

Data: the training set of one fold of setting-held-out cross-validation on
the default benchmark (``make_benchmark()``, cached in the skcath data
folder): catheter C1, bent shaft settings (``setting != "S00"``), one setting
(S01, 3 runs) held out, i.e. 45 training runs. The backbone columns come from
``PDLBackbone(n_jobs=2).fit(X).transform(X)``.

Part 1, training throughput. ``fit`` of the estimator prepares its
training windows (200-step windows, features, loss mask, normalised
targets, sweep context input) and hands them to skorch's training loop; a
skorch callback (``on_train_begin`` / ``on_train_end``, the public hooks of
skorch) records the windows, the freshly initialised module and the time of
the loop. The same windows are trained on by

- ``skorch``: the estimator's own training loop, timed by the callback
  inside ``GRUResidual.fit`` (seeded torch runtime, default callbacks,
  shuffled ``DataLoader`` over skorch's ``Dataset``);
- ``plain``: a hand-written torch loop over a copy of the estimator's
  freshly initialised module (same class, same initial weights), the same
  optimizer (Adam, same ``lr``, and the same learning-rate
  schedule: cosine annealing over the epochs of the call, as the
  estimator's default ``lr_schedule="cosine"``), the same loss
  (``MaskedNormalizedMSE``) and batch size, and shuffled batches cut from a
  new random permutation of the windows every epoch (numpy fancy indexing of
  the whole-data arrays, then ``torch.from_numpy``; ``--dataloader`` adds a
  variant with ``torch.utils.data.DataLoader(TensorDataset(...),
  shuffle=True)``). This is the minimal loop a user would write; indexing
  the arrays in numpy rather than the tensors in torch keeps the batch
  gathering out of torch's intra-op thread pool, whose parallel regions cost
  milliseconds each on a loaded machine.

Only the training loop is timed (not the window preparation before it,
timed apart as "prep": ``fit`` up to the first epoch). Both variants run in
the same process, interleaved (A B, then B A, ...) ``--repeat`` times per
thread count, with ``torch.set_num_threads(n)`` for both; the ratio of throughputs skorch / plain (plain time over skorch
time) is computed per interleaved pair and its median is reported, from the
wall-clock time and from the process CPU time (``time.process_time``, all
threads), which is less disturbed when other processes share the machine.
Throughput counts the real (non-padding) steps of the training windows that
the network processes per epoch, burn-in steps included (they are computed,
only left out of the loss); the loss steps (masked in: no padding, no
tracker dropout, no burn-in) are given beside. To check that the comparison is fair, the table gives the last
epoch's mean batch loss of both variants and the loss of both trained
networks on all windows.

Part 2, one fold. ``Pipeline([("backbone", PDLBackbone(n_jobs=2)),
("residual", GRUResidual(random_state=0, n_threads=n))])`` (and the same
with ``MLPResidual``) with default parameters (``max_epochs=40`` unless
``--epochs`` is given): wall time of ``fit`` on the 45 training runs and of
``predict`` on the 3 held-out runs, the PDL calibration time of those runs
(measured apart, same work as inside the pipeline), the per-epoch time
(skorch's ``dur``) and the held-out per-run RMSE over motion rows.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_residuals.py            # both parts
    .venv/bin/python benchmarks/bench_residuals.py --quick    # 2 epochs everywhere
    .venv/bin/python benchmarks/bench_residuals.py --skip-throughput --device cuda  # part 2 on a GPU

On an idle 2-core machine the default run takes about 5 minutes and
``--quick`` about 1 minute; with other processes on the machine, the 2-thread
measurements can take ten times longer.

Tables are printed in Markdown.
"""

import argparse
import copy
import json
import os
import statistics
import sys
import time

import numpy as np
import skorch
import torch
from _machine import machine_lines, source_digest
from sklearn.pipeline import Pipeline
from skorch.callbacks import Callback

import skcath.residuals
from skcath import ID_COLUMNS
from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import per_run_rmse
from skcath.residuals import GRUResidual, MaskedNormalizedMSE, MLPResidual

MODELS = {"gru": GRUResidual, "mlp": MLPResidual}
SEED = 0
CATHETER, SETTING, RUN = ID_COLUMNS


# ---------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------
def _fold(catheter, holdout):
    """Training and held-out recordings of one setting-held-out fold (bent settings)."""
    data = make_benchmark()
    X, y = data.X, data.y
    bent = (X[CATHETER] == catheter).to_numpy() & (X[SETTING] != "S00").to_numpy()
    test = bent & (X[SETTING] == holdout).to_numpy()
    train = bent & ~test

    def take(rows):
        part = X.loc[rows].reset_index(drop=True)
        for c in part.columns:
            if hasattr(part[c], "cat"):
                part[c] = part[c].cat.remove_unused_categories()
        return part, y[rows]

    return take(train), take(test)


class TrainingClock(Callback):
    """skorch callback: the training loop's windows, initial module and time.

    ``on_train_begin`` receives the windows that ``fit`` prepared (inputs
    and targets) and the freshly initialised module; the wall-clock and
    process CPU time from there to ``on_train_end`` is the training loop's.
    """

    def on_train_begin(self, net, X=None, y=None, **kwargs):
        self.windows, self.target = X, y
        self.initial_module = copy.deepcopy(net.module_)
        self.begin = time.perf_counter(), time.process_time()

    def on_train_end(self, net, X=None, y=None, **kwargs):
        end = time.perf_counter(), time.process_time()
        self.seconds = end[0] - self.begin[0], end[1] - self.begin[1]


def _window_counts(Xb, est, data):
    """Runs, motion samples, windows and their real and loss steps per epoch.

    The windows of a run tile its motion sequence, the last one aligned to
    the run's end, so every window is ``window`` steps long except the one
    window of a run shorter than that, which holds the whole run.
    """
    motion = Xb[Xb["phase"] == "motion"]
    lengths = motion.groupby(RUN, observed=True).size().to_numpy()
    short = lengths[(lengths > 0) & (lengths < est.window)]
    n_windows = len(data["features"])
    return {
        "runs": int(len(lengths)),
        "motion_samples": int(lengths.sum()),
        "window": int(est.window),
        "windows": int(n_windows),
        "window_steps": int(n_windows * est.window - (est.window - short).sum()),
        "loss_steps": int(data["mask"].sum()),
    }


def _windows(cls, Xb, y):
    """The windows ``fit`` trains on, the initial module, the counts, and the prep time."""
    clock = TrainingClock()
    est = cls(random_state=SEED, max_epochs=0, callbacks=[("clock", clock)])
    for _ in range(2):  # the second call, without the first call's one-time costs, is timed
        start = time.perf_counter()
        est.fit(Xb, y)  # no epoch: prepares the windows and initialises the module
    prep_s = clock.begin[0] - start
    return clock.windows, clock.target, clock.initial_module, _window_counts(Xb, est, clock.windows), prep_s


# ---------------------------------------------------------------------------
# the two training loops
# ---------------------------------------------------------------------------
def _run_skorch(cls, Xb, y, threads, epochs, module0):
    """The estimator's own training loop, timed inside ``fit`` by the callback."""
    clock = TrainingClock()
    est = cls(random_state=SEED, max_epochs=epochs, n_threads=threads, callbacks=[("clock", clock)])
    est.fit(Xb, y)
    for key, value in clock.initial_module.state_dict().items():
        if not torch.equal(value, module0.state_dict()[key]):
            raise RuntimeError(f"initial weights differ from the plain loop's ({key})")
    losses = [float(v) for v in est.history_[:, "train_loss"]]
    return clock.seconds, losses, est.module_


class _Clock:
    """Wall-clock and process CPU time (all threads) since creation."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def stop(self):
        return time.perf_counter() - self.wall, time.process_time() - self.cpu


def _tensors(data, target):
    keys = ["features", "mask"] + [k for k in ("sweep", "sweep_length") if k in data]
    out = {k: torch.from_numpy(np.ascontiguousarray(data[k])) for k in keys}
    out["target"] = torch.from_numpy(target)
    return out


def _run_plain(est, tensors, threads, module0, epochs, dataloader=False):
    """Minimal hand-written torch loop: same module, initial weights, Adam lr, loss, batches."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        module = copy.deepcopy(module0)
        optimizer = torch.optim.Adam(module.parameters(), lr=est.lr)
        scheduler = None
        if est.lr_schedule == "cosine":  # the estimator's LRScheduler
            scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=max(epochs, 1))
        criterion = MaskedNormalizedMSE()
        context = "sweep" in tensors
        n = len(tensors["features"])
        bs = est.batch_size
        rng = np.random.default_rng(SEED)
        arrays = {k: v.numpy() for k, v in tensors.items()}
        if dataloader:
            generator = torch.Generator().manual_seed(SEED)
            names = ["features", "mask", "target"] + (["sweep", "sweep_length"] if context else [])
            loader = torch.utils.data.DataLoader(
                torch.utils.data.TensorDataset(*(tensors[k] for k in names)),
                batch_size=bs, shuffle=True, generator=generator,
            )
        losses = []
        clock = _Clock()
        module.train()
        for _ in range(epochs):
            total = 0.0
            if dataloader:
                batches = (dict(zip(names, b)) for b in loader)
            else:
                perm = rng.permutation(n)
                batches = ({k: torch.from_numpy(v[idx]) for k, v in arrays.items()}
                           for idx in (perm[i:i + bs] for i in range(0, n, bs)))
            for b in batches:
                if context:
                    pred = module(b["features"], b["sweep"], b["sweep_length"])
                else:
                    pred = module(b["features"])
                loss = criterion(pred, b["target"], b["mask"])
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                total += loss.item() * len(b["features"])
            losses.append(total / n)
            if scheduler is not None:
                scheduler.step()
        seconds = clock.stop()
    finally:
        torch.set_num_threads(previous)
    return seconds, losses, module


def _full_loss(module, tensors):
    """Masked normalised loss of a trained module on all windows (no gradient)."""
    module.eval()
    with torch.no_grad():
        if "sweep" in tensors:
            pred = module(tensors["features"], tensors["sweep"], tensors["sweep_length"])
        else:
            pred = module(tensors["features"])
        loss = MaskedNormalizedMSE()(pred, tensors["target"], tensors["mask"])
    module.train()
    return float(loss)


def throughput(Xb, y, models, threads, epochs, repeat, dataloader):
    rows = []
    for name in models:
        cls = MODELS[name]
        data, target, module0, counts, prep_s = _windows(cls, Xb, y)
        tensors = _tensors(data, target)
        est = cls(random_state=SEED)  # the settings the plain loop copies (lr, batch, schedule)
        variants = ["skorch", "plain"] + (["plain DataLoader"] if dataloader else [])
        for n in threads:
            times = {v: [] for v in variants}
            result = {}
            for r in range(repeat):
                order = variants if r % 2 == 0 else variants[::-1]
                for v in order:
                    if v == "skorch":
                        s, losses, module = _run_skorch(cls, Xb, y, n, epochs, module0)
                    else:
                        s, losses, module = _run_plain(est, tensors, n, module0, epochs,
                                                       dataloader=v != "plain")
                    times[v].append(s)
                    result[v] = (losses, module)
                print(f"  {cls.__name__} threads={n} repeat {r + 1}/{repeat}: "
                      + ", ".join(f"{v} {times[v][-1][0]:.2f} s (CPU {times[v][-1][1]:.2f} s)"
                                  for v in variants),
                      file=sys.stderr, flush=True)
            for v in variants:
                losses, module = result[v]
                rows.append({
                    "model": cls.__name__, "threads": n, "variant": v, "epochs": epochs,
                    **counts, "prep_s": prep_s,
                    "seconds": [t[0] for t in times[v]], "cpu_seconds": [t[1] for t in times[v]],
                    "epoch_s": statistics.median(t[0] for t in times[v]) / epochs,
                    "cpu_epoch_s": statistics.median(t[1] for t in times[v]) / epochs,
                    "steps_per_s": counts["window_steps"] * epochs
                    / statistics.median(t[0] for t in times[v]),
                    "ratio_pairs": [p[0] / t[0] for t, p in zip(times[v], times["plain"])],
                    "cpu_ratio_pairs": [p[1] / t[1] for t, p in zip(times[v], times["plain"])],
                    "last_epoch_loss": losses[-1], "full_loss": _full_loss(module, tensors),
                })
    return rows


def _ratio(row, key):
    if row["variant"] == "plain":
        return "1"
    pairs = row[key]
    return f"{statistics.median(pairs):.2f} ({min(pairs):.2f}-{max(pairs):.2f})"


def _throughput_table(rows):
    head = ("| model | threads | loop | s / epoch | CPU s / epoch | window steps / s "
            "| throughput / plain, wall: median (min-max) | throughput / plain, CPU: median (min-max) "
            "| last-epoch mean batch loss | loss on all windows after training |")
    lines = [head, "|" + "|".join(["---"] * 3 + ["---:"] * 7) + "|"]
    for r in rows:
        lines.append(
            f"| {r['model']} | {r['threads']} | {r['variant']} | {r['epoch_s']:.2f} "
            f"| {r['cpu_epoch_s']:.2f} | {r['steps_per_s']:,.0f} | {_ratio(r, 'ratio_pairs')} "
            f"| {_ratio(r, 'cpu_ratio_pairs')} | {r['last_epoch_loss']:.4f} | {r['full_loss']:.4f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# one fold
# ---------------------------------------------------------------------------
def backbone_times(train, test, repeat):
    (X_tr, _), (X_te, y_te) = train, test
    fit_s, test_s = [], []
    for _ in range(repeat):
        start = time.perf_counter()
        bb = PDLBackbone(n_jobs=2).fit(X_tr)
        bb.transform(X_tr)
        fit_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        b_te = bb.predict(X_te)
        test_s.append(time.perf_counter() - start)
    rmse = per_run_rmse(y_te, b_te, X_te)
    return statistics.median(fit_s), statistics.median(test_s), rmse


def fold(train, test, models, threads, epochs, repeat, device="cpu"):
    (X_tr, y_tr), (X_te, y_te) = train, test
    rows = []
    for r in range(repeat):
        for name in models:
            for n in threads:
                params = {"random_state": SEED, "n_threads": n, "device": device}
                if epochs is not None:
                    params["max_epochs"] = epochs
                pipe = Pipeline([("backbone", PDLBackbone(n_jobs=2)),
                                 ("residual", MODELS[name](**params))])
                start = time.perf_counter()
                pipe.fit(X_tr, y_tr)
                fit_s = time.perf_counter() - start
                start = time.perf_counter()
                pred = pipe.predict(X_te)
                predict_s = time.perf_counter() - start
                res = pipe.named_steps["residual"]
                dur = [float(d) for d in res.history_[:, "dur"]]
                rmse = per_run_rmse(y_te, pred, X_te)
                rows.append({
                    "model": MODELS[name].__name__, "threads": n, "repeat": r, "device": device,
                    "epochs": len(dur), "fit_s": fit_s, "predict_s": predict_s,
                    "epoch_s": statistics.median(dur), "epochs_s": sum(dur),
                    "rmse": {str(k): float(v) for k, v in rmse.items()},
                })
                print(f"  {MODELS[name].__name__} threads={n}: fit {fit_s:.1f} s, "
                      f"predict {predict_s:.2f} s, RMSE {rmse.mean():.2f} mm",
                      file=sys.stderr, flush=True)
    return rows


def _fold_table(rows, bb_fit_s):
    head = ("| model | threads | epochs | fit s (45 runs) | of which PDL s | of which epochs s "
            "| s / epoch (median) | predict s (3 runs) | fold s | held-out RMSE per run mm | mean mm |")
    lines = [head, "|" + "|".join(["---"] * 2 + ["---:"] * 9) + "|"]
    for r in rows:
        per_run = ", ".join(f"{v:.2f}" for v in r["rmse"].values())
        lines.append(
            f"| {r['model']} | {r['threads']} | {r['epochs']} | {r['fit_s']:.1f} "
            f"| {bb_fit_s:.1f} | {r['epochs_s']:.1f} | {r['epoch_s']:.2f} "
            f"| {r['predict_s']:.2f} | {r['fit_s'] + r['predict_s']:.1f} | {per_run} "
            f"| {np.mean(list(r['rmse'].values())):.2f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------
def _machine():
    lines = machine_lines()
    lines.append(f"torch {torch.__version__} (default intra-op threads {torch.get_num_threads()}), "
                 f"skorch {skorch.__version__}; sha1 of skcath/residuals/*.py "
                 f"{source_digest(skcath.residuals)}")
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", choices=sorted(MODELS), default=["gru", "mlp"],
                        help="residual learners to measure (default: gru mlp)")
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2],
                        help="torch intra-op thread counts (default: 1 2)")
    parser.add_argument("--throughput-epochs", type=int, default=3,
                        help="epochs per timed training in part 1 (default: 3)")
    parser.add_argument("--repeat", type=int, default=5,
                        help="interleaved skorch / plain pairs per model and thread count (default: 5)")
    parser.add_argument("--epochs", type=int, default=None,
                        help="max_epochs of the fold in part 2 (default: the estimators' default, 40)")
    parser.add_argument("--fold-repeat", type=int, default=1,
                        help="timed folds per model and thread count (default: 1)")
    parser.add_argument("--quick", action="store_true",
                        help="2 epochs in both parts, 3 pairs: a check of the script, per-epoch times")
    parser.add_argument("--dataloader", action="store_true",
                        help="also time the plain loop with a torch DataLoader over a TensorDataset")
    parser.add_argument("--skip-throughput", action="store_true", help="skip part 1")
    parser.add_argument("--skip-fold", action="store_true", help="skip part 2")
    parser.add_argument("--device", default="cpu",
                        help="torch device of the learners in part 2, e.g. cuda (default: cpu)")
    parser.add_argument("--catheter", default="C1", help="catheter (default: C1)")
    parser.add_argument("--holdout", default="S01", help="held-out shaft setting (default: S01)")
    parser.add_argument("--json", metavar="PATH", help="also write the raw results to this JSON file")
    args = parser.parse_args(argv)
    if args.quick:
        args.throughput_epochs, args.epochs, args.repeat = 2, 2, 3
    if min(args.repeat, args.fold_repeat, args.throughput_epochs, *args.threads) < 1:
        parser.error("--repeat, --fold-repeat, --throughput-epochs and --threads must be >= 1")
    if args.holdout == "S00":
        parser.error("--holdout must be a bent setting (S01-S16)")

    print("loading the benchmark ...", file=sys.stderr, flush=True)
    train, test = _fold(args.catheter, args.holdout)
    n_train = train[0][RUN].nunique()
    n_test = test[0][RUN].nunique()
    load_before = os.getloadavg()[0]
    wall = time.perf_counter()

    print("PDL calibration ...", file=sys.stderr, flush=True)
    start = time.perf_counter()
    Xb = PDLBackbone(n_jobs=2).fit(train[0]).transform(train[0])
    first_bb_s = time.perf_counter() - start

    tp_rows, fold_rows = [], []
    if not args.skip_throughput:
        print("part 1: training throughput ...", file=sys.stderr, flush=True)
        tp_rows = throughput(Xb, train[1], args.models, args.threads, args.throughput_epochs,
                             args.repeat, args.dataloader)
    if not args.skip_fold:
        print("part 2: one fold ...", file=sys.stderr, flush=True)
        bb_fit_s, bb_test_s, bb_rmse = backbone_times(train, test, 3)
        fold_rows = fold(train, test, args.models, args.threads, args.epochs, args.fold_repeat,
                         args.device)
    load_after = os.getloadavg()[0]
    wall = time.perf_counter() - wall

    print("\n".join(_machine()))
    print(f"1-minute load average: {load_before:.2f} before, {load_after:.2f} after "
          f"(the benchmark itself adds 1-2); measured in {wall:.0f} s")
    print(f"data: make_benchmark(), catheter {args.catheter}, bent settings, {args.holdout} held out: "
          f"{n_train} training runs ({len(train[0]):,} rows), {n_test} held-out runs; "
          f"PDLBackbone(n_jobs=2) fit + transform of the training runs {first_bb_s:.1f} s")
    if tp_rows:
        c = {r["model"]: r for r in tp_rows}
        print(f"\n### Training throughput ({args.throughput_epochs} epochs per timed training, "
              f"median of {args.repeat} interleaved pairs)\n")
        for model, r in c.items():
            print(f"- {model}: {r['windows']} windows of {r['window']} steps per epoch, "
                  f"{r['window_steps']:,} real window steps (burn-in included; "
                  f"{r['motion_samples']:,} motion samples in {r['runs']} runs), "
                  f"{r['loss_steps']:,} loss steps; window preparation {r['prep_s']:.2f} s")
        print()
        print(_throughput_table(tp_rows))
    if fold_rows:
        print(f"\n### One fold (fit on {n_train} runs, predict {n_test} held-out runs, "
              f"device {args.device})\n")
        print(f"PDL calibration (median of 3): fit + transform of the {n_train} training runs "
              f"{bb_fit_s:.2f} s, predict of the {n_test} held-out runs {bb_test_s:.2f} s; "
              f"PDL alone, held-out RMSE per run "
              + ", ".join(f"{v:.2f}" for v in bb_rmse.to_numpy())
              + f" mm (mean {bb_rmse.mean():.2f})\n")
        print(_fold_table(fold_rows, bb_fit_s))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": _machine(), "args": vars(args),
                       "loadavg": [load_before, load_after],
                       "throughput": tp_rows, "fold": fold_rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
