"""The paper's evaluation protocol end to end: training schedule, tables and figures.

:func:`run_protocol` trains and evaluates every method (the PCC and PDL
backbones, PDL+GRU, its torque/context ablations and PDL+MLP) with settings
held out within each catheter and with whole catheters held out;
:func:`compute_tables` turns the held-out predictions into the paper's
tables; :func:`write_results` saves them as CSV and draws the figures.
``python -m skcath reproduce`` runs all three; see ``docs/results.rst``.
:func:`run_calibration_budget` scores the methods on reduced calibration
sweeps (``python -m skcath calibration-budget``, see
``docs/calibration_budget.rst``).
"""

from ._budget import (
    BUDGET_FILES,
    BUDGET_METHODS,
    format_budget_report,
    plot_calibration_budget,
    run_calibration_budget,
    write_budget_results,
)

from ._protocol import run_protocol
from ._report import format_report, write_results
from ._schedule import FULL, QUICK, VARIANTS, Schedule, get_schedule
from ._tables import COMPARISONS, MAIN_METHODS, TORQUE_CONTEXT, compute_tables

__all__ = [
    "BUDGET_FILES",
    "BUDGET_METHODS",
    "COMPARISONS",
    "FULL",
    "MAIN_METHODS",
    "QUICK",
    "Schedule",
    "TORQUE_CONTEXT",
    "VARIANTS",
    "compute_tables",
    "format_budget_report",
    "format_report",
    "get_schedule",
    "plot_calibration_budget",
    "run_calibration_budget",
    "run_protocol",
    "write_budget_results",
    "write_results",
]
