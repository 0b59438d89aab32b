"""Coordinate frames: tip position in the base frame from two sensor poses.

An electromagnetic (EM) tracker reports the pose of each 6-DOF sensor in its
own world frame W. With one sensor at the tip of the catheter (T) and one at
the base of the bending section (B), the tip position expressed in the base
frame is

.. math::

    p = R_{WB}^{\\top} \\, (p_{WT} - p_{WB}),

where :math:`p_{WT}` and :math:`p_{WB}` are the sensor positions in W (mm)
and :math:`R_{WB}` is the orientation of the base sensor in W. Expressed in
B, the tip position no longer depends on where the catheter lies in the
tracker volume, only on how the bending section is bent.

A second frame, the **sweep frame** S (:func:`sweep_frame`), is fixed by the
bending response that a run's initial sweep measures: its z axis points from
the base to the neutral tip and its x axis along the tip's motion when the
first motor turns positive. Expressed in S, residuals of different catheters
no longer depend on how the base sensor happens to be mounted (its roll about
the catheter and its tilt), which is what lets a residual learner trained on
some catheters transfer to another.

Quaternions are accepted scalar first (``"wxyz"``, as NDI Aurora exports
write them) or scalar last (``"xyzw"``, as SciPy and ROS use them).
:func:`fit_quat_order` tells from the data which of the two orders the stored
components fit, where the runs of a catheter allow it: the neutral tip of a
catheter points the same way in the base frame in every run only when the
base quaternions are read in their own order.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from ._format import QUAT_ORDERS
from ._quat_order import MIN_SPREAD_RATIO, QuatOrderFit, fit_quat_order, neutral_rows
from ._validation import check_quat_order, check_tip_offset, to_array

__all__ = [
    "FRAMES",
    "MIN_SPREAD_RATIO",
    "QUAT_ORDERS",
    "QuatOrderFit",
    "fit_quat_order",
    "neutral_rows",
    "quaternion_to_rotation",
    "sweep_frame",
    "tip_in_base_frame",
]

#: Frames a residual learner can work in: each run's sweep frame, or the base frame B.
FRAMES = ("sweep", "base")

# Column permutation that brings a quaternion of the given order to the
# scalar-last (x, y, z, w) layout that ``Rotation.from_quat`` expects.
_TO_XYZW = {"wxyz": [1, 2, 3, 0], "xyzw": [0, 1, 2, 3]}

# Quaternions with a norm below this are treated as zero (no orientation).
_MIN_QUAT_NORM = 1e-12


def _as_float_rows(values, name, width):
    """Convert an array-like to a new float array of shape ``(n, width)``.

    Parameters
    ----------
    values : array-like
        Input given by the caller; never modified.
    name : str
        Parameter name used in error messages.
    width : int
        Required number of columns.

    Returns
    -------
    array : ndarray of shape (n, width), dtype float64
        A copy of the input.

    Raises
    ------
    ValueError
        If the input is not numeric or does not have shape ``(n, width)``.
    """
    array = to_array(
        values, f"{name} must be a numeric array of shape (n, {width})", dtype=np.float64, copy=True
    )
    if array.ndim != 2 or array.shape[1] != width:
        hint = f" (for a single sample use shape (1, {width}))" if array.ndim == 1 else ""
        raise ValueError(
            f"{name} must have shape (n, {width}); got shape {array.shape}{hint}."
        )
    return array


def quaternion_to_rotation(q, quat_order="wxyz"):
    """Build a SciPy rotation from quaternions in a given component order.

    Parameters
    ----------
    q : array-like of shape (4,) or (n, 4)
        Quaternion(s), not necessarily of unit norm (they are normalised).
        Every value must be finite.
    quat_order : {"wxyz", "xyzw"}, default="wxyz"
        Component order of ``q``: scalar first (``"wxyz"``, NDI Aurora) or
        scalar last (``"xyzw"``, SciPy, ROS).

    Returns
    -------
    rotation : scipy.spatial.transform.Rotation
        A single rotation for a ``(4,)`` input, otherwise a stack of ``n``
        rotations.

    Raises
    ------
    ValueError
        If ``quat_order`` is unknown, ``q`` has the wrong shape, contains a
        non-finite value, or has a zero-norm row.

    Examples
    --------
    >>> from skcath.frames import quaternion_to_rotation
    >>> quaternion_to_rotation([1.0, 0.0, 0.0, 0.0]).as_matrix().round(3)
    array([[1., 0., 0.],
           [0., 1., 0.],
           [0., 0., 1.]])
    """
    quat_order = check_quat_order(quat_order)
    quats = to_array(
        q, "q must be a numeric array of shape (4,) or (n, 4)", dtype=np.float64, copy=True
    )
    single = quats.ndim == 1
    if single:
        quats = quats[None, :]
    if quats.ndim != 2 or quats.shape[1] != 4:
        raise ValueError(f"q must have shape (4,) or (n, 4); got shape {np.shape(q)}.")
    bad = np.flatnonzero(~np.isfinite(quats).all(axis=1))
    if bad.size:
        raise ValueError(
            f"q has a non-finite value at row {int(bad[0])}; "
            "a rotation needs four finite components."
        )
    rotation = _rotations(quats, quat_order, "q", np.arange(quats.shape[0]))
    return rotation[0] if single else rotation


def tip_in_base_frame(
    tip_position,
    base_position,
    base_orientation,
    *,
    quat_order="wxyz",
    tip_offset=None,
    tip_orientation=None,
):
    """Express the tip position in the frame at the base of the bending section.

    Implements :math:`p = R_{WB}^{\\top} (p_{WT} - p_{WB})`, where W is the
    tracker (world) frame, B the base sensor and T the tip. With
    ``tip_offset`` the tip is the point at a fixed offset :math:`o` from the
    tip sensor, given in the tip sensor frame:
    :math:`p_{WT} = p_{WS} + R_{WS}\\, o`, with S the tip sensor.

    Parameters
    ----------
    tip_position : array-like of shape (n, 3)
        Tip sensor position in the tracker frame (mm).
    base_position : array-like of shape (n, 3)
        Base sensor position in the tracker frame (mm).
    base_orientation : array-like of shape (n, 4)
        Base sensor orientation in the tracker frame as quaternions in the
        order ``quat_order``. They are normalised, so they need not be
        exactly unit.
    quat_order : {"wxyz", "xyzw"}, default="wxyz"
        Component order of the quaternions: scalar first (``"wxyz"``, as NDI
        Aurora exports write them) or scalar last (``"xyzw"``, SciPy, ROS).
    tip_offset : array-like of shape (3,), default=None
        Position of the real tip relative to the tip sensor, in the tip sensor
        frame (mm). Requires ``tip_orientation``.
    tip_orientation : array-like of shape (n, 4), default=None
        Tip sensor orientation in the tracker frame, same quaternion order as
        ``base_orientation``. Only used with ``tip_offset``; without it the
        values are ignored (only the shape is checked).

    Returns
    -------
    p : ndarray of shape (n, 3)
        Tip position in the base frame B (mm). A row is NaN wherever any input
        row has a non-finite value (a tracker dropout is written as NaN); the
        other rows are unaffected.

    Raises
    ------
    ValueError
        If an array has the wrong shape or is not numeric, the row counts
        differ, ``quat_order`` is unknown, ``tip_offset`` is given without
        ``tip_orientation`` or is not three finite numbers, or a finite
        quaternion has zero norm (the message names the argument and the row).

    Notes
    -----
    The inputs are never modified.

    Examples
    --------
    >>> import numpy as np
    >>> from skcath.frames import tip_in_base_frame
    >>> # base sensor at (10, 0, 0), rotated by 90 degrees about z
    >>> q = [[np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]]
    >>> p = tip_in_base_frame([[10.0, 80.0, 0.0]], [[10.0, 0.0, 0.0]], q)
    >>> p.round(6) + 0.0
    array([[80.,  0.,  0.]])
    """
    quat_order = check_quat_order(quat_order)
    p_wt = _as_float_rows(tip_position, "tip_position", 3)
    p_wb = _as_float_rows(base_position, "base_position", 3)
    q_wb = _as_float_rows(base_orientation, "base_orientation", 4)
    used = {"tip_position": p_wt, "base_position": p_wb, "base_orientation": q_wb}

    q_ws = None
    if tip_orientation is not None:
        q_ws = _as_float_rows(tip_orientation, "tip_orientation", 4)
    offset = None
    if tip_offset is not None:
        if q_ws is None:
            raise ValueError(
                "tip_offset is given in the tip sensor frame, so tip_orientation "
                "(n, 4) is required as well; got tip_orientation=None."
            )
        offset = check_tip_offset(tip_offset)
        used["tip_orientation"] = q_ws

    n = p_wt.shape[0]
    given = dict(used, tip_orientation=q_ws) if q_ws is not None else used
    for name, array in given.items():
        if array.shape[0] != n:
            raise ValueError(
                f"{name} has {array.shape[0]} rows but tip_position has {n}; "
                "all pose arrays must have one row per sample."
            )

    finite = np.ones(n, dtype=bool)
    for array in used.values():
        finite &= np.isfinite(array).all(axis=1)

    result = np.full((n, 3), np.nan)
    if not finite.any():
        return result

    rows = np.flatnonzero(finite)
    r_wb = _rotations(q_wb[finite], quat_order, "base_orientation", rows)
    tip = p_wt[finite]
    if offset is not None:
        r_ws = _rotations(q_ws[finite], quat_order, "tip_orientation", rows)
        tip = tip + r_ws.apply(offset)
    result[finite] = r_wb.inv().apply(tip - p_wb[finite])
    return result


def _rotations(quats, quat_order, name, rows):
    """Build rotations from finite quaternion rows, normalising them.

    Parameters
    ----------
    quats : ndarray of shape (m, 4)
        Finite quaternion rows, in the order ``quat_order``.
    quat_order : {"wxyz", "xyzw"}
        Component order.
    name : str
        Parameter name used in error messages.
    rows : ndarray of int, shape (m,)
        Index, in the caller's array, of each row of ``quats``, so that an
        error names the row the caller sees.

    Returns
    -------
    rotation : scipy.spatial.transform.Rotation
        Stack of ``m`` rotations.

    Raises
    ------
    ValueError
        If a row has (near) zero norm; the message names the first such row.
    """
    norms = np.linalg.norm(quats, axis=1)
    zero = np.flatnonzero(norms < _MIN_QUAT_NORM)
    if zero.size:
        raise ValueError(
            f"{name} has a zero-norm quaternion at row {int(rows[zero[0]])} "
            f"({zero.size} such row(s) in total); a rotation needs a nonzero "
            "quaternion. Mark missing samples with NaN instead."
        )
    unit = quats / norms[:, None]
    return Rotation.from_quat(unit[:, _TO_XYZW[quat_order]])


#: Smallest tip motion (mm) across the first motor's sweep range, normal to the
#: neutral direction, for the sweep frame's x axis to be defined.
_MIN_FRAME_MOTION_MM = 1e-3


def _quadratic_design(q):
    """Columns ``1, q_i, q_i q_j (i <= j)`` of a quadratic in the motor angles ``q`` (n, N).

    For two motors ``1, q1, q2, q1^2, q1 q2, q2^2``.
    """
    n_motors = q.shape[1]
    squares = [q[:, i] * q[:, j] for i in range(n_motors) for j in range(i, n_motors)]
    return np.column_stack([np.ones(q.shape[0]), *q.T, *squares])


def sweep_frame(q, p, *, run=None, n_motors=2):
    r"""Rotation from the base frame B to the sweep frame S of one run.

    The tip positions of the sweep are fitted by a quadratic in the motor
    angles, :math:`p(q) \approx c + A q + Q(q)`, by least squares. The axes of
    S, expressed in B, are

    .. math::

        e_z = \frac{c}{\lVert c \rVert}, \qquad
        e_x = \frac{a_1 - (a_1 \cdot e_z) e_z}{\lVert a_1 - (a_1 \cdot e_z) e_z \rVert},
        \qquad e_y = e_z \times e_x,

    where :math:`c` is the fitted neutral tip and :math:`a_1` the first
    column of :math:`A` (the tip's motion per degree of the first motor at
    neutral). The returned matrix :math:`R_{SB}` has rows
    :math:`e_x, e_y, e_z`, so that a vector ``v`` in B is ``R @ v`` in S.
    Rotating every tip position of a run by any rotation ``G`` turns the
    result into ``R @ G.T``: vectors expressed in S do not change.

    Parameters
    ----------
    q : array-like of shape (n, n_motors)
        Motor angles of the sweep samples (degrees). The sweep must move
        every motor (at
        least as many samples as the quadratic has coefficients, ``1 + N +
        N (N + 1) / 2``: 6 for two motors, not all on one conic).
    p : array-like of shape (n, 3)
        Tip positions of the same samples in the base frame (mm): the EM
        reference, or a backbone's nominal tip. Rows with a non-finite value
        are ignored.
    run : str, optional
        Run id, named in error messages.
    n_motors : int, default=2
        Number of motors ``N``, the columns of ``q``.

    Returns
    -------
    R : ndarray of shape (3, 3)
        Rotation matrix :math:`R_{SB}` (orthonormal, determinant 1).

    Raises
    ------
    ValueError
        If the shapes are wrong, fewer finite samples remain than the
        quadratic has coefficients, the motor angles do not determine a
        quadratic (e.g. only one of two motors moves), or the tip does not
        move along the first motor's direction.

    Examples
    --------
    >>> import numpy as np
    >>> from skcath.frames import sweep_frame
    >>> q = np.array([[0, 0], [30, 0], [-30, 0], [0, 30], [0, -30], [20, 20], [-20, 20]])
    >>> p = np.c_[q[:, 1] * 0.5, -q[:, 0] * 0.5, np.full(7, 50.0)]  # q1 moves the tip to -y
    >>> sweep_frame(q, p).round(3) + 0.0
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    where = "" if run is None else f" of run {run!r}"
    q = _as_float_rows(q, "q", n_motors)
    p = _as_float_rows(p, "p", 3)
    if q.shape[0] != p.shape[0]:
        raise ValueError(
            f"q and p must have the same number of rows{where}; got {q.shape[0]} and {p.shape[0]}."
        )
    return _sweep_frame(q, p, run)


def _sweep_frame(q, p, run=None):
    """:func:`sweep_frame` of float64 arrays ``q`` (n, n_motors) and ``p`` (n, 3) of equal length.

    For the checked sweep rows of a run (``run``: its id, for the
    messages): not converted again, and never modified.
    """
    where = "" if run is None else f" of run {run!r}"
    keep = np.isfinite(q).all(axis=1) & np.isfinite(p).all(axis=1)
    q, p = q[keep], p[keep]
    design = _quadratic_design(q)
    if q.shape[0] < design.shape[1]:
        raise ValueError(
            f"The sweep frame{where} needs at least {design.shape[1]} sweep samples with "
            f"finite motor angles and tip positions; got {q.shape[0]}."
        )
    q1 = q[:, 0]
    scale = np.abs(design).max(axis=0)
    scale[scale == 0] = 1.0
    coef, _, rank, _ = np.linalg.lstsq(design / scale, p, rcond=None)
    if rank < design.shape[1]:
        raise ValueError(
            f"The motor angles of the sweep{where} do not determine the sweep frame: "
            f"a quadratic fit in the {q.shape[1]} motor angle(s) is rank deficient. The "
            "sweep must move every motor, two motors in several directions (the 8-ray "
            "sweep does)."
        )
    coef = coef / scale[:, None]
    neutral, a1 = coef[0], coef[1]
    norm = np.linalg.norm(neutral)
    if not norm > 0:
        raise ValueError(f"The fitted neutral tip of the sweep{where} is at the base frame's origin.")
    ez = neutral / norm
    ex = a1 - (a1 @ ez) * ez
    moved = np.linalg.norm(ex) * max(np.ptp(q1), 1.0)
    if not moved > _MIN_FRAME_MOTION_MM:
        raise ValueError(
            f"The tip does not move when the first motor turns in the sweep{where}, so "
            "the sweep frame's x axis is undefined."
        )
    ex = ex / np.linalg.norm(ex)
    return np.stack([ex, np.cross(ez, ex), ez])
