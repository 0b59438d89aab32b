"""Figures of the evaluation protocol, drawn from its summary tables.

Every function takes one of the summary tables that the protocol computes (a
pandas DataFrame with fixed column names, described in each docstring) and
returns a :class:`matplotlib.figure.Figure`. :func:`write_figures` draws all the
figures whose tables are available and saves them as PNG files with fixed
names.

matplotlib is an optional dependency (``pip install "skcath[plot]"``); it is
imported only when a figure is drawn. The figures are built as standalone
:class:`~matplotlib.figure.Figure` objects attached to the Agg canvas, without
the global state of :mod:`matplotlib.pyplot`, so that drawing works headless
and from several threads at once. The input tables are never modified.

Methods are identified by their label in the ``method`` column (``"PCC"``,
``"PDL"``, ``"PDL+GRU"``, ...). Each method of the protocol keeps the colour
that :data:`~skcath.protocol.METHODS` gives it in every figure.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from numbers import Real
from pathlib import Path

import pandas as pd
from sklearn.utils._param_validation import Interval, validate_params

from ._error_figures import (
    cdf_fraction_at,
    plot_error_by_magnitude,
    plot_error_cdf,
    plot_error_over_time,
    plot_motion_example,
)
from ._figure_tools import TABLE_COLUMNS, _check_table
from ._methods import LOCO_VARIANT, MAIN_METHODS, METHODS, PROPOSED_METHOD, methods_with_role
from ._run_figures import plot_paired_reductions, plot_rmse_boxes

__all__ = [
    "CONDITIONING_METHODS",
    "FIGURE_FILES",
    "NEW_CATHETER_METHODS",
    "RESIDUAL_METHODS",
    "TABLE_COLUMNS",
    "cdf_fraction_at",
    "plot_error_by_magnitude",
    "plot_error_cdf",
    "plot_error_over_time",
    "plot_motion_example",
    "plot_paired_reductions",
    "plot_rmse_boxes",
    "write_figures",
]

#: The two residual learners on top of the PDL backbone.
RESIDUAL_METHODS = methods_with_role("residual_learners")
#: Within-catheter training against training on the other catheters only.
NEW_CATHETER_METHODS = methods_with_role("new_catheter")
#: The GRU residual with and without its torque and context inputs.
CONDITIONING_METHODS = methods_with_role("conditioning")

#: File names written by :func:`write_figures`, in the order they are written.
FIGURE_FILES = (
    "rmse_boxes.png",
    "residual_learners.png",
    "new_catheter.png",
    "conditioning.png",
    "error_cdf.png",
    "error_by_magnitude.png",
    "error_over_time.png",
    "motion_example.png",
    "paired_reductions.png",
)

#: Box-plot figures written by :func:`write_figures`: file name -> (methods,
#: how many of them the table must hold, title). The conditioning figure
#: counts only the ablated variants.
_BOX_FIGURES = {
    "rmse_boxes.png": (MAIN_METHODS, 1, None),
    "residual_learners.png": (
        RESIDUAL_METHODS,
        len(RESIDUAL_METHODS),
        "Residual learners on the {backbone} backbone: {learners}".format(
            backbone=METHODS[RESIDUAL_METHODS[0]].backbone.upper(),
            learners=" and ".join(METHODS[m].learner.upper() for m in RESIDUAL_METHODS),
        ),
    ),
    "new_catheter.png": (
        NEW_CATHETER_METHODS,
        len(NEW_CATHETER_METHODS),
        f"{LOCO_VARIANT} trained on the test catheter and on the other catheters (LOCO)",
    ),
    "conditioning.png": (
        CONDITIONING_METHODS,
        1,
        f"{PROPOSED_METHOD} with and without its torque and context inputs",
    ),
}


# ---------------------------------------------------------------------------
# all figures to files
# ---------------------------------------------------------------------------
def _box_plans(run_rmse):
    """(file name, drawing function) of every box-plot figure whose methods were run."""
    plans = []
    for file_name, (methods, needed, title) in _BOX_FIGURES.items():
        found = _has_methods(run_rmse, methods)
        if file_name == "conditioning.png":  # the full model alone is no ablation
            found = [m for m in found if not (METHODS[m].use_torque and METHODS[m].use_context)]
        if len(found) >= needed:
            plans.append((file_name, lambda m=methods, t=title: plot_rmse_boxes(run_rmse, m, title=t)))
    return plans


def _has_methods(table, methods):
    """Which of ``methods`` appear in the method column of ``table``."""
    available = set(pd.unique(table["method"]))
    return [method for method in methods if method in available]


@validate_params(
    {
        "tables": [Mapping],
        "out_dir": [str, os.PathLike],
        "dpi": [Interval(Real, 0, None, closed="neither")],
    },
    prefer_skip_nested_validation=True,
)
def write_figures(tables: Mapping[str, pd.DataFrame], out_dir, *, dpi: float = 150) -> list[Path]:
    """Draw the protocol figures from its summary tables and save them as PNG.

    The figures whose tables are given are written to ``out_dir`` (created if
    needed) under fixed names, in this order:

    ``rmse_boxes.png``
        :func:`plot_rmse_boxes` of PCC, PDL and PDL+GRU (``run_rmse``).
    ``residual_learners.png``
        PDL+MLP against PDL+GRU, if both are in ``run_rmse``.
    ``new_catheter.png``
        PDL+GRU against PDL+GRU (LOCO), if both are in ``run_rmse``.
    ``conditioning.png``
        The GRU residual with and without torque and context inputs, if
        ``run_rmse`` holds at least one of the ablated variants.
    ``error_cdf.png``
        :func:`plot_error_cdf` (``cdf``).
    ``error_by_magnitude.png``
        :func:`plot_error_by_magnitude` (``magnitude_bins``).
    ``error_over_time.png``
        :func:`plot_error_over_time` (``time_bins``).
    ``motion_example.png``
        :func:`plot_motion_example` (``example``).
    ``paired_reductions.png``
        :func:`plot_paired_reductions` (``paired``).

    A figure of the main methods is skipped when its table holds none of
    PCC, PDL and PDL+GRU.

    Parameters
    ----------
    tables : mapping of str to pandas.DataFrame
        Any of the keys ``run_rmse``, ``cdf``, ``magnitude_bins``,
        ``time_bins``, ``paired`` and ``example`` (see the plotting functions
        for their columns). A missing key or a None value skips its figures.
    out_dir : str or os.PathLike
        Folder of the PNG files.
    dpi : float, default 150
        Resolution of the PNG files (dots per inch).

    Returns
    -------
    paths : list of pathlib.Path
        The written files, in the order above.

    Raises
    ------
    ValueError
        If ``tables`` holds an unknown key, if ``dpi`` is not a positive
        number, or if a table is malformed (see the plotting functions).
    ImportError
        If matplotlib is not installed.
    """
    unknown = [key for key in tables if key not in TABLE_COLUMNS]
    if unknown:
        raise ValueError(
            f"Unknown table name(s) {unknown!r}; expected any of {', '.join(TABLE_COLUMNS)}."
        )
    given = {key: table for key, table in tables.items() if table is not None}
    for key, table in given.items():
        _check_table(table, key)

    plans = _box_plans(given["run_rmse"]) if given.get("run_rmse") is not None else []
    for key, file_name, plot in (
        ("cdf", "error_cdf.png", plot_error_cdf),
        ("magnitude_bins", "error_by_magnitude.png", plot_error_by_magnitude),
        ("time_bins", "error_over_time.png", plot_error_over_time),
    ):
        table = given.get(key)
        if table is not None and _has_methods(table, MAIN_METHODS):
            plans.append((file_name, lambda plot=plot, table=table: plot(table, MAIN_METHODS)))
    if given.get("example") is not None:
        plans.append(("motion_example.png", lambda: plot_motion_example(given["example"])))
    if given.get("paired") is not None:
        plans.append(("paired_reductions.png", lambda: plot_paired_reductions(given["paired"])))

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for file_name, draw in plans:
        figure = draw()
        path = out_dir / file_name
        figure.savefig(path, dpi=dpi)
        figure.clear()
        written.append(path)
    return written
