"""Reading options: how the columns of a table become the long format.

Every reader of :mod:`skcath.io` takes the same keyword options (those of
:func:`skcath.io.read_recording`): which file column holds which skcath
column, the ids, time and phase of files that lack them, constant channels,
unit factors, a validity column and the tip offset. :class:`ReadingOptions`
holds them with their defaults and checks them once, before a file is read.

Column names used here (the "skcath names"):

- ids ``catheter``, ``setting``, ``run``; time ``t`` (s); ``phase``;
  motor angles ``q1 .. qN`` (degrees); torques ``tau1 .. tauN``;
  reference tip ``ref_x``, ``ref_y``, ``ref_z`` (mm, base frame);
- base-frame tip (target) ``p_x``, ``p_y``, ``p_z`` (mm);
- raw sensor poses in the tracker frame: ``tip_px``, ``tip_py``, ``tip_pz``,
  ``tip_qw``, ``tip_qx``, ``tip_qy``, ``tip_qz`` and the same with ``base_``
  (positions in mm, quaternions named by component).
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from dataclasses import dataclass, fields
from types import MappingProxyType

import numpy as np

from .._format import (
    CATHETER, ID_COLUMNS, MOTION, MOTOR_COLUMNS, PHASES, REFERENCE_COLUMNS, REQUIRED_COLUMNS,
    RUN, SENSOR_POSE_COLUMNS, SETTING, TARGET_NAMES, TIME, TORQUE_COLUMNS, TORQUE_PREFIX,
    channel_index,
)
from .._validation import check_quat_order, check_tip_offset

__all__ = ["OPTION_NAMES", "SINGLE_NAMES", "ReadingOptions", "check_option_names"]

#: The ``n_sweep`` that finds each run's sweep from its motor angles.
AUTO_SWEEP = "auto"

_POSE_NAMES = tuple(name for names in SENSOR_POSE_COLUMNS.values() for name in names)
_POSITION_GROUPS = ("tip_position", "base_position")
_ORIENTATION_GROUPS = ("tip_orientation", "base_orientation")
#: Names that ``columns`` may map, one file column each; besides these, any
#: motor or torque channel ``qk``, ``tauk`` (:func:`skcath._format.channel_index`).
SINGLE_NAMES = (*REQUIRED_COLUMNS, *TARGET_NAMES, *_POSE_NAMES)
#: Channels that ``constants`` may set (and any other ``qk``, ``tauk``).
_CONSTANT_NAMES = (*MOTOR_COLUMNS, *TORQUE_COLUMNS)
#: Numeric names that ``scale`` may rescale (quaternions are normalised anyway).
_SCALABLE_NAMES = (
    TIME,
    *MOTOR_COLUMNS,
    *TORQUE_COLUMNS,
    *REFERENCE_COLUMNS,
    *TARGET_NAMES,
    *(n for g in _POSITION_GROUPS for n in SENSOR_POSE_COLUMNS[g]),
)


def _is_real(value) -> bool:
    """True for a real number that is not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _items(values, name, targets):
    """The ``(key, value)`` pairs of a mapping option; none for None.

    Parameters
    ----------
    values : mapping or None
        Option given by the caller.
    name : str
        Option name, for messages.
    targets : str
        What the mapping maps skcath column names to, for messages.

    Raises
    ------
    ValueError
        If ``values`` is not a mapping.
    """
    if values is None:
        return []
    if not hasattr(values, "items"):
        raise ValueError(
            f"{name} must be a mapping from skcath column names to {targets}; "
            f"got {type(values).__name__}."
        )
    return list(values.items())


def _check_group(key, value, quat_order, columns):
    """File columns of a sensor group in ``columns``, keyed by skcath name.

    Raises
    ------
    ValueError
        If ``value`` is not 3 (position) or 4 (orientation, in the order
        ``quat_order``) file column names, an orientation group is given
        without ``quat_order``, or ``columns`` also maps one of the group's
        components.
    """
    names = SENSOR_POSE_COLUMNS[key]
    if key in _ORIENTATION_GROUPS:
        if quat_order is None:
            raise ValueError(
                f"columns[{key!r}] maps the {key.replace('_', ' ')} to the file columns "
                f"{value!r}, but quat_order is not given and skcath does not guess the "
                "component order: pass quat_order='wxyz' if they are w, x, y, z (scalar "
                "first) or quat_order='xyzw' if they are x, y, z, w (scalar last), or map "
                f"the components by name ({key.split('_')[0]}_qw, ...)."
            )
        prefix = key.split("_")[0]
        names = tuple(f"{prefix}_q{c}" for c in quat_order)
        expected = f"4 file column names in the order {quat_order!r}"
    else:
        expected = "3 file column names (x, y, z)"
    if (
        isinstance(value, str)
        or not hasattr(value, "__len__")
        or len(value) != len(names)
        or not all(isinstance(v, str) for v in value)
    ):
        raise ValueError(f"columns[{key!r}] must be {expected}; got {value!r}.")
    for name in names:
        if name in columns:
            raise ValueError(
                f"columns maps both the group {key!r} and its component "
                f"{name!r}; give one or the other."
            )
    return dict(zip(names, value))


def _check_columns(columns, quat_order):
    """Expand ``columns`` into a mapping skcath name -> file column name.

    Parameters
    ----------
    columns : mapping or None
        Keys: skcath names (see the module docstring) or the sensor groups
        ``tip_position``, ``base_position`` (3 file columns x, y, z) and
        ``tip_orientation``, ``base_orientation`` (4 file columns in the order
        ``quat_order``). Values: file column names.
    quat_order : {"wxyz", "xyzw"} or None
        Component order of the file columns listed for an orientation group;
        None when not given (then no orientation group may be mapped).

    Returns
    -------
    mapping : dict of str to str
        Explicit mapping, one entry per skcath name.

    Raises
    ------
    ValueError
        If a key is unknown, a value is not a column name (or a sequence of
        3 or 4 names for a group), an orientation group is given without
        ``quat_order``, or a group and one of its components are both given.
    """
    mapping = {}
    for key, value in _items(columns, "columns", "file column names"):
        if key in SENSOR_POSE_COLUMNS:
            mapping.update(_check_group(key, value, quat_order, columns))
        elif key in SINGLE_NAMES or channel_index(key) is not None:
            if not isinstance(value, str):
                raise ValueError(
                    f"columns[{key!r}] must be a file column name (str); got {value!r}."
                )
            mapping[key] = value
        else:
            raise ValueError(
                f"columns has the unknown key {key!r}; expected one of "
                f"{list(SINGLE_NAMES)} (motors q1 .. qN, torques tau1 .. tauN) or a "
                f"sensor group {list(SENSOR_POSE_COLUMNS)}."
            )
    return mapping


def _check_numbers(values, name, allowed, *, nonzero=False):
    """Validate a mapping skcath column -> finite real number (``constants``, ``scale``).

    Parameters
    ----------
    values : mapping or None
        Mapping given by the caller.
    name : str
        Option name used in error messages.
    allowed : tuple of str
        Keys that are accepted, besides any motor or torque channel
        ``qk``, ``tauk``.
    nonzero : bool, default=False
        Reject zero.

    Returns
    -------
    checked : dict of str to float
        A new dict.

    Raises
    ------
    ValueError
        On an unknown key or a value that is not an accepted real number.
    """
    checked = {}
    for key, value in _items(values, name, "numbers"):
        if key not in allowed and channel_index(key) is None:
            raise ValueError(f"{name} has the key {key!r}; expected one of {list(allowed)}.")
        if not (_is_real(value) and np.isfinite(value) and (value != 0 or not nonzero)):
            what = "a finite nonzero" if nonzero else "a finite"
            raise ValueError(f"{name}[{key!r}] must be {what} real number; got {value!r}.")
        checked[key] = float(value)
    return checked


def _expand_scale(scale):
    """Expand the position groups of ``scale`` to their three components.

    Parameters
    ----------
    scale : mapping or None
        Factors by skcath name; ``tip_position`` / ``base_position`` stand
        for their three components.

    Returns
    -------
    scale : mapping or None
        Same factors keyed by component names only (``scale`` itself when it
        is not a mapping, for :func:`_check_numbers` to reject).
    """
    if scale is None or not hasattr(scale, "items"):
        return scale
    expanded = {}
    for key, value in scale.items():
        for name in SENSOR_POSE_COLUMNS[key] if key in _POSITION_GROUPS else (key,):
            expanded[name] = value
    return expanded


def _check_id(value, name):
    """Raise unless an id given as an option is None, a string or an integer."""
    if value is None or isinstance(value, str):
        return
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
        return
    raise ValueError(f"{name} must be a string or an integer id; got {value!r}.")


def _check_phase(phase, n_sweep):
    """Validate ``phase`` and ``n_sweep`` (at most one of them).

    Raises
    ------
    ValueError
        If both are given or either has an invalid value.
    """
    if phase is not None and n_sweep is not None:
        raise ValueError(
            "Give either phase (one phase for every row) or n_sweep (the first "
            "n_sweep samples of each run are the sweep), not both."
        )
    if phase is not None and phase not in PHASES:
        raise ValueError(f"phase must be one of {list(PHASES)}; got {phase!r}.")
    if n_sweep is not None and n_sweep != AUTO_SWEEP and (
        not isinstance(n_sweep, numbers.Integral)
        or isinstance(n_sweep, (bool, np.bool_))
        or n_sweep < 0
    ):
        raise ValueError(
            f"n_sweep must be a non-negative integer or {AUTO_SWEEP!r} (found from the motor "
            f"angles); got {n_sweep!r}."
        )


def _check_rate(rate_hz):
    """Raise unless ``rate_hz`` is None or a positive finite number (Hz)."""
    if rate_hz is not None and not (_is_real(rate_hz) and np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive finite number (Hz); got {rate_hz!r}.")


def _check_valid(valid):
    """``valid`` as None, a column name, or ``(column, tuple of values meaning valid)``.

    Raises
    ------
    ValueError
        If ``valid`` has another form, or lists no value.
    """
    if valid is None or isinstance(valid, str):
        return valid
    if isinstance(valid, tuple) and len(valid) == 2 and isinstance(valid[0], str):
        column, accepted = valid
        if isinstance(accepted, (str, numbers.Number)):
            accepted = [accepted]
        try:
            accepted = tuple(accepted)
        except TypeError:
            accepted = ()
        if accepted:
            return column, accepted
    raise ValueError(
        "valid must be a file column name, or a tuple (column name, values that "
        f"mean valid) with at least one value; got {valid!r}."
    )


def _check_torques(torques, columns, constants, scale):
    """Raise unless ``torques`` is a bool, and no option names a torque when it is False."""
    if not isinstance(torques, (bool, np.bool_)):
        raise ValueError(
            f"torques must be True (the file has drive torques tau1 .. tauN) or False "
            f"(a rig without torque sensing); got {torques!r}."
        )
    if torques:
        return
    for option, names in (("columns", columns), ("constants", constants), ("scale", scale)):
        named = [k for k in names if (channel_index(k) or ("",))[0] == TORQUE_PREFIX]
        if named:
            raise ValueError(
                f"torques=False reads no torque, but {option} names {named}; leave them "
                "out, or pass torques=True to read the torques."
            )


@dataclass(frozen=True)
class ReadingOptions:
    """The keyword options of the readers of :mod:`skcath.io`, checked.

    The fields are the options of :func:`skcath.io.read_recording`, with the
    same names, defaults and meaning. The checks run when the options are
    made; the checked options are kept in a normalised form (read-only
    copies: the caller's mappings are never modified), so that making
    options again from the fields gives equal options.

    Attributes
    ----------
    columns : mapping of str to str
        skcath name -> file column name, the sensor groups expanded to their
        components (empty when no column is mapped).
    quat_order : {"wxyz", "xyzw"} or None
        Component order of the orientation groups given in ``columns``; None
        when not given, which is allowed only when ``columns`` maps no
        orientation group.
    catheter, setting, run : str, int or None
        Id of all rows, for files without that column.
    rate_hz : float or None
        Sampling rate (Hz), for files without a time column.
    constants : mapping of str to float
        Values of the motor and torque channels the file lacks.
    scale : mapping of str to float
        Factor of every rescaled column, the position groups expanded to
        their components.
    phase : {"sweep", "motion"} or None
        Phase of every row, for files without a phase column.
    n_sweep : int, "auto" or None
        Sweep samples at the start of every run, for files without a phase
        column; ``"auto"`` finds them from the motor angles.
    valid : str, tuple (str, tuple) or None
        Status column, optionally with the values that mean valid.
    tip_offset : tuple of 3 float or None
        Offset of the tip from the tip sensor, tip sensor frame (mm).
    torques : bool
        Whether the recording has drive torques ``tau1 .. tauN``; False for
        a rig without torque sensing (no torque column is read).

    Raises
    ------
    ValueError
        On an invalid option; the message names the option and what was
        expected.
    """

    # the annotations are the normalised forms; the fields take what the readers take
    columns: Mapping[str, str] | None = None
    quat_order: str | None = None
    catheter: str | int | None = None
    setting: str | int | None = None
    run: str | int | None = None
    rate_hz: float | None = None
    constants: Mapping[str, float] | None = None
    scale: float | Mapping[str, float] | None = None
    phase: str | None = None
    n_sweep: int | str | None = None
    valid: str | tuple[str, tuple] | None = None
    tip_offset: tuple[float, float, float] | None = None
    torques: bool = True

    def __post_init__(self):
        quat_order = None if self.quat_order is None else check_quat_order(self.quat_order)
        columns = _check_columns(self.columns, quat_order)
        constants = _check_numbers(self.constants, "constants", _CONSTANT_NAMES)
        scale = _check_numbers(_expand_scale(self.scale), "scale", _SCALABLE_NAMES, nonzero=True)
        for name in ID_COLUMNS:
            _check_id(getattr(self, name), name)
        _check_rate(self.rate_hz)
        _check_phase(self.phase, self.n_sweep)
        valid = _check_valid(self.valid)
        tip_offset = self.tip_offset
        if tip_offset is not None:
            tip_offset = tuple(check_tip_offset(tip_offset).tolist())
        _check_torques(self.torques, columns, constants, scale)
        normalised = {
            "columns": MappingProxyType(columns),
            "constants": MappingProxyType(constants),
            "scale": MappingProxyType(scale),
            "valid": valid,
            "tip_offset": tip_offset,
        }
        for name, value in normalised.items():
            object.__setattr__(self, name, value)

    @classmethod
    def from_kwargs(cls, kwargs, caller):
        """Options from the keyword arguments passed on by a reader.

        Parameters
        ----------
        kwargs : dict
            Keyword arguments given to ``caller``; the options left out take
            their defaults.
        caller : str
            Name of the reader, for messages.

        Returns
        -------
        options : ReadingOptions

        Raises
        ------
        TypeError
            On a keyword that is not a reading option; the message lists the
            options.
        ValueError
            On an invalid option value.
        """
        check_option_names(kwargs, caller)
        return cls(**kwargs)

    @property
    def ids(self):
        """Ids given as options: ``{"catheter": ..., "setting": ..., "run": ...}``."""
        return {CATHETER: self.catheter, SETTING: self.setting, RUN: self.run}

    @property
    def valid_column(self):
        """File column holding the status of every row, or None."""
        return self.valid[0] if isinstance(self.valid, tuple) else self.valid

    @property
    def valid_values(self):
        """Values of :attr:`valid_column` that mean valid, or None for the default rules."""
        return list(self.valid[1]) if isinstance(self.valid, tuple) else None

    @property
    def require_sweep(self):
        """Whether every run must have a sweep: unless the caller chose no sweep."""
        return not (self.phase == MOTION or self.n_sweep == 0)


#: Names of the reading options, in the order of :func:`skcath.io.read_recording`.
OPTION_NAMES = tuple(field.name for field in fields(ReadingOptions))


def check_option_names(kwargs, caller):
    """Raise a TypeError naming the keywords of ``kwargs`` that are not reading options.

    Parameters
    ----------
    kwargs : mapping
        Keyword arguments given to ``caller``.
    caller : str
        Name of the reader, for messages.
    """
    unknown = sorted(set(kwargs) - set(OPTION_NAMES))
    if unknown:
        raise TypeError(
            f"{caller}() got the unknown keyword argument(s) {unknown}; the reading "
            f"options are {list(OPTION_NAMES)}."
        )
