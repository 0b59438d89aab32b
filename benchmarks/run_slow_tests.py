"""Run the tests marked ``slow``, which the default test command leaves out.

The default run (``python -m pytest -q``, the command of README.md and
``.ci/run``) deselects the tests marked ``@pytest.mark.slow`` (``addopts``
in ``pyproject.toml``), so that it stays under about 15 minutes on two CPU
cores. Each slow test checks a behaviour that a faster test of the default
run also checks, on more data, more epochs or more cases. This script runs
them all and prints a table: each test's outcome and time (s, setup, call
and teardown together), slowest first, then the totals.

Usage::

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/run_slow_tests.py [pytest options]

Options after the script's name go to pytest (``-x``, ``-k EXPR``,
``tests/test_x.py``, ...). The exit status is pytest's: 0 when every slow
test passed, 5 when none was collected.
"""

import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import pytest

from _machine import machine_lines

ROOT = Path(__file__).resolve().parents[1]


class _Times:
    """A pytest plugin that keeps each test's time (s) and outcome."""

    def __init__(self):
        self.seconds = defaultdict(float)
        self.outcome = {}

    def pytest_runtest_logreport(self, report):
        self.seconds[report.nodeid] += report.duration
        # the first phase that did not pass (setup, call), else the call's outcome
        if report.when == "call" or report.outcome != "passed":
            outcome = "xfailed" if hasattr(report, "wasxfail") else report.outcome
            self.outcome.setdefault(report.nodeid, outcome)


def _table(times, wall):
    """The Markdown table of the tests run, slowest first, and the totals."""
    rows = sorted(times.seconds.items(), key=lambda item: -item[1])
    lines = ["| test | outcome | time (s) |", "|---|---|---:|"]
    lines += [f"| `{node}` | {times.outcome.get(node, 'passed')} | {s:.1f} |" for node, s in rows]
    counts = defaultdict(int)
    for node, _ in rows:
        counts[times.outcome.get(node, "passed")] += 1
    summary = ", ".join(f"{n} {outcome}" for outcome, n in sorted(counts.items()))
    lines.append("")
    lines.append(f"{len(rows)} slow tests ({summary or 'none run'}): "
                 f"{sum(times.seconds.values()):.0f} s in the tests, {wall:.0f} s wall time")
    return lines


def main(argv):
    """Run ``pytest -m slow`` with the options ``argv``; print the table; return pytest's status."""
    times = _Times()
    start = time.perf_counter()
    os.chdir(ROOT)  # pytest's testpaths (tests/) apply to a run from the root
    status = pytest.main(["-m", "slow", "-q", *argv], plugins=[times])
    wall = time.perf_counter() - start
    print()
    print("\n".join(machine_lines()))
    print("\n".join(_table(times, wall)))
    return int(status)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
