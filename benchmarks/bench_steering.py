"""The controllers of skcath.control in closed loop on the simulated rig, per hysteresis mechanism.

Data: for each mechanism (``play``, ``bouc_wen``, ``dahl_creep``) the
simulated benchmark of two catheters, one run per setting
(``make_benchmark(n_catheters=2, n_runs=1, mechanism=...)``, cached in the
skcath data folder), trains ``Pipeline([("backbone",
PDLBackbone(hysteresis="play")), ("residual", GRUResidual(max_epochs=3,
module__hidden_size=32))])``. The closed loop runs on a held-out unit
(``SimulatedCatheter(catheter=3, ...)``, not in the training data) in
held-out runs of shaft settings S05 and S12 (``--quick``: S05 only), with the
tracker on (only the tracker-closed controller reads it).

Tasks (:func:`skcath.datasets.run_task` on the rig's sweep): reach and hold
six targets for 5 s each, a circle at 2 and at 10 mm/s, a figure-eight at
5 mm/s. Scores (:func:`skcath.datasets.task_scores`): RMS and 95th
percentile of the true tip error (mm), median settling time of the reach
targets (s; below 2 mm until the next target, inf when never held), and
the RMS of the streamed estimate's error on the same run (the estimate of
each record against its true tip): the estimator's own error on the motion
the controller made.

Controllers:

- ``PCC inverse, open loop`` / ``PDL inverse, open loop``:
  ``FeedforwardController`` of a pipeline of the backbone alone (no play, no
  residual; PCC calibrated on the run's sweep, PDL fitted on the training
  data);
- ``skcath feedforward``: ``FeedforwardController`` of the trained pipeline;
- ``skcath closed loop (estimate)``: ``FeedbackController(close_on="estimate")``;
- ``closed on the tracker``: ``FeedbackController(close_on="tracker")``,
  the bound that a tracker in the loop gives.

All run with ``latency=1`` (the rig's timing), the sweep's motor range as
limits and a rate limit of 60 deg/s. The time of one controller step is
timed with ``time.perf_counter`` around ``step`` inside the runs, next to the
time of the estimator's own step on the same observations (a fresh
``OnlineEstimator`` of the same pipeline stepping the recorded samples), on
the same engine.

``--timing N`` instead times N steps (CPU time, ``time.process_time``) of
each controller and of the estimator alone on the same samples, on the
numba engine and the fast path (observations as tuples), for a pipeline of
PDL with the play and ``NoResidual`` (see ``time_steps``).

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_steering.py [--quick]
[--mechanisms ...] [--settings ...] [--timing N]``.
"""

import argparse
import time
import warnings

import numpy as np
from sklearn.pipeline import Pipeline

from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.control import FeedbackController, FeedforwardController, UnreachableTargetWarning
from skcath.datasets import (
    SimulatedCatheter,
    circle_task,
    figure_eight_task,
    make_benchmark,
    reach_task,
    run_task,
    task_scores,
)
from skcath.online import OnlineEstimator
from skcath.residuals import GRUResidual

RATE_LIMIT = 60.0  # deg/s


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


class Timed:
    """A controller whose ``step`` is timed; it keeps the observations it was given."""

    def __init__(self, controller):
        self.controller, self.seconds, self.observations = controller, [], []

    def start(self, sweep):
        self.controller.start(sweep)
        self.sweep = sweep
        return self

    def step(self, target, obs):
        t0 = time.perf_counter()
        command = self.controller.step(target, obs)
        self.seconds.append(time.perf_counter() - t0)
        self.observations.append(obs)
        self.estimate_ = self.controller.estimate_
        return command


def registry(pipe, X_train):
    """Controller factories: name -> factory() of an unstarted controller."""
    common = {"rate_limit": RATE_LIMIT, "latency": 1}
    pdl = Pipeline([("backbone", PDLBackbone().fit(X_train))])
    return {
        "PCC inverse, open loop": lambda: SweepFitted(PCCBackbone, **common),
        "PDL inverse, open loop": lambda: FeedforwardController(pdl, **common),
        "skcath feedforward": lambda: FeedforwardController(pipe, **common),
        "skcath closed loop (estimate)": lambda: FeedbackController(pipe, **common),
        "closed on the tracker": lambda: FeedbackController(pipe, close_on="tracker", **common),
    }


def fit_pipeline(X, y, seed):
    backbone = PDLBackbone(hysteresis="play").fit(X)
    residual = GRUResidual(max_epochs=3, module__hidden_size=32, n_threads=1, random_state=seed)
    return Pipeline([("backbone", backbone), ("residual", residual.fit(backbone.transform(X), y))])


def tasks_of(sweep, seed):
    return [
        ("reach", reach_task(sweep, random_state=seed)),
        ("circle 2 mm/s", circle_task(sweep, speed_mm_s=2.0, n_laps=1)),
        ("circle 10 mm/s", circle_task(sweep, speed_mm_s=10.0)),
        ("figure-eight 5 mm/s", figure_eight_task(sweep, speed_mm_s=5.0)),
    ]


def estimator_seconds(pipe, timed):
    """Mean time (s) of the estimator's step on the observations a timed controller was given."""
    est = OnlineEstimator(pipe).start(timed.sweep)
    samples = [tuple(float(o[c]) for c in est.channels_) for o in timed.observations]
    t0 = time.perf_counter()
    for sample in samples:
        est.step(*sample)
    return (time.perf_counter() - t0) / len(samples)


def run_mechanism(mechanism, settings, seed):
    """Rows of the table for one mechanism."""
    bench = make_benchmark(n_catheters=2, n_runs=1, mechanism=mechanism, random_state=seed)
    pipe = fit_pipeline(bench.X, np.asarray(bench.y), seed)
    factories = registry(pipe, bench.X)
    rows = []
    for setting in settings:
        rig = SimulatedCatheter(catheter=3, setting=setting, mechanism=mechanism, tracker=True,
                                random_state=seed)
        sweep = rig.reset()
        for task_name, task in tasks_of(sweep, seed):
            for name, factory in factories.items():
                timed = Timed(factory())
                result = run_task(rig, timed, task)
                scores = task_scores(result)
                est_err = np.linalg.norm(result.estimate[2:] - result.tip[:-2], axis=1)
                step_us = 1e6 * float(np.median(timed.seconds))
                est_us = 1e6 * estimator_seconds(pipe, timed) if name.startswith(("skcath", "closed")) else np.nan
                rows.append((mechanism, setting, task_name, name, scores["rms_mm"], scores["p95_mm"],
                             scores["settling_s"], float(np.sqrt(np.mean(est_err**2))), step_us, est_us))
                print(_format(rows[-1]), flush=True)
    return rows


HEADER = ("mechanism", "setting", "task", "controller", "RMS mm", "p95 mm", "settle s",
          "est. RMS mm", "step us", "est. step us")


def _format(row):
    return (f"| {row[0]:10s} | {row[1]:4s} | {row[2]:19s} | {row[3]:29s} | {row[4]:6.2f} | {row[5]:6.2f} "
            f"| {row[6]:6.1f} | {row[7]:6.2f} | {row[8]:7.0f} | {row[9]:7.0f} |")


def summary(rows):
    """Per mechanism and task kind: the ratios the goals name."""
    print("\nratios (mean over settings): closed loop (estimate) RMS / PCC open-loop RMS, "
          "/ estimator RMS on the same run")
    for mech in dict.fromkeys(r[0] for r in rows):
        for task in dict.fromkeys(r[2] for r in rows):
            sel = [r for r in rows if r[0] == mech and r[2] == task]
            cl = np.mean([r[4] for r in sel if r[3] == "skcath closed loop (estimate)"])
            pcc = np.mean([r[4] for r in sel if r[3] == "PCC inverse, open loop"])
            est = np.mean([r[7] for r in sel if r[3] == "skcath closed loop (estimate)"])
            print(f"| {mech:10s} | {task:19s} | {cl / pcc:5.2f} | {cl / est:5.2f} |")


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
    for name, controller in (("estimator step", None),
                             ("FeedforwardController.step", FeedforwardController(pipe, engine="numba")),
                             ("FeedbackController.step", FeedbackController(pipe, engine="numba"))):
        if controller is None:
            est.reset()
            cpu = time.process_time()
            for x in samples:
                est.step(*x)
        else:
            controller.start(sweep)
            controller.step(targets[0], samples[0])  # the compiled solve loaded outside the timing
            cpu = time.process_time()
            for target, x in zip(targets, samples):
                controller.step(target, x)
        out[name] = 1e6 * (time.process_time() - cpu) / n_steps
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the play mechanism and setting S05 only")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mechanisms", nargs="+", default=None, choices=("play", "bouc_wen", "dahl_creep"))
    parser.add_argument("--settings", nargs="+", default=None, help="shaft settings of the rig")
    parser.add_argument("--timing", type=int, default=0, metavar="N",
                        help="only time N steps of each controller and of the estimator (CPU time)")
    args = parser.parse_args()
    if args.timing:
        times = time_steps(args.timing, args.seed)
        for name, us in times.items():
            print(f"| {name:28s} | {us:7.1f} us | {us / times['estimator step']:5.1f} x |")
        return
    warnings.simplefilter("ignore", UnreachableTargetWarning)
    mechanisms = args.mechanisms or (("play",) if args.quick else ("play", "bouc_wen", "dahl_creep"))
    settings = args.settings or (("S05",) if args.quick else ("S05", "S12"))
    print("| " + " | ".join(HEADER) + " |")
    rows = []
    for mechanism in mechanisms:
        rows += run_mechanism(mechanism, settings, args.seed)
    summary(rows)


if __name__ == "__main__":
    main()
