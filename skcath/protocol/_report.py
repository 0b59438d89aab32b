"""Print and save the protocol's tables (text, CSV) and figures (PNG)."""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
from sklearn.utils import Bunch
from sklearn.utils._param_validation import validate_params

from ._figures import write_figures
from ._methods import LOCO_VARIANT, MAIN_METHODS, METHODS, methods_with_role

__all__ = ["format_report", "write_results", "TABLE_FILES"]

#: Table key -> CSV file name written by :func:`write_results`.
TABLE_FILES = {
    "table_1": "table_1_rmse.csv",
    "table_2": "table_2_torque_context.csv",
    "residual_learners": "residual_learners.csv",
    "loco": "leave_one_catheter_out.csv",
    "adaptation": "sweep_adaptation.csv",
    "cdf_at_5mm": "cdf_at_5mm.csv",
    "magnitude": "rmse_by_magnitude.csv",
    "time": "rmse_over_time.csv",
    "paired": "paired_reductions.csv",
    "run_rmse": "run_rmse.csv",
    "run_rmse_by_seed": "run_rmse_by_seed.csv",
    "cdf": "error_cdf.csv",
    "magnitude_bins": "run_bin_rmse_magnitude.csv",
    "time_bins": "run_bin_rmse_time.csv",
    "example": "motion_example.csv",
}


#: Tables the figures are drawn from.
FIGURE_TABLES = ("run_rmse", "cdf", "magnitude_bins", "time_bins", "paired", "example")

#: Long tables, written without their (row number) index.
_LONG_TABLES = ("run_rmse", "run_rmse_by_seed", "cdf", "magnitude_bins", "time_bins", "example", "paired")


def _mm(table):
    """Position errors to one decimal place, as the paper reports them."""
    return table.to_string(float_format=lambda v: f"{v:.1f}")


def _bins(table, unit):
    table = table.copy()
    table.index = [f"{left:g}-{right:g} {unit}" for left, right in table.index]
    return table


def _residual_learners_text(table):
    """The residual learners' table, with the runs improved by the second learner."""
    first, second = methods_with_role("residual_learners")
    first_learner, second_learner = (METHODS[m].learner.upper() for m in (first, second))
    text = table.drop(index="fraction_improved").to_string(float_format=lambda v: f"{v:.1f}")
    improved = " ".join(f"{c}: {100 * v:.0f}%" for c, v in table.loc["fraction_improved"].items())
    return (f"Residual learners: {first} vs {second} (mm; reduction = {first_learner} - "
            f"{second_learner}, 95% setting-cluster interval)\n{text}\n"
            f"runs improved by the {second_learner}: {improved}")


def _adaptation_text(table):
    """The sweep-adaptation table: errors to one decimal (mm), ratios to two."""
    ratios = [label for label in table.index if str(label).startswith("ratio ")]
    errors = table.drop(index=ratios).to_string(float_format=lambda v: f"{v:.1f}")
    ratio_text = table.loc[ratios].to_string(float_format=lambda v: f"{v:.2f}")
    return ("Sweep adaptation: each run's hysteresis identified on its own tracked sweep "
            f"(mm)\n{errors}\n{ratio_text}")


@validate_params({"tables": [dict], "result": [Bunch, None]}, prefer_skip_nested_validation=True)
def format_report(tables, result=None):
    """The protocol's tables as text, in the order of the paper.

    Parameters
    ----------
    tables : dict of pandas.DataFrame
        Output of :func:`compute_tables`.
    result : sklearn.utils.Bunch, optional
        Output of :func:`run_protocol`, for the header (schedule, seeds, time).

    Returns
    -------
    text : str
    """
    parts = []
    if result is not None:
        s = result.schedule
        folds = "one setting held out" if s.n_setting_folds is None else f"{s.n_setting_folds} setting folds"
        parts.append(
            f"schedule: {s.name} ({folds} per catheter, seeds {list(s.seeds)}); "
            f"{result.X['run'].nunique()} evaluated runs; "
            f"not evaluated: {list(result.exclude_settings) or 'none'}; "
            f"wall time {result.elapsed / 60:.1f} min"
        )
    parts.append("Table I. Tip-position RMSE (mm), setting held out within each catheter\n"
                 + _mm(tables["table_1"]))
    if "table_2" in tables:
        parts.append("Table II. Torque/context ablation RMSE (mm)\n" + _mm(tables["table_2"]))
    if "residual_learners" in tables:
        parts.append(_residual_learners_text(tables["residual_learners"]))
    if "loco" in tables:
        t = tables["loco"]
        text = t.drop(index=t.index[-1]).to_string(float_format=lambda v: f"{v:.1f}")
        below = " ".join(f"{c}: {v:.0f}%" for c, v in t.iloc[-1].items())
        parts.append(f"Leave one catheter out: {LOCO_VARIANT} trained on the other catheters only (mm)\n"
                     f"{text}\nruns below 4 mm (LOCO): {below}")
    if "adaptation" in tables:
        parts.append(_adaptation_text(tables["adaptation"]))
    parts.append("Samples below 5 mm (%, within-run fractions averaged over runs)\n"
                 + tables["cdf_at_5mm"].to_string(float_format=lambda v: f"{v:.0f}"))
    main = [m for m in MAIN_METHODS if m in tables["magnitude"]]
    parts.append("RMSE by motor-input magnitude (median run-bin RMSE, mm)\n"
                 + _mm(_bins(tables["magnitude"][main], "deg")))
    parts.append("RMSE over motion time (mean run-bin RMSE, mm)\n"
                 + _mm(_bins(tables["time"][main], "s")))
    paired = tables["paired"]
    if not paired.empty:
        pooled = paired[paired["scope"] == "pooled"].set_index("comparison")
        show = pd.DataFrame({
            "reduction (mm)": pooled["reduction_mm"],
            "95% low": pooled["ci_low_mm"],
            "95% high": pooled["ci_high_mm"],
            "reduction (%)": pooled["reduction_pct"],
            "runs improved (%)": 100 * pooled["fraction_improved"],
        })
        parts.append("Paired reductions, pooled (baseline - candidate; setting-cluster bootstrap)\n"
                     + show.to_string(float_format=lambda v: f"{v:.1f}"))
    return "\n\n".join(parts)


@validate_params(
    {"tables": [dict], "out_dir": [str, os.PathLike], "figures": ["boolean"]},
    prefer_skip_nested_validation=True,
)
def write_results(tables, out_dir, *, figures=True):
    """Write the tables as CSV and, if matplotlib is installed, the figures as PNG.

    Parameters
    ----------
    tables : dict of pandas.DataFrame
        Output of :func:`compute_tables`.
    out_dir : str or path-like
        Folder (created if missing).
    figures : bool, default=True
        Also draw the figures (needs matplotlib: ``pip install "skcath[plot]"``).

    Returns
    -------
    paths : list of pathlib.Path
        The files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for key, name in TABLE_FILES.items():
        if key in tables:
            path = out / name
            tables[key].to_csv(path, index=key not in _LONG_TABLES, float_format="%.6g")
            paths.append(path)
    if figures:
        figure_tables = {key: tables[key] for key in FIGURE_TABLES if key in tables}
        paths.extend(write_figures(figure_tables, out))
    return paths
