"""The paper's evaluation protocol end to end: methods, training schedule, tables and figures.

:data:`METHODS` describes every method once (PCC and PDL backbones,
PDL+GRU, its torque/context ablations, PDL+MLP, the catheter-held-out
PDL+GRU, and the sweep-adapted PDL and PDL+GRU): learner, inputs, colour and
the tables it appears in.
:func:`run_protocol` trains and evaluates every method with settings held
out within each catheter and with whole catheters held out;
:func:`compute_tables` turns the held-out predictions into the paper's
tables; :func:`write_results` saves them as CSV and draws the figures.
``python -m skcath reproduce`` runs all three; see ``docs/studies/results.rst``.
:func:`run_calibration_budget` scores the methods on reduced calibration
sweeps (``python -m skcath calibration-budget``, see
``docs/studies/calibration_budget.rst``).
"""

from ._budget import (
    BUDGET_FILES,
    BUDGET_METHODS,
    format_budget_report,
    plot_calibration_budget,
    run_calibration_budget,
    write_budget_results,
)
from ._methods import (
    ADAPTED_BACKBONE,
    ADAPTED_METHOD,
    COMPARISONS,
    LOCO_METHOD,
    LOCO_METHODS,
    MAIN_METHODS,
    METHODS,
    PROPOSED_METHOD,
    ROLES,
    TORQUE_CONTEXT,
    VARIANTS,
    Method,
    backbone_method,
    make_learner,
    methods_with_role,
)
from ._protocol import (
    LEARNER_COLUMNS,
    Fold,
    calibrate_backbones,
    finetune_models,
    learner_input,
    pretrain_models,
    protocol_folds,
    run_protocol,
)
from ._report import format_report, write_results
from ._schedule import FULL, QUICK, Schedule, get_schedule
from ._tables import compute_tables

__all__ = [
    "ADAPTED_BACKBONE",
    "ADAPTED_METHOD",
    "BUDGET_FILES",
    "BUDGET_METHODS",
    "COMPARISONS",
    "FULL",
    "Fold",
    "LEARNER_COLUMNS",
    "LOCO_METHOD",
    "LOCO_METHODS",
    "MAIN_METHODS",
    "METHODS",
    "Method",
    "PROPOSED_METHOD",
    "QUICK",
    "ROLES",
    "Schedule",
    "TORQUE_CONTEXT",
    "VARIANTS",
    "backbone_method",
    "calibrate_backbones",
    "compute_tables",
    "finetune_models",
    "format_budget_report",
    "format_report",
    "get_schedule",
    "learner_input",
    "make_learner",
    "methods_with_role",
    "plot_calibration_budget",
    "pretrain_models",
    "protocol_folds",
    "run_calibration_budget",
    "run_protocol",
    "write_budget_results",
    "write_results",
]
