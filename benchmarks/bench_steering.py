"""The controllers of skcath.control in closed loop on the simulated rig, per hysteresis mechanism.

The model: the estimator the evaluation protocol gives for a unit it never
saw, its sweep-adapted catheter-held-out method (``PDL+GRU+adapt (LOCO)``
of :data:`skcath.protocol.METHODS`): PDL with the play identified on each
run's sweep (:data:`skcath.protocol.ADAPTED_BACKBONE`) and the GRU residual
of :func:`skcath.protocol.make_learner`, pretrained with the schedule's
``model_params`` and ``pretrain_params`` (``--schedule quick``, the
default, or ``full``; the schedule's first seed) on every run of every
setting of the other units of ``make_benchmark(mechanism=...,
random_state=seed)`` (C1-C4, the ``reproduce`` job's data at ``--seed 0``;
the steered unit ``--catheter`` left out; ``--train-runs K``: the first K
repeats of each setting only). The
fitted pipeline is saved with :func:`skcath.persist.save` under ``--cache``
(default: the skcath data folder's ``steering`` folder) and loaded on the
next run. ``--residual none`` takes ``NoResidual`` instead of the GRU (the
backbone with the play alone). Beside it the script prints the model's own
error on the held-out unit's benchmark runs of each steered setting (RMS
over the motion rows against the noise-free tip, mean over the runs): the
floor a loop on the estimate cannot beat.

The closed loop runs on the held-out unit (``SimulatedCatheter(catheter=3,
...)``, ``--catheter``) in settings S05 and S12 (``--quick``: the play,
S05), tracker on (only the tracker-closed controller reads it). Tasks
(:func:`skcath.datasets.run_task` on the rig's sweep): reach and hold six
targets for 5 s each, a circle at 2 and at 10 mm/s, a figure-eight at
5 mm/s.

Scores, every error over the same samples: RMS and 95th percentile of the
true tip error (mm; :func:`skcath.datasets.task_scores` for the whole task),
the median settling time of the reach targets (s; below 2 mm until the next
target, inf when never held), ``est.``: the RMS error of the streamed
estimate of each record against its true tip on the same samples of the
same run (the estimator's own error on the motion the controller made; the
record of a sample reaches the controller two samples after its command),
and ``tracker``: the RMS of the tracker's measured tip against the true tip
there. The reach task is also scored in two phases: ``transit``, the first
``--transit-s`` seconds after each new target (the rate-limited move), and
``hold``, the rest.

Controllers:

- ``sweep lookup``: the motor angles of the sweep sample whose tracked tip
  is nearest the target (no model, no hysteresis compensation);
- ``PCC inverse, open loop`` / ``PDL inverse, open loop``:
  ``FeedforwardController`` of a pipeline of the backbone alone (no play, no
  residual), calibrated on the run's sweep;
- ``skcath feedforward``: ``FeedforwardController`` of the model;
- ``skcath closed loop (estimate)``: ``FeedbackController(close_on="estimate")``;
- ``closed on the tracker``: ``FeedbackController(close_on="tracker")``,
  the bound that a tracker in the loop gives;
- ``skcath feedforward, preview``, ``skcath closed loop (estimate), preview``
  and ``closed on the tracker, preview``: the same with ``preview=10``
  (1 s at 10 Hz), given the task's next targets by
  ``run_task(..., preview=10)`` (of a reach task, the present target's
  only: its successor is not known before it starts);
- with ``--diagnose``, ``closed on the tracker, no rate limit``; the
  script then also prints, for the feedback loops, their error split into
  the model's error that the correction does not cancel and the solve's
  miss of the wanted tip, with the model's error itself and its change over
  the loop's delay (see ``feedback_terms``);
- only when named in ``--controllers`` (they take about a hundred times a
  controller's time), two bounds that read the rig's own state instead of
  measuring it: ``true-rig inverse``, the
  noise-free inverse of the true rig with a look-ahead of 5 samples and no
  rate limit, whose command speeds are those each task asks of the motors,
  and ``true-rig inverse, rate limit``, the same at 60 deg/s with a
  look-ahead of 15 samples, a greedy search whose error on a reach task's
  transit is about the least the rate limit allows (on a fast curved path
  a controller may do better; see ``RigInverse``).

After the tables the script prints what each controller asked of the
motors (``print_feasibility``): the motor speed of its commands (median,
95th percentile, largest; deg/s), the share of samples at the rate limit,
the number of its commands' reversals and the rig's play there (the motor
travel after a reversal before the rig's unit play element moves again),
and the model's play (twice its half-width identified on the sweep).

All run with ``latency=1`` (the rig's timing) and, except the lookup and
the last one, a rate limit of 60 deg/s. The time of one controller step is
timed with ``time.perf_counter`` around ``step`` inside the runs, next to the
time of the estimator's own step on the same observations (a fresh
``OnlineEstimator`` of the same pipeline stepping the recorded samples), on
the same engine.

``--timing N`` instead times N steps (CPU time, ``time.process_time``) of
each controller and of the estimator alone on the same samples, on the
numba engine and the fast path (observations as tuples), for a pipeline of
PDL with the play and ``NoResidual`` (see ``time_steps``); then the
feedback on the numpy engine, and with ``preview=10`` (the next 10 targets
given) on the numba engine (the preview inside the compiled step) and on
the numpy engine, each also as a ratio to the feedback's compiled step.
``--rig-timing N`` times the rig itself first: ``SimulatedCatheter.reset``
and N ``step`` calls with the tracker off and on (wall and CPU time).

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_steering.py [--quick]
[--mechanisms ...] [--settings ...] [--residual {none,gru}] [--schedule
{quick,full}] [--cache DIR] [--controllers NAME ...] [--tasks NAME ...]
[--diagnose] [--rig-timing N] [--timing N]``.
"""

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from sklearn.pipeline import Pipeline

from skcath import persist
from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.control import FeedbackController, FeedforwardController, UnreachableTargetWarning
from skcath.datasets import (
    SimulatedCatheter,
    circle_task,
    figure_eight_task,
    get_data_home,
    make_benchmark,
    reach_task,
    run_task,
    task_scores,
)
from skcath.metrics import per_run_rmse
from skcath.online import OnlineEstimator
from skcath.protocol import ADAPTED_BACKBONE, ADAPTED_METHOD, LEARNER_COLUMNS, get_schedule, make_learner
from skcath.residuals import NoResidual

RATE_LIMIT = 60.0  # deg/s
#: Samples of path preview of the controllers named ``..., preview`` (``run_task(..., preview=PREVIEW)``).
PREVIEW = 10
#: The suffix of the names of the controllers given the task's next targets.
PREVIEW_SUFFIX = ", preview"
#: The controller that ``--diagnose`` adds.
DIAGNOSTIC = "closed on the tracker, no rate limit"
#: Bounds run only when named in ``--controllers``: the true rig's inverse (``RigInverse``), without and with the rate limit.
ORACLES = ("true-rig inverse", "true-rig inverse, rate limit")
#: Samples between a command and the record of the sample it moved (the rig's timing).
RECORD_DELAY = 2


def _cache_file(cache, bench_seed, mechanism, residual, schedule, catheter, train_runs):
    """The model's file: named by everything its training depends on (the benchmark's seed when not 0)."""
    name = f"steering-{mechanism}-{residual}-{schedule.name if residual == 'gru' else 'none'}-C{catheter}"
    runs = "" if train_runs is None else f"-R{train_runs}"
    bench = "" if bench_seed == 0 else f"-benchmark{bench_seed}"
    return Path(cache) / f"{name}{runs}{bench}-seed{schedule.seeds[0]}.skcath"


def protocol_pipeline(bench, mechanism, catheter, residual, schedule, cache, train_runs=None, bench_seed=0):
    """The protocol's estimator for held-out unit ``catheter``, loaded from ``cache`` or trained there.

    Trained on every run of the benchmark's other units (``train_runs``: on
    their first that many repeats of each setting only; ``bench_seed``: the
    seed ``bench`` was made with); returns the fitted pipeline and the
    seconds its training (or loading) took.
    """
    path = _cache_file(cache, bench_seed, mechanism, residual, schedule, catheter, train_runs)
    start = time.perf_counter()
    if path.exists():
        return persist.load(path), time.perf_counter() - start
    train = (bench.X["catheter"] != f"C{catheter}").to_numpy()
    if train_runs is not None:
        repeat = bench.runs.set_index("run")["repeat"]
        train = train & (bench.X["run"].map(repeat).astype(int) <= train_runs).to_numpy()
    X, y = bench.X[train], np.asarray(bench.y)[train]
    backbone = PDLBackbone(**ADAPTED_BACKBONE).fit(X)
    X_learner = backbone.transform(X)[list(LEARNER_COLUMNS)]
    if residual == "gru":
        learner = make_learner(ADAPTED_METHOD, random_state=schedule.seeds[0], n_threads=1,
                               **schedule.model_params, **schedule.pretrain_params)
    else:
        learner = NoResidual()
    pipe = Pipeline([("backbone", backbone), ("residual", learner.fit(X_learner, y))])
    path.parent.mkdir(parents=True, exist_ok=True)
    persist.save(pipe, path)
    return pipe, time.perf_counter() - start


def estimator_floor(pipe, bench, catheter, setting):
    """RMS (mm) of the model on the held-out unit's benchmark runs of ``setting``, against the true tip.

    Over the motion rows of each run, then the mean over the runs.
    """
    rows = ((bench.X["catheter"] == f"C{catheter}") & (bench.X["setting"] == setting)).to_numpy()
    if not rows.any():  # a unit the benchmark does not hold
        return np.nan
    X = bench.X[rows]
    return float(np.mean(per_run_rmse(np.asarray(bench.y_true)[rows], pipe.predict(X), X)))


class SweepFitted:
    """A feedforward inverse of a backbone alone, fitted on the run's own sweep at ``start``."""

    def __init__(self, Backbone, **params):
        self.Backbone, self.params = Backbone, params

    def start(self, sweep):
        backbone = self.Backbone().fit(sweep)
        self.controller = FeedforwardController(Pipeline([("backbone", backbone)]), **self.params)
        self.controller.start(sweep)
        return self

    def step(self, target, obs):
        command = self.controller.step(target, obs)
        self.estimate_ = self.controller.estimate_
        return command


class SweepLookup:
    """Naive open-loop baseline: the motor angles of the sweep sample whose tracked tip is nearest the target."""

    def start(self, sweep):
        tracked = sweep[["ref_x", "ref_y", "ref_z"]].notna().all(axis=1).to_numpy()
        motors = [c for c in sweep.columns if c.startswith("q") and c[1:].isdigit()]
        self.tips_ = sweep[["ref_x", "ref_y", "ref_z"]].to_numpy(dtype=float)[tracked]
        self.q_ = sweep[motors].to_numpy(dtype=float)[tracked]
        return self

    def step(self, target, obs):
        return self.q_[np.argmin(np.linalg.norm(self.tips_ - target, axis=1))]


class RigInverse:
    """The noise-free inverse of the true rig with a look-ahead: what a path asks of the motors.

    At every sample it reads the rig's state and the task's next
    ``horizon`` targets (5 without ``rate_limit``, 15 with it; of a reach
    task, up to the current target's last sample only: the next target is
    not known before it starts), and picks the end point of a move of the
    motors (within the rig's motor range) whose true tips over those samples are
    nearest the targets (RMS), the move going straight to the end point,
    at most ``rate_limit * dt`` per sample on every motor with
    ``rate_limit`` (scaled as a whole, as the controllers' limit), at once
    without; it commands the move's first sample. The end point is found on
    nested grids (25 points a side over the reachable box, then three finer
    grids of 9 about the best point); among end points about as good, the
    nearest (1e-3 mm per degree). It knows the rig exactly, so no
    controller that measures the rig does much better: without
    ``rate_limit`` its motor speeds are those the path asks for; with it,
    its error on a straight move (a reach task's transit) is about the
    least that the rate limit allows. The search is greedy (one straight
    move per look-ahead), so on a fast curved path a controller may do
    better.
    """

    def __init__(self, rig, task, rate_limit=None, horizon=None):
        self.rig, self.targets, self.rate_limit = rig, task.target, rate_limit
        bounds = [*task.changes[1:], len(task.target)] if task.changes else [len(task.target)]
        starts = [*task.changes] if task.changes else [0]
        self.last = np.concatenate([np.full(b - a, b - 1) for a, b in zip(starts, bounds)])
        self.horizon = horizon or (5 if rate_limit is None else 15)

    def start(self, sweep):
        motors = [c for c in sweep.columns if c.startswith("q") and c[1:].isdigit()]
        self.previous = sweep[motors].to_numpy(dtype=float)[-1]
        self.dt = float(np.median(np.diff(sweep["t"].to_numpy(dtype=float))))
        self.i = 0
        return self

    def _paths(self, ends):
        """The commands (horizon, n, n_motors) of the moves from the previous command to ``ends``."""
        move = ends - self.previous
        if self.rate_limit is None:
            return np.repeat((self.previous + move)[None], self.horizon, axis=0)
        largest = np.maximum(np.abs(move).max(axis=1, keepdims=True), 1e-12)
        j = np.arange(1, self.horizon + 1)[:, None, None]
        return self.previous + move * np.minimum(1.0, j * self.rate_limit * self.dt / largest)

    def _best(self, wanted, low, high, n):
        axes = [np.linspace(a, b, n) for a, b in zip(low, high)]
        ends = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(low))
        miss = np.linalg.norm(self.rig.tips_ahead(self._paths(ends)) - wanted[:, None], axis=2)
        cost = np.sqrt(np.mean(miss**2, axis=0)) + 1e-3 * np.abs(ends - self.previous).max(axis=1)
        return ends[np.argmin(cost)], (high - low) / (n - 1)

    def step(self, target, obs):
        limit = float(self.rig.motor_limit_deg)
        ahead = self.targets[np.minimum(self.i + np.arange(self.horizon), self.last[self.i])]
        half = limit if self.rate_limit is None else self.horizon * self.rate_limit * self.dt
        low = np.maximum(self.previous - half, -limit)
        high = np.minimum(self.previous + half, limit)
        best, spacing = self._best(ahead, low, high, 25)
        for _ in range(3):
            best, spacing = self._best(ahead, np.maximum(best - spacing, low),
                                       np.minimum(best + spacing, high), 9)
        self.previous = self._paths(best[None])[0, 0]
        self.i += 1
        return self.previous


class Timed:
    """A controller whose ``step`` is timed; it keeps the observations it was given."""

    def __init__(self, controller):
        self.controller, self.seconds, self.observations = controller, [], []
        self.aimed, self.corrections = [], []

    def start(self, sweep):
        self.controller.start(sweep)
        self.sweep = sweep
        return self

    def step(self, target, obs, upcoming=None):
        t0 = time.perf_counter()
        if upcoming is None:
            command = self.controller.step(target, obs)
        else:
            command = self.controller.step(target, obs, upcoming=upcoming)
        self.seconds.append(time.perf_counter() - t0)
        self.observations.append(obs)
        self.estimate_ = getattr(self.controller, "estimate_", None)
        self.aimed.append(getattr(self.controller, "aimed_", None))
        self.corrections.append(getattr(self.controller, "correction_", None))
        return command


def registry(pipe, diagnose=False):
    """Controller factories: name -> factory() of an unstarted controller."""
    common = {"rate_limit": RATE_LIMIT, "latency": 1}
    out = {
        "sweep lookup": SweepLookup,
        "PCC inverse, open loop": lambda: SweepFitted(PCCBackbone, **common),
        "PDL inverse, open loop": lambda: SweepFitted(PDLBackbone, **common),
        "skcath feedforward": lambda: FeedforwardController(pipe, **common),
        "skcath closed loop (estimate)": lambda: FeedbackController(pipe, **common),
        "closed on the tracker": lambda: FeedbackController(pipe, close_on="tracker", **common),
        "skcath feedforward" + PREVIEW_SUFFIX: lambda: FeedforwardController(pipe, preview=PREVIEW, **common),
        "skcath closed loop (estimate)" + PREVIEW_SUFFIX: lambda: FeedbackController(
            pipe, preview=PREVIEW, **common),
        "closed on the tracker" + PREVIEW_SUFFIX: lambda: FeedbackController(
            pipe, close_on="tracker", preview=PREVIEW, **common),
    }
    if diagnose:
        out[DIAGNOSTIC] = lambda: FeedbackController(
            pipe, close_on="tracker", latency=1)
    return out


def tasks_of(sweep, seed):
    return [
        ("reach", reach_task(sweep, random_state=seed)),
        ("circle 2 mm/s", circle_task(sweep, speed_mm_s=2.0, n_laps=1)),
        ("circle 10 mm/s", circle_task(sweep, speed_mm_s=10.0)),
        ("figure-eight 5 mm/s", figure_eight_task(sweep, speed_mm_s=5.0)),
    ]


def phases(task, transit_s):
    """The samples each score reads: name -> mask over the task's samples.

    Every view keeps only the scored samples whose record reached the
    controller (all but the last ``RECORD_DELAY``), so that the controller's
    error and the estimator's are over the same samples. A reach task also
    gets ``transit`` (the first ``transit_s`` seconds of each target) and
    ``hold`` (the rest).
    """
    n = len(task.target)
    seen = np.asarray(task.scored, dtype=bool) & (np.arange(n) < n - RECORD_DELAY)
    out = {"": seen}
    if task.changes:
        transit = np.zeros(n, dtype=bool)
        for first in task.changes:
            transit[first:first + int(round(transit_s * task.rate_hz))] = True
        out[" transit"], out[" hold"] = seen & transit, seen & ~transit
    return out


def _rms(values):
    """RMS of the finite values (NaN if none)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else np.nan


def run_errors(result, observations):
    """Per sample: the true tip's error, the estimate's error and the tracker's error (mm), NaN where unseen.

    Sample ``i``'s record is the observation given with command ``i + RECORD_DELAY``.
    """
    n, d = len(result.error), RECORD_DELAY
    est, tracker = np.full(n, np.nan), np.full(n, np.nan)
    if result.estimate is not None:
        est[:-d] = np.linalg.norm(result.estimate[d:] - result.tip[:-d], axis=1)
    seen = np.full(n, np.nan)
    measured = np.array([[o.get(c, np.nan) for c in "xyz"] for o in observations[d:]], dtype=float)
    tracker[:-d] = np.linalg.norm(measured - result.tip[:-d], axis=1)
    seen[:-d] = np.linalg.norm(measured - result.target[:-d], axis=1)
    return {"true": np.asarray(result.error, dtype=float), "est": est, "tracker": tracker, "seen": seen}


def score_run(result, observations, transit_s):
    """One dict of scores per view of the task (see ``phases``), every error over the view's samples."""
    errors = run_errors(result, observations)
    settling = task_scores(result)["settling_s"]
    out = []
    for view, mask in phases(result.task, transit_s).items():
        true = errors["true"][mask]
        out.append({
            "view": view, "rms": _rms(true), "p95": float(np.percentile(true, 95)),
            "settle": settling if view == "" else np.nan,
            **{key: _rms(errors[key][mask]) for key in ("est", "tracker", "seen")},
        })
    return out


def feedback_terms(result, timed):
    """The true tip's error of an internal-model loop split in two, per sample (mm), or None.

    With ``a`` the model's tip aimed at (``aimed_``), ``c`` the correction
    (``correction_``) and ``w = target - c`` the wanted tip, the error
    ``tip - target`` is ``(tip - a - c) + (a - w)``: the model's error at the
    commanded tip that the correction does not cancel, and the solve's miss
    of the wanted tip (a wanted tip off the model's reachable surface).
    Also the model's error ``tip - a`` itself and its change over the
    loop's delay (``RECORD_DELAY`` samples), which a correction measured that
    late cannot follow.
    """
    if any(c is None for c in timed.corrections) or any(a is None for a in timed.aimed):
        return None
    aimed, corr = np.array(timed.aimed, dtype=float), np.array(timed.corrections, dtype=float)
    model_error = result.tip - aimed
    change = np.full(len(aimed), np.nan)
    change[RECORD_DELAY:] = np.linalg.norm(model_error[RECORD_DELAY:] - model_error[:-RECORD_DELAY], axis=1)
    return {
        "uncorrected": np.linalg.norm(model_error - corr, axis=1),
        "solve miss": np.linalg.norm(aimed - (result.target - corr), axis=1),
        "model error": np.linalg.norm(model_error, axis=1),
        "change over delay": change,
    }


def command_speeds(result, sweep):
    """Per sample, the motor speed (deg/s) of its command: the largest change of a motor from the previous command."""
    motors = [c for c in sweep.columns if c.startswith("q") and c[1:].isdigit()]
    previous = np.vstack([sweep[motors].to_numpy(dtype=float)[-1:], result.command[:-1]])
    return np.abs(result.command - previous).max(axis=1) * result.task.rate_hz


def play_at_reversals(rig, commands, mask):
    """The rig's play where a motor's command turns back within ``mask``: (reversals, median crossing, deg).

    The crossing is :meth:`SimulatedCatheter.play_crossing` at the command,
    the motor travel after a reversal before the rig's unit play element
    moves again; NaN without a play mechanism or without reversals. A move
    below 0.01 deg does not count as motion.
    """
    if rig.mechanism != "play":
        return 0, np.nan
    step = np.diff(commands, axis=0)
    moving = np.abs(step) > 1e-2
    crossings = []
    for j in range(commands.shape[1]):
        idx = np.flatnonzero(moving[:, j])
        turns = idx[1:][np.sign(step[idx[1:], j]) != np.sign(step[idx[:-1], j])] + 1
        crossings.extend(rig.play_crossing(commands[k])[j] for k in turns[mask[turns]])
    return len(crossings), float(np.median(crossings)) if crossings else np.nan


def print_feasibility(rows):
    """What each task asks of the motors: command speeds, samples at the rate limit, the play at reversals."""
    step = RATE_LIMIT / 10.0
    print(f"\nfeasibility: the motor speed of each controller's commands (deg/s over the view's samples: "
          f"median, p95, max), the share of samples at the rate limit ({RATE_LIMIT:g} deg/s, {step:g} deg "
          f"per sample at 10 Hz); the commands' reversals and the rig's play crossing there (deg, unit "
          f"element; elements 0.3 to 8 times it); the model's play (2 x half-width, deg)")
    print("| mechanism | setting | task | controller | RMS mm | speed median | p95 | max | at limit "
          "| reversals | rig's play crossing | model's play |")
    for r in rows:
        v = r["speed"]
        at_limit = np.mean(v >= 0.999 * RATE_LIMIT) if len(v) else np.nan
        n_rev, crossing = r["play"]
        play = " / ".join(f"{w:.1f}" for w in r["model_play"])
        print(f"| {r['mechanism']} | {r['setting']} | {r['task']} | {r['controller']} | {r['rms']:.2f} "
              f"| {np.median(v):.0f} | {np.percentile(v, 95):.0f} | {v.max():.0f} | {at_limit:.2f} "
              f"| {n_rev} | {crossing:.1f} | {play} |")


def estimator_seconds(pipe, timed):
    """Mean time (s) of the estimator's step on the observations a timed controller was given."""
    est = OnlineEstimator(pipe).start(timed.sweep)
    samples = [tuple(float(o[c]) for c in est.channels_) for o in timed.observations]
    t0 = time.perf_counter()
    for sample in samples:
        est.step(*sample)
    return (time.perf_counter() - t0) / len(samples)


def run_setting(pipe, factories, mechanism, setting, args):
    """Rows of the table for one mechanism in one setting of the held-out unit."""
    rig = SimulatedCatheter(catheter=args.catheter, setting=setting, mechanism=mechanism, tracker=True,
                            random_state=args.seed)
    rows, sweep = [], rig.reset()
    model_play = 2.0 * np.atleast_1d(OnlineEstimator(pipe).start(sweep).play_width_)
    for task_name, task in tasks_of(sweep, args.seed):
        if args.tasks and task_name not in args.tasks:
            continue
        oracles = {ORACLES[0]: lambda task=task: RigInverse(rig, task),
                   ORACLES[1]: lambda task=task: RigInverse(rig, task, RATE_LIMIT)}
        for name, factory in {**factories, **{o: oracles[o] for o in args.oracles}}.items():
            timed = Timed(factory())
            result = run_task(rig, timed, task, preview=PREVIEW if name.endswith(PREVIEW_SUFFIX) else 0)
            step_us = 1e6 * float(np.median(timed.seconds))
            model_step = name.startswith(("skcath", "closed"))
            est_us = 1e6 * estimator_seconds(pipe, timed) if model_step else np.nan
            terms = feedback_terms(result, timed) if args.diagnose else None
            speed = command_speeds(result, timed.sweep)
            for scores, mask in zip(score_run(result, timed.observations, args.transit_s),
                                    phases(task, args.transit_s).values()):
                if terms is not None:
                    scores["terms"] = {key: _rms(value[mask]) for key, value in terms.items()}
                scores["speed"] = speed[mask]
                scores["play"] = play_at_reversals(rig, result.command, mask)
                scores["model_play"] = model_play
                rows.append({"mechanism": mechanism, "setting": setting, "task": task_name + scores.pop("view"),
                             "controller": name, **scores, "step_us": step_us, "est_us": est_us,
                             "clipped": result.n_clipped})
                print(_format(rows[-1]), flush=True)
    return rows


HEADER = ("mechanism", "setting", "task", "controller", "RMS mm", "p95 mm", "settle s", "est. mm",
          "tracker mm", "seen mm", "step us", "est. step us")


def _format(row):
    return (f"| {row['mechanism']:10s} | {row['setting']:4s} | {row['task']:19s} | {row['controller']:36s} "
            f"| {row['rms']:6.2f} | {row['p95']:6.2f} | {row['settle']:5.1f} | {row['est']:6.2f} "
            f"| {row['tracker']:5.2f} | {row['seen']:5.2f} | {row['step_us']:7.0f} | {row['est_us']:7.0f} |")


def print_terms(rows):
    """The split of the feedback loops' error (``feedback_terms``), RMS over each view's samples (mm)."""
    print("\nthe feedback's true tip error split: uncorrected model error + solve miss; the model error "
          "itself and its change over the loop's delay; the tracker's own error (RMS, mm)")
    print("| mechanism | setting | task | controller | RMS | uncorrected | solve miss | model error "
          "| change over delay | tracker |")
    for r in rows:
        if "terms" in r:
            t = r["terms"]
            print(f"| {r['mechanism']} | {r['setting']} | {r['task']} | {r['controller']} | {r['rms']:.2f} "
                  f"| {t['uncorrected']:.2f} | {t['solve miss']:.2f} | {t['model error']:.2f} "
                  f"| {t['change over delay']:.2f} | {r['tracker']:.2f} |")


def summary(rows, floors):
    """Per mechanism, setting and task view: the ratios the goals name, both errors over the same samples."""
    print("\nclosed loop (estimate) RMS / PCC open-loop RMS (goal <= 0.5), / the estimator's RMS on the "
          "same samples (goal <= 1.1); tracker-closed RMS; the model's floor on the unit's benchmark runs")
    print("| mechanism | setting | task | preview | closed (est.) mm | / PCC | est. mm | / est. "
          "| feedforward / PCC | closed (tracker) mm | floor mm |")
    keys = dict.fromkeys((r["mechanism"], r["setting"], r["task"]) for r in rows)
    for mech, setting, task in keys:
        sel = {r["controller"]: r for r in rows
               if (r["mechanism"], r["setting"], r["task"]) == (mech, setting, task)}
        pcc = sel.get("PCC inverse, open loop")
        for suffix, preview in (("", "no"), (PREVIEW_SUFFIX, str(PREVIEW))):
            cl = sel.get("skcath closed loop (estimate)" + suffix)
            ff, tr = sel.get("skcath feedforward" + suffix), sel.get("closed on the tracker" + suffix)
            if cl is None or pcc is None:
                continue
            print(f"| {mech:10s} | {setting:4s} | {task:19s} | {preview:>2s} | {cl['rms']:5.2f} "
                  f"| {cl['rms'] / pcc['rms']:5.2f} | {cl['est']:5.2f} | {cl['rms'] / cl['est']:5.2f} "
                  f"| {ff['rms'] / pcc['rms'] if ff else np.nan:5.2f} | {tr['rms'] if tr else np.nan:5.2f} "
                  f"| {floors[mech, setting]:5.2f} |")


def time_rig(n_steps, catheter, setting):
    """Seconds per step of the rig, tracker off and on, along a slow random walk of the motors."""
    rng = np.random.default_rng(0)
    path = np.clip(np.cumsum(rng.normal(0.0, 1.0, size=(n_steps, 2)), axis=0), -50.0, 50.0)
    out = {}
    for tracker in (False, True):
        rig = SimulatedCatheter(catheter, setting, tracker=tracker)
        start = time.perf_counter()
        rig.reset()
        reset_s = time.perf_counter() - start
        start, cpu = time.perf_counter(), time.process_time()
        for command in path:
            rig.step(command)
        out[tracker] = (reset_s, (time.perf_counter() - start) / n_steps,
                        (time.process_time() - cpu) / n_steps)
    return out


def time_steps(n_steps, seed):
    """CPU time (us) of one step of each controller and of the estimator alone, fast path, numba engine.

    A pipeline of PDL with the play and ``NoResidual`` (fitted on one unit)
    steers the rig's own records back as targets: the model's tip for the
    recorded samples of a ``SimulatedCatheter`` run (catheter 3, S05) driven
    along a random walk; observations are passed as tuples.
    """
    from skcath.residuals import NoResidual

    bench = make_benchmark(n_catheters=1, n_runs=1, random_state=seed)
    backbone = PDLBackbone(hysteresis="play").fit(bench.X)
    pipe = Pipeline([("backbone", backbone),
                     ("residual", NoResidual().fit(backbone.transform(bench.X), bench.y))])
    rig = SimulatedCatheter(catheter=3, setting="S05", random_state=seed)
    sweep = rig.reset()
    rng = np.random.default_rng(seed)
    walk = np.clip(np.cumsum(rng.normal(0.0, 1.0, size=(n_steps, 2)), axis=0), -45.0, 45.0)
    est = OnlineEstimator(pipe, engine="numba").start(sweep)
    records = [rig.step(q) for q in walk]
    samples = [tuple(r[c] for c in est.channels_) for r in records]
    targets = [est.step(*x).copy() for x in samples]
    out = {}
    targets = np.array(targets)
    for name, controller in (("estimator step", None),
                             ("FeedforwardController.step", FeedforwardController(pipe, engine="numba")),
                             ("FeedbackController.step", FeedbackController(pipe, engine="numba")),
                             ("FeedbackController.step, numpy", FeedbackController(pipe, engine="numpy")),
                             (f"FeedbackController.step, preview={PREVIEW}", FeedbackController(
                                 pipe, preview=PREVIEW, engine="numba")),
                             (f"FeedbackController.step, preview={PREVIEW}, numpy", FeedbackController(
                                 pipe, preview=PREVIEW, engine="numpy"))):
        if controller is None:
            est.reset()
            cpu = time.process_time()
            for x in samples:
                est.step(*x)
        else:
            controller.start(sweep)
            controller.step(targets[0], samples[0])  # the compiled solve loaded outside the timing
            ahead = [targets[i + 1:i + 1 + PREVIEW] if controller.preview else None for i in range(n_steps)]
            cpu = time.process_time()
            for target, x, upcoming in zip(targets, samples, ahead):
                controller.step(target, x, upcoming=upcoming)
        out[name] = 1e6 * (time.process_time() - cpu) / n_steps
    return out


def parse_args():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the play mechanism and setting S05 only")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the benchmark (the training data and the rig) and of the reach targets")
    parser.add_argument("--mechanisms", nargs="+", default=None, choices=("play", "bouc_wen", "dahl_creep"))
    parser.add_argument("--settings", nargs="+", default=None, help="shaft settings of the rig")
    parser.add_argument("--catheter", type=int, default=3,
                        help="the steered unit, left out of the model's training data (default 3)")
    parser.add_argument("--residual", choices=("none", "gru"), default="gru",
                        help="the model's residual: the protocol's GRU (default) or NoResidual")
    parser.add_argument("--schedule", choices=("quick", "full"), default="quick",
                        help="the protocol's schedule the GRU is pretrained with (default quick)")
    parser.add_argument("--train-runs", type=int, default=None, metavar="K",
                        help="train on the first K repeats of each setting only (default: every run)")
    parser.add_argument("--cache", default=None,
                        help="folder of the trained models (default: <skcath data folder>/steering)")
    parser.add_argument("--transit-s", type=float, default=2.0,
                        help="seconds after each new reach target scored as the transit (default 2)")
    parser.add_argument("--controllers", nargs="+", default=None, metavar="NAME",
                        help="names of the controllers to run (default: all of them)")
    parser.add_argument("--tasks", nargs="+", default=None, metavar="NAME",
                        choices=("reach", "circle 2 mm/s", "circle 10 mm/s", "figure-eight 5 mm/s"),
                        help="names of the tasks to run (default: all of them)")
    parser.add_argument("--diagnose", action="store_true",
                        help="also the tracker-closed loop without the rate limit")
    parser.add_argument("--rig-timing", type=int, default=0, metavar="N",
                        help="first time the rig's reset and N steps, tracker off and on")
    parser.add_argument("--timing", type=int, default=0, metavar="N",
                        help="only time N steps of each controller and of the estimator (CPU time)")
    args = parser.parse_args()
    if args.train_runs is not None and args.train_runs < 1:
        parser.error(f"argument --train-runs: expected a positive number of repeats, got {args.train_runs}")
    if args.catheter < 1:
        parser.error(f"argument --catheter: expected a unit number of at least 1, got {args.catheter}")
    if args.transit_s < 0:
        parser.error(f"argument --transit-s: expected a non-negative number of seconds, got {args.transit_s}")
    return args


def main():
    args = parse_args()
    if args.timing:
        times = time_steps(args.timing, args.seed)
        for name, us in times.items():
            print(f"| {name:44s} | {us:7.1f} us | {us / times['estimator step']:5.1f} x "
                  f"| {us / times['FeedbackController.step']:5.1f} x |")
        return
    mechanisms = args.mechanisms or (("play",) if args.quick else ("play", "bouc_wen", "dahl_creep"))
    settings = args.settings or (("S05",) if args.quick else ("S05", "S12"))
    if args.rig_timing:
        for tracker, (reset_s, step_s, cpu_s) in time_rig(args.rig_timing, args.catheter, settings[0]).items():
            print(f"rig, tracker {'on' if tracker else 'off'}: reset {reset_s:.2f} s, "
                  f"{step_s * 1e6:.0f} us/step wall, {cpu_s * 1e6:.0f} us/step CPU ({args.rig_timing} steps)")
    warnings.simplefilter("ignore", UnreachableTargetWarning)
    cache = args.cache or Path(get_data_home()) / "steering"
    schedule = get_schedule(args.schedule)
    rows, floors = [], {}
    for mechanism in mechanisms:
        bench = make_benchmark(mechanism=mechanism, random_state=args.seed)
        pipe, seconds = protocol_pipeline(bench, mechanism, args.catheter, args.residual, schedule, cache,
                                          args.train_runs, args.seed)
        print(f"\n{mechanism}: the model trained or loaded in {seconds:.0f} s", flush=True)
        for setting in settings:
            floors[mechanism, setting] = estimator_floor(pipe, bench, args.catheter, setting)
            print(f"{mechanism}, {setting}: the model's RMS on unit C{args.catheter}'s benchmark runs "
                  f"{floors[mechanism, setting]:.2f} mm", flush=True)
        print("| " + " | ".join(HEADER) + " |")
        factories = registry(pipe, args.diagnose)
        unknown = sorted(set(args.controllers or ()) - set(factories) - set(ORACLES))
        if unknown:
            raise SystemExit(f"--controllers: unknown {unknown}; expected names among "
                             f"{[*factories, *ORACLES]}")
        wanted = set(args.controllers or factories) | ({DIAGNOSTIC} if args.diagnose else set())
        factories = {name: f for name, f in factories.items() if name in wanted}
        args.oracles = [name for name in ORACLES if name in wanted]
        for setting in settings:
            rows += run_setting(pipe, factories, mechanism, setting, args)
    summary(rows, floors)
    if args.diagnose:
        print_terms(rows)
    print_feasibility(rows)


if __name__ == "__main__":
    main()
