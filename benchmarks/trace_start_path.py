"""The path of one sweep through ``OnlineEstimator.start``: which modules of skcath it crosses.

Data: the simulated benchmark with one catheter and one run per setting
(``make_benchmark(n_catheters=1, n_runs=1, random_state=0)``, cached in the
skcath data folder). A ``Pipeline([("backbone", PDLBackbone()),
("residual", GRUResidual(max_epochs=1))])`` is fitted on three shaft
settings (S02, S09, S13); the sweep rows of the run of setting S05 are then
given to ``OnlineEstimator(pipe, engine=...).start``, once untraced (so that
imports and first-call caches are out of the way) and once traced.

The trace follows every call of a function defined in a file of the skcath
package (``sys.setprofile``, ``tests/module_trace.py``, whose docstring
defines the terms below); calls into other libraries are skipped, a call is
attributed to the nearest skcath function below it on the stack, and the
objective calls of the Levenberg-Marquardt loop (``backbones._lm``) are
callbacks, left out. The script prints:

- the number of times the call stack enters ``_validation`` (with the
  modules it is split into, ``_validation_columns``, ``_validation_runs``,
  ``_validation_target``) from outside it: the calls of one of its
  functions whose nearest skcath caller is in another module, and the
  separate visits (the calls made by one call of an outside function count
  once);
- the crossings that re-enter a module from a module below it (back up the
  path: the calls between the modules form a cycle);
- every crossing from one module to another, in call order and indented by
  the depth of the module stack: ``caller_module.function ->
  callee_module.function``; a crossing marked ``re-enters`` goes back up
  the path. Runs of equal lines are collapsed, and calls into ``_format``
  (names and constants) are left out unless ``--show-leaves`` is given;
- before the sequence, the calls into ``_validation`` grouped by the step of
  ``online._estimator`` they are made under.

``--sweep-every k`` keeps every k-th sweep sample, so that the sweep's rate
differs from the rate the residual was fitted at.

Run: ``python benchmarks/trace_start_path.py [--engine numpy] [--sweep-every 1]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from sklearn.pipeline import Pipeline

import skcath
from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.online import OnlineEstimator
from skcath.residuals import GRUResidual

# the tracer is shared with tests/test_start_path.py
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from module_trace import ModuleTracer  # noqa: E402

TRAIN_SETTINGS = ["S02", "S09", "S13"]
TEST_SETTING = "S05"
TRACED = "_validation"
TOP = "online._estimator"
#: Modules of names and constants only; their calls are left out of the sequence.
LEAVES = ("_format",)


def _collapse(lines):
    """Runs of equal consecutive lines, as (line, count)."""
    out = []
    for line in lines:
        if out and out[-1][0] == line:
            out[-1][1] += 1
        else:
            out.append([line, 1])
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--engine", default="numpy", choices=["numpy", "numba"])
    parser.add_argument("--sweep-every", type=int, default=1,
                        help="keep every k-th sweep sample (k > 1: a sweep at a lower rate)")
    parser.add_argument("--show-leaves", action="store_true",
                        help="also list the calls into the modules of names and constants")
    args = parser.parse_args(argv)

    data = make_benchmark(n_catheters=1, n_runs=1, random_state=0)
    X, y = data.X, np.asarray(data.y)
    train = X["setting"].isin(TRAIN_SETTINGS).to_numpy()
    pipe = Pipeline([("backbone", PDLBackbone()),
                     ("residual", GRUResidual(max_epochs=1, n_threads=1, random_state=0))])
    pipe.fit(X[train], y[train])
    run = X[(X["setting"] == TEST_SETTING).to_numpy()]
    sweep = run[(run["phase"] == "sweep").to_numpy()].iloc[:: args.sweep_every]

    OnlineEstimator(pipe, engine=args.engine).start(sweep)  # imports and caches
    estimator = OnlineEstimator(pipe, engine=args.engine)
    with ModuleTracer() as tracer:
        estimator.start(sweep)

    print(f"OnlineEstimator(engine={args.engine!r}).start on the S05 sweep "
          f"({len(sweep)} samples, every {args.sweep_every} kept), skcath {skcath.__version__}")
    entries = tracer.entries(TRACED)
    print(f"calls into {TRACED} from another module: {len(entries)}; separate visits "
          f"(one per calling call): {tracer.visits(TRACED)}")
    re_entries = set(tracer.re_entries())
    print(f"crossings between modules: {len(tracer.crossings)}, re-entering a module from a module "
          f"below it: {len(re_entries)}")
    print(f"\n{TRACED} below each step of {TOP}:")
    for stage, n_calls, calls in tracer.by_stage(TRACED, TOP):
        print(f"  {n_calls:3d}  {stage}: {', '.join(calls)}")
    print("\ncrossings in call order (* into " + TRACED + "; repeats collapsed"
          + ("" if args.show_leaves else f"; calls into {', '.join(LEAVES)} left out") + "):")
    lines = [(depth, caller, callee, (caller, callee) in re_entries)
             for depth, caller, callee, _ in tracer.crossings
             if args.show_leaves or callee.rsplit(".", 1)[0] not in LEAVES]
    for (depth, caller, callee, re_entry), count in _collapse(lines):
        mark = "   re-enters" if re_entry else ""
        flag = " *" if (caller, callee) in entries else ""
        times = f" (x{count})" if count > 1 else ""
        print(f"{'  ' * depth}{caller} -> {callee}{flag}{times}{mark}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
