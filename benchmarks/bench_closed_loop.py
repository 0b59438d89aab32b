"""Closed-loop steering on the simulated catheter: tasks x mechanisms x controllers.

For each hysteresis mechanism (play, bouc_wen, dahl_creep), a
``skcath.datasets.SimulatedCatheter`` of a unit the training benchmark does
not hold (``--catheter 5``: ``make_benchmark``'s default has C1-C4) in one
shaft setting (``--setting``) runs the standard tasks of its sweep
(``skcath.datasets.standard_tasks``: reach and hold 6 targets for 5 s each, a
circle and a figure-eight at ``--speed`` mm/s) with every controller of the
registry, and the true tip is scored (``skcath.datasets.task_scores``): RMS
and 95th percentile of the error (mm), and for the reach task the median
settling time to 2 mm (s) and the share of targets held; "clipped" counts
the commands the rig clipped to its motor range and "warnings" the
warnings raised during the task (a controller's unreachable targets).

Controllers (``CONTROLLERS``: name -> ``(backbone, tracker, factory)``, the
factory called with the fitted pipeline of ``backbone``):

- ``sweep lookup``: the naive open-loop baseline: it commands the motor
  angles of the sweep sample whose tracked tip is nearest the target (no
  model, no hysteresis compensation);
- with ``skcath.control`` installed, its controllers on pipelines of a
  backbone and ``NoResidual``, fitted on ``make_benchmark(mechanism=...)``
  of the same mechanism: ``PCC inverse, open loop`` and ``PDL inverse, open
  loop`` (``FeedforwardController`` of the backbone alone, no play),
  ``skcath feedforward`` (``FeedforwardController`` of PDL with the play,
  ``hysteresis="play"``), ``skcath closed loop (estimate)``
  (``FeedbackController`` on the streamed estimate of that pipeline) and
  ``closed on the tracker`` (``FeedbackController(close_on="tracker")``, the
  rig's tracker on: the bound of what an estimate can give), all with a rate
  limit of 60 deg/s and ``latency=1``. Without it they are skipped.

The script also times the rig itself: ``SimulatedCatheter.reset`` and
``step`` with the tracker off and on (wall time, and the process's CPU time,
which a loaded machine inflates less).

Run ``python benchmarks/bench_closed_loop.py`` (``--quick``: shorter tasks
and a one-unit training benchmark).
"""

import argparse
import importlib
import time
import warnings

import numpy as np
from sklearn.pipeline import Pipeline

from skcath.datasets import (
    SimulatedCatheter,
    circle_task,
    figure_eight_task,
    make_benchmark,
    reach_task,
    run_task,
    standard_tasks,
    task_scores,
)

MECHANISMS = ("play", "bouc_wen", "dahl_creep")


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


#: name -> (backbone of the pipeline it needs or None, whether the rig's tracker is on, factory(pipeline))
CONTROLLERS = {"sweep lookup": (None, False, lambda pipeline: SweepLookup())}

try:  # an optional package: imported by name, so that the script runs without it
    control = importlib.import_module("skcath.control")
except ImportError:
    CONTROL_MISSING = True
else:
    CONTROL_MISSING = False
    _LIMITS = {"rate_limit": 60.0}  # deg/s; latency=1 (the default) is the rig's timing
    CONTROLLERS.update({
        "PCC inverse, open loop": ("pcc", False, lambda p: control.FeedforwardController(p, **_LIMITS)),
        "PDL inverse, open loop": ("pdl", False, lambda p: control.FeedforwardController(p, **_LIMITS)),
        "skcath feedforward": ("pdl-play", False, lambda p: control.FeedforwardController(p, **_LIMITS)),
        "skcath closed loop (estimate)": (
            "pdl-play", False, lambda p: control.FeedbackController(p, **_LIMITS)
        ),
        "closed on the tracker": (
            "pdl-play", True, lambda p: control.FeedbackController(p, close_on="tracker", **_LIMITS)
        ),
    })


def fit_pipelines(mechanism, backbones, quick):
    """Pipelines of each backbone and NoResidual, fitted on the benchmark of ``mechanism``.

    ``"pcc"`` and ``"pdl"`` are the backbones alone; ``"pdl-play"`` is PDL
    with the play identified on the sweep (``hysteresis="play"``).
    """
    from skcath.backbones import PCCBackbone, PDLBackbone
    from skcath.residuals import NoResidual

    size = {"n_catheters": 1, "n_runs": 1} if quick else {}
    data = make_benchmark(mechanism=mechanism, **size)
    out = {}
    for name in backbones:
        Backbone = PCCBackbone if name == "pcc" else PDLBackbone
        backbone = Backbone(hysteresis="play" if name.endswith("-play") else None).fit(data.X)
        residual = NoResidual().fit(backbone.transform(data.X), data.y)
        out[name] = Pipeline([("backbone", backbone), ("residual", residual)])
    return out


def tasks_of(sweep, quick, speed, seed):
    """The standard tasks, or shorter ones with ``quick``."""
    if not quick:
        return standard_tasks(sweep, speed_mm_s=speed, random_state=seed)
    return [
        reach_task(sweep, n_targets=3, hold_s=4.0, random_state=seed),
        circle_task(sweep, speed_mm_s=speed, n_laps=1),
        figure_eight_task(sweep, speed_mm_s=speed),
    ]


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


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter tasks, one-unit training data")
    parser.add_argument("--catheter", type=int, default=5, help="held-out unit (default 5)")
    parser.add_argument("--setting", default="S06", help="shaft setting of the rig (default S06)")
    parser.add_argument("--speed", type=float, default=5.0, help="tip speed of the paths (mm/s)")
    parser.add_argument("--mechanisms", nargs="+", default=list(MECHANISMS), choices=MECHANISMS)
    parser.add_argument("--controllers", nargs="+", default=None, help="names in CONTROLLERS")
    parser.add_argument("--seed", type=int, default=0, help="draw of the reach targets")
    parser.add_argument("--timing-steps", type=int, default=2000, help="steps timed (0: no timing)")
    args = parser.parse_args()

    if args.timing_steps:
        for tracker, (reset_s, step_s, cpu_s) in time_rig(args.timing_steps, args.catheter, args.setting).items():
            print(f"rig, tracker {'on' if tracker else 'off'}: reset {reset_s:.2f} s, "
                  f"{step_s * 1e6:.0f} us/step wall, {cpu_s * 1e6:.0f} us/step CPU "
                  f"({args.timing_steps} steps)")
    if CONTROL_MISSING:
        print("skipped: skcath.control not available")
    names = args.controllers or list(CONTROLLERS)
    unknown = sorted(set(names) - set(CONTROLLERS))
    if unknown:
        parser.error(f"unknown controller(s) {unknown}; available: {sorted(CONTROLLERS)}")

    print()
    print("| task | mechanism | controller | RMS mm | p95 mm | settling s | held | clipped | warnings |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for mechanism in args.mechanisms:
        backbones = sorted({CONTROLLERS[n][0] for n in names} - {None})
        pipelines = fit_pipelines(mechanism, backbones, args.quick) if backbones else {}
        for name in names:
            backbone, tracker, factory = CONTROLLERS[name]
            rig = SimulatedCatheter(args.catheter, args.setting, mechanism=mechanism, tracker=tracker)
            for task in tasks_of(rig.reset(), args.quick, args.speed, args.seed):
                with warnings.catch_warnings(record=True) as warned:
                    warnings.simplefilter("always")
                    result = run_task(rig, factory(pipelines.get(backbone)), task)
                s = task_scores(result)
                settling = "" if np.isnan(s["settling_s"]) else f"{s['settling_s']:.1f}"
                held = "" if np.isnan(s["settled"]) else f"{s['settled']:.2f}"
                print(f"| {task.name} | {mechanism} | {name} | {s['rms_mm']:.2f} | {s['p95_mm']:.2f} "
                      f"| {settling} | {held} | {result.n_clipped} | {len(warned)} |", flush=True)


if __name__ == "__main__":
    main()
