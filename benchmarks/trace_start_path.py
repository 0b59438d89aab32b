"""The path of one sweep through ``OnlineEstimator.start``: which modules of skcath it crosses.

Data: the simulated benchmark with one catheter and one run per setting
(``make_benchmark(n_catheters=1, n_runs=1, random_state=0)``, cached in the
skcath data folder). A ``Pipeline([("backbone", PDLBackbone()),
("residual", GRUResidual(max_epochs=1))])`` is fitted on three shaft
settings (S02, S09, S13); the sweep rows of the run of setting S05 are then
given to ``OnlineEstimator(pipe, engine=...).start``, once untraced (so that
imports and first-call caches are out of the way) and once traced.

The trace follows every call of a function defined in a file of the skcath
package (``sys.setprofile``); calls into other libraries are skipped, and a
call is attributed to the nearest skcath function below it on the stack.
The script prints:

- the number of times the call stack enters ``skcath/_validation.py`` from
  outside it: the calls of a function of ``_validation`` whose nearest
  skcath caller is in another module, and the separate visits (the calls
  made by one call of an outside function count once);
- every crossing from one module to another, in call order and indented by
  the depth of the module stack: ``caller_module.function ->
  callee_module.function``; a crossing marked ``re-enters`` goes into a
  module that is already on the module stack below (the module calls down
  and the module below calls back up into it; a callback such as the
  objective a solver calls is one too). Runs of equal lines are collapsed,
  and calls into ``_format`` (names and constants) are left out unless
  ``--show-leaves`` is given;
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

TRAIN_SETTINGS = ["S02", "S09", "S13"]
TEST_SETTING = "S05"
PACKAGE_DIR = Path(skcath.__file__).resolve().parent
TRACED = "_validation"
TOP = "online._estimator"
#: Modules of names and constants only; their calls are left out of the sequence.
LEAVES = ("_format",)


def module_of(filename):
    """Module name of a file of the package, relative to it (``online._estimator``), or None."""
    try:
        relative = Path(filename).resolve().relative_to(PACKAGE_DIR)
    except ValueError:
        return None
    parts = list(relative.with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts) or "skcath"


class ModuleTracer:
    """Record the crossings between modules of the package during a call.

    Use as a context manager; afterwards :attr:`crossings` holds one
    ``(depth, caller, callee, re_entry)`` per call of a package function
    whose nearest package caller is in another module, where ``caller`` and
    ``callee`` are ``"module.function"`` and ``depth`` is the number of
    modules on the module stack below the callee.
    """

    def __init__(self):
        self.crossings = []
        self._callers = []
        self._modules = {}

    def _module(self, code):
        filename = code.co_filename
        if filename not in self._modules:
            self._modules[filename] = module_of(filename)
        return self._modules[filename]

    def _package_caller(self, frame):
        """The nearest frame below ``frame`` that runs package code, or None."""
        frame = frame.f_back
        while frame is not None and self._module(frame.f_code) is None:
            frame = frame.f_back
        return frame

    def _module_stack(self, frame):
        """Modules of the package frames below ``frame``, bottom first, runs collapsed."""
        stack = []
        while frame is not None:
            module = self._module(frame.f_code)
            if module is not None and (not stack or stack[-1] != module):
                stack.append(module)
            frame = frame.f_back
        return stack[::-1]

    def _profile(self, frame, event, arg):
        if event != "call":
            return
        callee = self._module(frame.f_code)
        if callee is None:
            return
        caller_frame = self._package_caller(frame)
        if caller_frame is None:
            return
        caller = self._module(caller_frame.f_code)
        if caller == callee:
            return
        below = self._module_stack(caller_frame)
        self.crossings.append((
            len(below),
            f"{caller}.{caller_frame.f_code.co_name}",
            f"{callee}.{frame.f_code.co_name}",
            callee in below,
        ))
        self._callers.append(caller_frame)  # kept alive: one frame, one visit

    def __enter__(self):
        sys.setprofile(self._profile)
        return self

    def __exit__(self, *exc):
        sys.setprofile(None)
        return False

    def entries(self, module):
        """How many crossings go into ``module``."""
        return sum(1 for _, _, callee, _ in self.crossings if callee.rsplit(".", 1)[0] == module)

    def visits(self, module):
        """How many calls of functions outside ``module`` go into it (one count per calling call)."""
        return len({id(frame) for frame, (_, _, callee, _) in zip(self._callers, self.crossings)
                    if callee.rsplit(".", 1)[0] == module})

    def by_stage(self, module, top):
        """Crossings into ``module`` below each call that ``top`` makes into another module.

        Returns a list of ``(stage, n_calls, functions)``: ``stage`` is the
        crossing out of ``top`` (``"top.function -> other.function"``),
        ``functions`` the functions of ``module`` called below it, in order.
        """
        stages = []
        for _, caller, callee, _ in self.crossings:
            if caller.rsplit(".", 1)[0] == top:
                stages.append((f"{caller} -> {callee}", []))
                if callee.rsplit(".", 1)[0] != module:
                    continue
            if callee.rsplit(".", 1)[0] == module and stages:
                stages[-1][1].append(callee.rsplit(".", 1)[1])
        return [(stage, len(calls), calls) for stage, calls in stages if calls]


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
    print(f"calls into {TRACED} from another module: {tracer.entries(TRACED)}; separate visits "
          f"(one per calling call): {tracer.visits(TRACED)}")
    re_entries = [c for c in tracer.crossings if c[3]]
    print(f"crossings between modules: {len(tracer.crossings)}, re-entering a module below: "
          f"{len(re_entries)}")
    print(f"\n{TRACED} below each step of {TOP}:")
    for stage, n_calls, calls in tracer.by_stage(TRACED, TOP):
        print(f"  {n_calls:3d}  {stage}: {', '.join(calls)}")
    print("\ncrossings in call order (* into " + TRACED + "; repeats collapsed"
          + ("" if args.show_leaves else f"; calls into {', '.join(LEAVES)} left out") + "):")
    lines = [(depth, caller, callee, re_entry) for depth, caller, callee, re_entry in tracer.crossings
             if args.show_leaves or callee.rsplit(".", 1)[0] not in LEAVES]
    for (depth, caller, callee, re_entry), count in _collapse(lines):
        mark = "   re-enters" if re_entry else ""
        flag = " *" if callee.startswith(TRACED + ".") else ""
        times = f" (x{count})" if count > 1 else ""
        print(f"{'  ' * depth}{caller} -> {callee}{flag}{times}{mark}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
