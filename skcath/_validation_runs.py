"""Checks of recordings that span the rows of a run.

The ids of a run (one catheter and one setting), its phases (the sweep
first), its time axis (strictly increasing) and the sampling of its motion
rows (no missing samples), for :func:`skcath.check_recordings`. All are
vectorised over the rows sorted by run.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ._format import CATHETER, MOTION, PHASE, PHASES, REFERENCE_COLUMNS, RUN, SWEEP, TIME
from ._medians import group_medians
from ._validation_columns import _factorize, _list_items, _plain, factorize_ids

__all__ = ["CUT_RUN_HINT", "MAX_GAP_FRACTION", "check_sweeps"]

#: Motion rows of a run are consecutive samples at a constant rate. A run
#: with at least ``_MIN_MOTION_STEPS`` motion steps is refused when more than
#: this fraction of them are longer than ``_GAP_FACTOR`` times its median step:
#: rows are missing, as in a fold of a shuffled ``KFold`` or a random row
#: selection (a fold keeping 80 % of the rows leaves 20 % such steps).
MAX_GAP_FRACTION = 0.05
_GAP_FACTOR = 1.5
_MIN_MOTION_STEPS = 20

#: How to keep the runs whole, added to the messages of the checks that a
#: subset of a run fails (no sweep rows, missing motion rows).
CUT_RUN_HINT = (
    "If X is a subset of the recordings (a cross-validation fold, a row selection), "
    "it cut a run: keep all rows of a run together, for example cv=GroupKFold(n_splits) "
    "with groups=X['run'], or a splitter of skcath.model_selection such as "
    "LeaveOneSettingOut(). KFold, the default cv of cross_val_score and "
    "cross_validate, cuts runs. See docs/evaluation.rst."
)


def _check_run_ids_unique(
    X: pd.DataFrame, codes: np.ndarray, runs: np.ndarray, column: str
) -> None:
    """Raise if a run id appears with more than one value of ``column``."""
    other_codes, other_values = factorize_ids(X, column)
    # a run holds a single value exactly when its smallest and largest codes agree
    lowest = np.full(len(runs), len(other_values), dtype=np.intp)
    highest = np.full(len(runs), -1, dtype=np.intp)
    np.minimum.at(lowest, codes, other_codes)
    np.maximum.at(highest, codes, other_codes)
    bad_runs = np.flatnonzero(lowest != highest)
    if not bad_runs.size:
        return
    run = int(bad_runs[0])
    values = other_values[np.unique(other_codes[codes == run])]
    noun = "catheters" if column == CATHETER else "settings"
    raise ValueError(
        f"Run id {_plain(runs[run])!r} is used for several {noun} "
        f"({column!r} values {_list_items(values)}); a run id must belong to "
        f"exactly one catheter and one setting. Runs affected: "
        f"{_list_items(runs[bad_runs])}."
    )


def _phase_masks(X: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks of sweep and motion rows; raise on any other phase value."""
    codes, uniques = _factorize(X, PHASE, f"contain only {list(PHASES)}")
    bad = [value for value in uniques if value not in PHASES]
    n_missing = int(np.count_nonzero(codes < 0))
    if n_missing:
        bad.append(None)
    if bad:
        raise ValueError(
            f"Column {PHASE!r} must contain only {list(PHASES)}; found invalid "
            f"value(s) {_list_items(bad)}"
            + (f" ({n_missing} missing)" if n_missing else "")
            + "."
        )
    is_sweep = np.zeros(len(uniques), dtype=bool)
    is_sweep[[i for i, value in enumerate(uniques) if value == SWEEP]] = True
    sweep = is_sweep[codes]
    return sweep, ~sweep


def _check_every_run_swept(sweep, codes, runs, needed_by=None, without=None) -> None:
    """Raise if a run of the codes ``codes`` has no row of the mask ``sweep``.

    ``needed_by`` names what reads the sweep and ``without`` says what to do
    for recordings without one; both enter the message when given.
    """
    n_sweep = np.bincount(codes[sweep], minlength=len(runs))
    no_sweep = np.flatnonzero(n_sweep == 0)
    if not no_sweep.size:
        return
    why = (
        "every run must start with its calibration sweep"
        if needed_by is None
        else f"{needed_by} reads the calibration sweep at the start of every run"
    )
    raise ValueError(
        f"Run(s) {_list_items(runs[no_sweep])} have no {SWEEP!r} rows; {why} (rows with "
        f"{PHASE!r} == {SWEEP!r} and the reference tip {list(REFERENCE_COLUMNS)}). "
        + ("" if without is None else without + " ")
        + CUT_RUN_HINT
    )


def check_sweeps(X: pd.DataFrame, needed_by: str, without: str) -> None:
    """Raise unless every run of checked recordings has sweep rows.

    For the estimators that read the sweep only with some of their
    parameters: they check the recordings with ``require_sweep=False`` and
    then call this when their parameters need the sweep.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings checked by :func:`check_recordings` (with the ``run`` and
        ``phase`` columns); never modified.
    needed_by : str
        What reads the sweep, e.g. ``"GRUResidual(frame='sweep')"``.
    without : str
        What to do instead for recordings without a sweep, one sentence.

    Raises
    ------
    ValueError
        Naming the runs without sweep rows, ``needed_by`` and ``without``.
    """
    codes, runs = factorize_ids(X, RUN)
    _check_every_run_swept((X[PHASE] == SWEEP).to_numpy(), codes, runs, needed_by, without)


def _check_phase_order(
    X: pd.DataFrame,
    sweep: np.ndarray,
    codes: np.ndarray,
    runs: np.ndarray,
    order: np.ndarray,
    *,
    require_sweep: bool,
) -> None:
    """Raise if a run has no sweep rows or a sweep row follows a motion row."""
    if require_sweep:
        _check_every_run_swept(sweep, codes, runs)
    sorted_sweep = sweep[order]
    sorted_codes = codes[order]
    late = sorted_sweep[1:] & ~sorted_sweep[:-1] & (sorted_codes[1:] == sorted_codes[:-1])
    if late.any():
        i = int(np.flatnonzero(late)[0])
        prev, cur = int(order[i]), int(order[i + 1])
        raise ValueError(
            f"In run {_plain(runs[sorted_codes[i]])!r} a {SWEEP!r} row (row label "
            f"{_plain(X.index[cur])!r}) follows a {MOTION!r} row (row label "
            f"{_plain(X.index[prev])!r}); each run must start with its calibration "
            f"sweep, followed by the {MOTION!r} rows."
        )


def _check_time_order(
    X: pd.DataFrame,
    t: np.ndarray,
    codes: np.ndarray,
    runs: np.ndarray,
    order: np.ndarray,
) -> None:
    """Raise if time is not strictly increasing within a run, in row order."""
    if order.size < 2:
        return
    sorted_t = t[order]
    sorted_codes = codes[order]
    same_run = sorted_codes[1:] == sorted_codes[:-1]
    with np.errstate(invalid="ignore"):
        not_increasing = same_run & ~(np.diff(sorted_t) > 0)
    if not not_increasing.any():
        return
    hits = np.flatnonzero(not_increasing)
    i = int(hits[0])
    prev, cur = int(order[i]), int(order[i + 1])
    n_runs_bad = np.unique(sorted_codes[hits]).size
    raise ValueError(
        f"Column {TIME!r} must be strictly increasing within each run (rows of a "
        f"run in time order); run {_plain(runs[sorted_codes[i]])!r} goes from "
        f"t={_plain(t[prev])!r} s at row label {_plain(X.index[prev])!r} to "
        f"t={_plain(t[cur])!r} s at row label {_plain(X.index[cur])!r} "
        f"({hits.size} such step(s) in {n_runs_bad} run(s))."
    )


def _check_motion_sampling(
    t: np.ndarray,
    motion: np.ndarray,
    codes: np.ndarray,
    runs: np.ndarray,
    order: np.ndarray,
) -> None:
    """Raise if a run's motion rows miss samples (a cut run), see :data:`MAX_GAP_FRACTION`."""
    rows = order[motion[order]]  # motion rows, those of every run together in row order
    same_run = codes[rows][1:] == codes[rows][:-1]
    step_run = codes[rows][1:][same_run]
    steps = np.diff(t[rows])[same_run]
    n_steps = np.bincount(step_run, minlength=len(runs))
    median = group_medians(steps, step_run, len(runs))
    n_gaps = np.bincount(
        step_run, weights=steps > _GAP_FACTOR * median[step_run], minlength=len(runs)
    )
    bad = np.flatnonzero(
        (n_steps >= _MIN_MOTION_STEPS) & (n_gaps > MAX_GAP_FRACTION * n_steps)
    )
    if not bad.size:
        return
    k = int(bad[0])
    raise ValueError(
        f"The {MOTION!r} rows of run {_plain(runs[k])!r} miss samples: {int(n_gaps[k])} of "
        f"their {int(n_steps[k])} time steps ({100.0 * n_gaps[k] / n_steps[k]:.0f} %, at "
        f"most {100.0 * MAX_GAP_FRACTION:g} % allowed) are longer than {_GAP_FACTOR:g} "
        f"times the run's median step of {median[k]:.3g} s, while a run is recorded at a "
        f"constant rate. Runs affected: {_list_items(runs[bad])}. " + CUT_RUN_HINT
        + " If the motor log itself has gaps, cut the run at each gap."
    )
