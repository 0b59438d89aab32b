"""Benchmarks whose catheter units differ in kind: each unit's transmission has a mechanism of its own.

``make_benchmark(mechanism="mixed")`` gives unit ``Ck`` the mechanism
``MECHANISMS[(k - 1) % 3]`` (C1 play, C2 Bouc-Wen, C3 Dahl friction with
creep, C4 play, ...); ``mechanism=("play", "bouc_wen", ...)`` names one per
unit. The runs are simulated by grouping the run specifications by
mechanism and calling :func:`simulate_runs` once per group, so that every
unit's runs are those :func:`simulate_runs` gives for the unit's runs alone
with its mechanism; the groups are put back in the order of the units.
"""

import numpy as np
import pandas as pd
from sklearn.utils import Bunch

from .. import _format as fmt
from ._hysteresis import MECHANISMS
from ._simulator import simulate_runs

__all__ = ["MIXED", "simulate_mixed", "unit_mechanisms"]

#: The value of ``mechanism`` that gives unit ``Ck`` the mechanism ``MECHANISMS[(k - 1) % 3]``.
MIXED = "mixed"


def unit_mechanisms(mechanism, numbers):
    """The mechanism of each unit, or None when one mechanism drives every unit.

    Parameters
    ----------
    mechanism : str or sequence of str
        One of :data:`MECHANISMS`, ``"mixed"``, or one mechanism per unit.
    numbers : sequence of int
        The numbers ``k`` of the units ``Ck``, in order.

    Returns
    -------
    mechanisms : list of str or None
        One mechanism per unit; None for a single mechanism (also when a
        sequence names the same mechanism for every unit).

    Raises
    ------
    ValueError
        A sequence of another length than the units, or with a name that is
        no mechanism.
    """
    if isinstance(mechanism, str):
        if mechanism != MIXED:
            return None
        mechanisms = [MECHANISMS[(k - 1) % len(MECHANISMS)] for k in numbers]
    else:
        mechanisms = list(mechanism)
        if len(mechanisms) != len(numbers):
            raise ValueError(
                f"mechanism: a sequence names the mechanism of every catheter unit, one per unit; "
                f"got {len(mechanisms)} for {len(numbers)} units."
            )
        bad = [m for m in mechanisms if not isinstance(m, str) or m not in MECHANISMS]
        if bad:
            raise ValueError(
                f"mechanism: every entry of a sequence must be one of {MECHANISMS}; got {bad!r}."
            )
    return None if len(set(mechanisms)) == 1 else mechanisms


def _split_by_catheter(bunch):
    """The rows of each catheter in ``bunch`` (``X``, ``y``, ``y_true``, ``sensors``, ``runs``)."""
    catheter = bunch.X[fmt.CATHETER].astype(str).to_numpy()
    parts = {}
    for name in pd.unique(catheter):
        rows = np.flatnonzero(catheter == name)
        parts[name] = {
            "X": bunch.X.iloc[rows],
            "y": bunch.y[rows],
            "y_true": bunch.y_true[rows],
            "sensors": bunch.sensors.iloc[rows],
            "runs": bunch.runs[bunch.runs["catheter"] == name],
        }
    return parts


def simulate_mixed(specs, mechanisms, names, **kwargs):
    """Simulate the runs of units of several mechanisms, one :func:`simulate_runs` per mechanism.

    Parameters
    ----------
    specs : list of RunSpec
        Runs to simulate, in unit order.
    mechanisms : list of str
        Mechanism of each unit, in the order of ``names``.
    names : list of str
        Names of the units.
    **kwargs
        Passed on to :func:`simulate_runs` (``field``, ``run_variation``,
        ``rate_hz``).

    Returns
    -------
    bunch : sklearn.utils.Bunch
        As :func:`simulate_runs`, the rows in the order of the units;
        ``mechanism`` is ``"mixed"``, ``mechanisms`` maps each unit to its
        mechanism, and ``runs`` has the column ``mechanism``.
    """
    of_unit = dict(zip(names, mechanisms))
    parts = {}
    for mechanism in dict.fromkeys(mechanisms):
        group = [s for s in specs if of_unit[s.catheter.name] == mechanism]
        parts.update(_split_by_catheter(simulate_runs(group, mechanism=mechanism, **kwargs)))
    ordered = [parts[name] for name in names]
    X = pd.concat([p["X"] for p in ordered], ignore_index=True)
    for col in (*fmt.ID_COLUMNS, fmt.PHASE):
        X[col] = X[col].astype(str).astype("category")
    runs = pd.concat([p["runs"] for p in ordered], ignore_index=True)
    runs["mechanism"] = runs["catheter"].map(of_unit)
    return Bunch(
        X=X,
        y=np.concatenate([p["y"] for p in ordered]),
        y_true=np.concatenate([p["y_true"] for p in ordered]),
        sensors=pd.concat([p["sensors"] for p in ordered], ignore_index=True),
        runs=runs,
        noise_floor=float(runs["noise_floor_mm"].mean()),
        mechanism=MIXED,
        mechanisms=of_unit,
    )
