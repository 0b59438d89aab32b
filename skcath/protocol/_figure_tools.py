"""Shared pieces of the protocol figures: table checks, blank figures, colours, boxes and legends.

:data:`TABLE_COLUMNS` fixes the columns of every summary table that the
figures draw; :func:`_check_table` checks a table against it with messages
naming the table and the column. :func:`_new_figure` builds a standalone
figure on the Agg canvas (matplotlib is imported only then), and the other
helpers select methods, colour them, place and draw box plots and put the
legend below the axes.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

import numpy as np
import pandas as pd
from pandas.api import types as pdt

from ._methods import METHODS

#: Columns of each summary table, keyed by the table name used by
#: :func:`write_figures`.
TABLE_COLUMNS = {
    "run_rmse": ("method", "catheter", "setting", "run", "rmse_mm"),
    "cdf": ("method", "error_mm", "fraction"),
    "magnitude_bins": ("method", "run", "bin_left", "bin_right", "rmse_mm"),
    "time_bins": ("method", "run", "bin_left", "bin_right", "rmse_mm"),
    "paired": (
        "comparison",
        "scope",
        "reduction_mm",
        "ci_low_mm",
        "ci_high_mm",
        "reduction_pct",
        "fraction_improved",
    ),
    "example": ("t", "p_x", "p_y", "p_z", "phat_x", "phat_y", "phat_z"),
}

#: Scope label of the group (box plots) or row (forest plot) over all catheters.
POOLED = "pooled"

_FIGSIZE = (8.0, 4.5)
_SPARE_COLOURS = ("tab:cyan", "tab:gray", "#1b3a6b", "#8c5a00", "#006d5b", "#7a1f5c")


def _new_figure(figsize=_FIGSIZE):
    """Create a standalone figure on the Agg canvas with constrained layout.

    Parameters
    ----------
    figsize : tuple of float
        Width and height in inches.

    Returns
    -------
    figure : matplotlib.figure.Figure

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(
            'Drawing the protocol figures needs matplotlib: pip install "skcath[plot]"'
        ) from exc
    figure = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _check_table(table, name, *, numeric=(), finite=(), no_inf=()):
    """Check that ``table`` is a non-empty DataFrame with the columns of ``name``.

    Parameters
    ----------
    table : object
        The table to check.
    name : str
        Key of the table in :data:`TABLE_COLUMNS`, used in the messages.
    numeric : sequence of str
        Columns that must hold numbers.
    finite : sequence of str
        Numeric columns that must be finite on every row.
    no_inf : sequence of str
        Numeric columns that may hold NaN but never +-inf.

    Raises
    ------
    ValueError
        If ``table`` is not a DataFrame, is empty, lacks a column, or holds a
        value of the wrong kind; the message names the table and the column.
    """
    expected = TABLE_COLUMNS[name]
    listed = ", ".join(expected)
    if not isinstance(table, pd.DataFrame):
        raise ValueError(
            f"The {name!r} table must be a pandas DataFrame with the columns {listed}; "
            f"got {type(table).__name__}."
        )
    missing = ", ".join(repr(column) for column in expected if column not in table.columns)
    if missing:
        raise ValueError(f"The {name!r} table lacks the column(s) {missing}; expected the columns {listed}.")
    if len(table) == 0:
        raise ValueError(f"The {name!r} table is empty; expected at least one row.")
    for column in (*numeric, *finite, *no_inf):
        values = table[column]
        if not pdt.is_numeric_dtype(values) or pdt.is_bool_dtype(values):
            raise ValueError(
                f"Column {column!r} of the {name!r} table must hold numbers; "
                f"got dtype {values.dtype}."
            )
    for column in finite:
        values = table[column].to_numpy(dtype=float)
        if not np.isfinite(values).all():
            raise ValueError(
                f"Column {column!r} of the {name!r} table must be finite on every row; "
                f"found {int((~np.isfinite(values)).sum())} NaN or infinite value(s)."
            )
    for column in no_inf:
        values = table[column].to_numpy(dtype=float)
        if np.isinf(values).any():
            raise ValueError(
                f"Column {column!r} of the {name!r} table must not hold infinite values "
                f"(NaN marks a missing value)."
            )


def _as_labels(values, argument):
    """Turn ``values`` (one label or an iterable of labels) into a tuple without repeats."""
    if isinstance(values, str):
        values = (values,)
    if not isinstance(values, Iterable):
        raise ValueError(f"{argument} must be a label or a sequence of labels; got {values!r}.")
    labels = tuple(dict.fromkeys(values))
    if not labels:
        raise ValueError(f"{argument} must name at least one label; got an empty sequence.")
    return labels


def _select(table, column, requested, name, argument):
    """The requested labels present in ``table[column]``, in the requested order.

    Absent labels are skipped; a ValueError is raised if none is present.
    """
    requested = _as_labels(requested, argument)
    available = list(pd.unique(table[column]))
    present = [label for label in requested if label in set(available)]
    if not present:
        raise ValueError(
            f"None of the requested {argument} {list(requested)!r} is in column {column!r} "
            f"of the {name!r} table; it holds {available!r}."
        )
    return present


def _method_colours(methods):
    """Colour of every method: fixed for the known methods, spare colours otherwise."""
    colours = {}
    spare = iter(_SPARE_COLOURS * (1 + len(methods) // len(_SPARE_COLOURS)))
    for method in methods:
        colours[method] = METHODS[method].colour if method in METHODS else next(spare)
    return colours


def _natural_key(label):
    """Sort key that orders "C2" before "C10"."""
    parts = re.split(r"(\d+)", str(label))
    return tuple(int(part) if index % 2 else part for index, part in enumerate(parts))


def _offsets(n_items, total_width):
    """Centre offsets and width of ``n_items`` boxes side by side in ``total_width``."""
    width = total_width / n_items
    offsets = (np.arange(n_items) - (n_items - 1) / 2.0) * width
    return offsets, width


def _draw_boxes(ax, data, positions, width, colour, *, showfliers):
    """Draw one method's box plots (median line, quartile box, 1.5 IQR whiskers)."""
    from matplotlib.colors import to_rgba

    if not data:
        return None
    return ax.boxplot(
        data,
        positions=positions,
        widths=width,
        patch_artist=True,
        manage_ticks=False,
        showfliers=showfliers,
        boxprops={"facecolor": to_rgba(colour, 0.55), "edgecolor": colour, "linewidth": 1.2},
        medianprops={"color": "black", "linewidth": 1.4},
        whiskerprops={"color": colour, "linewidth": 1.1},
        capprops={"color": colour, "linewidth": 1.1},
        flierprops={
            "marker": "o",
            "markersize": 3.0,
            "markerfacecolor": to_rgba(colour, 0.6),
            "markeredgecolor": colour,
            "linestyle": "none",
        },
    )


def _legend_columns(labels, width_chars=100):
    """How many legend columns fit across an 8 in wide figure for these labels."""
    n_columns = len(labels)
    while n_columns > 1 and sum(len(label) + 5 for label in labels[:n_columns]) > width_chars:
        n_columns -= 1
    return max(n_columns, 1)


def _figure_legend(figure, handles, labels, *, title=None):
    """Put the legend below the axes, outside them."""
    return figure.legend(
        handles,
        labels,
        loc="outside lower center",
        ncols=_legend_columns(labels),
        frameon=False,
        fontsize="small",
        title=title,
        title_fontsize="small",
    )


def _legend_patch(colour):
    """A legend handle that looks like one of the boxes."""
    from matplotlib.colors import to_rgba
    from matplotlib.patches import Patch

    return Patch(facecolor=to_rgba(colour, 0.55), edgecolor=colour, linewidth=1.2)

