r"""Single-section piecewise-constant-curvature (PCC) backbone.

The motor angles ``q = (q1, q2)`` (degrees) map to bending coordinates and to
the tip position ``p`` (mm) in the frame ``B`` at the base of the bending
section by

.. math::

    \mathbf u = C \frac{\mathbf q - \mathbf q_0}{S_m} + \mathbf u_0,
    \qquad \alpha = \lVert \mathbf u \rVert_2,

    g(\mathbf q) = L R_g \begin{bmatrix}
        u_1 (1 - \cos\alpha) / \alpha^2 \\
        u_2 (1 - \cos\alpha) / \alpha^2 \\
        \sin\alpha / \alpha
    \end{bmatrix},

with ``C`` (2 x 2, rad) the motor coupling, ``q0`` (deg) the motor reference,
``S_m`` (deg) the motor-angle scale, ``u0`` (rad) the resting-curvature
offset, ``L`` (mm) the bending length and ``R_g`` a rotation. ``alpha`` is the
bend angle (rad) of the arc. The ratios are evaluated by their Taylor series in
``alpha^2`` for ``alpha < 2`` and by closed forms above, so the model and its
derivatives are exact (to rounding) at and near ``alpha = 0``.

Gauge. Only ``C / S_m`` and the combined offset ``u0 - C q0 / S_m`` are
identifiable, and a roll ``R_z(gamma)`` of ``R_g`` about its z axis equals a
rotation of ``C`` and ``u0`` in the bending plane
(``R_z(gamma) h(u) = h(Q(gamma) u)``, ``Q`` the 2-D rotation). Calibration
therefore fixes ``q0`` and ``S_m`` and writes ``R_g = exp([w1, w2, 0]^)``: a
rotation about an axis in the xy plane, which still maps ``e_z`` to any
direction. The nine free parameters, in this order, are
``(C11, C12, C21, C22, u0_1, u0_2, L, w1, w2)`` (:data:`PCC_FREE_PARAMETERS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
from sklearn.utils._param_validation import Interval, validate_params

from .._kernel import evaluate_rows, offsets, row_loop, tip_kernel
from ._arrays import frozen_array
from ._lm import levenberg_marquardt

__all__ = [
    "PCC_FREE_PARAMETERS",
    "PCCParams",
    "calibrate_pcc",
    "pcc_jacobian",
    "pcc_kernel",
    "pcc_tip",
]

#: Names of the free parameters of the calibration, in the column order of
#: :func:`pcc_jacobian`.
PCC_FREE_PARAMETERS = ("C11", "C12", "C21", "C22", "u0_1", "u0_2", "L", "w1", "w2")

_MIN_ROWS = 10
# Below alpha^2 = _SERIES_MAX the ratios use their Taylor series in alpha^2
# (_N_TERMS terms: truncation error < 1e-20 relative at the threshold); above,
# the closed forms, whose cancellation error is ~3e-16 relative at alpha = 2.
_SERIES_MAX = 4.0
_N_TERMS = 14

# Layout of the packed vector of PCCParams.pack(), read by pcc_kernel: offsets
# of the motor reference q0 (2, deg), the scale S_m (deg), C row by row (4),
# u0 (2, rad), L R_g row by row (9, mm), then the Taylor coefficients in
# alpha^2 of f = (1 - cos a) / a^2 and of s = sin a / a, highest power first
# (_N_TERMS each).
(PCC_Q0, PCC_S_M, PCC_C, PCC_U0, PCC_LR, PCC_F_SERIES, PCC_S_SERIES, PCC_PACKED_SIZE) = offsets(
    2, 1, 4, 2, 9, _N_TERMS, _N_TERMS
)
# Rows within this distance of the smallest |q - q0| / S_m count as neutral
# for the initial guess.
_NEUTRAL_BAND = 0.02


# ---------------------------------------------------------------------------
# even functions of the bend angle
# ---------------------------------------------------------------------------
def _series_table():
    r"""Taylor coefficients in ``x = a^2`` of the ratios used by the model.

    Rows: ``f = (1 - cos a) / a^2``, ``s = sin a / a``, ``F = f'(a) / a``,
    ``S = s'(a) / a`` and ``c = (a - sin a) / a^3`` (for the SO(3) Jacobian):

    .. math::

        f = \sum_k \frac{(-1)^k x^k}{(2k+2)!},\quad
        s = \sum_k \frac{(-1)^k x^k}{(2k+1)!},\quad
        F = -\sum_k \frac{2(k+1)(-1)^k x^k}{(2k+4)!},\quad
        S = -\sum_k \frac{2(k+1)(-1)^k x^k}{(2k+3)!},\quad
        c = \sum_k \frac{(-1)^k x^k}{(2k+3)!}.
    """
    table = np.empty((5, _N_TERMS))
    for k in range(_N_TERMS):
        sign = -1.0 if k % 2 else 1.0
        table[0, k] = sign / math.factorial(2 * k + 2)
        table[1, k] = sign / math.factorial(2 * k + 1)
        table[2, k] = -2.0 * (k + 1) * sign / math.factorial(2 * k + 4)
        table[3, k] = -2.0 * (k + 1) * sign / math.factorial(2 * k + 3)
        table[4, k] = sign / math.factorial(2 * k + 3)
    return table


_TABLE = _series_table()


def _horner(x, coefficients):
    """Evaluate the power series with rows ``coefficients`` (m, K) at ``x`` (n,)."""
    out = np.repeat(coefficients[:, -1:], x.shape[0], axis=1)
    for k in range(coefficients.shape[1] - 2, -1, -1):
        out *= x
        out += coefficients[:, k : k + 1]
    return out


def _arc_ratios(x, derivatives):
    r"""Ratios of the arc as functions of ``x = alpha^2``.

    Parameters
    ----------
    x : ndarray of shape (n,)
        Squared bend angle (rad^2), ``x >= 0``.
    derivatives : bool
        Whether to return ``F`` and ``S`` too.

    Returns
    -------
    ratios : ndarray of shape (2, n) or (4, n)
        ``f = (1 - cos a) / a^2`` and ``s = sin a / a``, then (if
        ``derivatives``) ``F = f'(a) / a = (a sin a - 2 (1 - cos a)) / a^4``
        and ``S = s'(a) / a = (a cos a - sin a) / a^3``; all even and smooth
        in ``a``, with ``f(0) = 1/2``, ``s(0) = 1``, ``F(0) = -1/12``,
        ``S(0) = -1/3``.
    """
    rows = _TABLE[:4] if derivatives else _TABLE[:2]
    out = _horner(np.minimum(x, _SERIES_MAX), rows)
    large = x >= _SERIES_MAX
    if np.any(large):
        xl = x[large]
        a = np.sqrt(xl)
        sin, cos = np.sin(a), np.cos(a)
        versine = 2.0 * np.sin(0.5 * a) ** 2  # 1 - cos a without cancellation
        out[0, large] = versine / xl
        out[1, large] = sin / a
        if derivatives:
            out[2, large] = (a * sin - 2.0 * versine) / (xl * xl)
            out[3, large] = (a * cos - sin) / (a * xl)
    return out


# ---------------------------------------------------------------------------
# rotations
# ---------------------------------------------------------------------------
def _hat(w):
    """Skew-symmetric matrix ``[w]^`` with ``[w]^ y = w x y``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _so3_exp(w):
    r"""Rotation matrix ``exp([w]^) = I + s [w]^ + f [w]^2`` (Rodrigues).

    ``s = sin t / t`` and ``f = (1 - cos t) / t^2`` with ``t = |w|`` (rad).
    """
    w = np.asarray(w, dtype=float)
    f, s = _arc_ratios(np.array([w @ w]), derivatives=False)[:, 0]
    W = _hat(w)
    return np.eye(3) + s * W + f * (W @ W)


def _so3_left_jacobian(w):
    r"""Left Jacobian of the exponential map, ``exp([w + d]^) ~ exp([J_l d]^) exp([w]^)``.

    ``J_l = I + f [w]^ + c [w]^2`` with ``f = (1 - cos t) / t^2`` and
    ``c = (t - sin t) / t^3``, ``t = |w|`` (rad).
    """
    w = np.asarray(w, dtype=float)
    t2 = float(w @ w)
    coeffs = _horner(np.array([min(t2, _SERIES_MAX)]), _TABLE[[0, 4]])[:, 0]
    if t2 >= _SERIES_MAX:
        t = math.sqrt(t2)
        coeffs = np.array([2.0 * math.sin(0.5 * t) ** 2 / t2, (t - math.sin(t)) / (t * t2)])
    W = _hat(w)
    return np.eye(3) + coeffs[0] * W + coeffs[1] * (W @ W)


def _tilt_vector(direction):
    """Rotation vector ``(w1, w2)`` of the smallest rotation taking ``e_z`` to ``direction``.

    The axis ``e_z x n / |e_z x n|`` lies in the xy plane; for ``n = -e_z``
    the rotation by pi about ``e_x`` is returned.
    """
    n = np.asarray(direction, dtype=float)
    n = n / np.linalg.norm(n)
    sin_t = math.hypot(n[0], n[1])
    angle = math.atan2(sin_t, n[2])
    if sin_t < 1e-300:
        return np.array([angle, 0.0])
    return angle * np.array([-n[1], n[0]]) / sin_t


def _roll_free_split(R):
    """Write ``R = exp([w1, w2, 0]^) R_z(gamma)``.

    Returns
    -------
    w : ndarray of shape (2,)
        Tilt rotation vector (rad).
    Q : ndarray of shape (2, 2)
        The roll ``R_z(gamma)`` restricted to the xy plane.
    """
    w = _tilt_vector(R[:, 2])
    roll = _so3_exp(np.array([w[0], w[1], 0.0])).T @ R
    gamma = math.atan2(roll[1, 0], roll[0, 0])
    c, s = math.cos(gamma), math.sin(gamma)
    return w, np.array([[c, -s], [s, c]])


def _rotvec(R):
    """Rotation vector (rad) of the rotation matrix ``R`` (inverse of :func:`_so3_exp`)."""
    cos_t = min(1.0, max(-1.0, 0.5 * (np.trace(R) - 1.0)))
    axis_sin = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin_t = float(np.linalg.norm(axis_sin))
    angle = math.atan2(sin_t, cos_t)
    if cos_t > -0.5:
        # angle < 2 pi / 3: axis from the antisymmetric part; angle / sin t is
        # smooth (1 + t^2/6 + ...) and never divides by zero.
        ratio = 1.0 + sin_t**2 / 6.0 if sin_t < 1e-4 else angle / sin_t
        return ratio * axis_sin
    # angle near pi: axis from the symmetric part, sign from the antisymmetric.
    B = 0.5 * (R + R.T) - cos_t * np.eye(3)  # = (1 - cos t) a a^T
    k = int(np.argmax(np.diag(B)))
    axis = B[:, k] / np.linalg.norm(B[:, k])
    if axis @ axis_sin < 0.0:
        axis = -axis
    return angle * axis


# ---------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------


def _as_positive(value, name):
    """Validate a finite, strictly positive scalar."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number; got {value!r}.") from None
    if not (math.isfinite(out) and out > 0.0):
        raise ValueError(f"{name} must be a finite positive number; got {value!r}.")
    return out


@dataclass(frozen=True, eq=False)
class PCCParams:
    """Parameters of the PCC backbone (paper eqs. pcc-input and pcc).

    Arrays are copied and made read-only on construction.

    Parameters
    ----------
    C : ndarray of shape (2, 2)
        Motor coupling (rad per unit of ``(q - q0) / S_m``).
    q0 : ndarray of shape (2,)
        Motor reference angles (deg).
    u0 : ndarray of shape (2,)
        Resting-curvature offset of the bending coordinates (rad).
    S_m : float
        Motor-angle scale (deg), > 0.
    L : float
        Effective bending length (mm), > 0.
    R_g : ndarray of shape (3, 3)
        Rotation from the arc frame to the base frame ``B`` (proper rotation
        matrix).
    """

    C: np.ndarray
    q0: np.ndarray
    u0: np.ndarray
    S_m: float
    L: float
    R_g: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "C", frozen_array(self.C, (2, 2), "C"))
        object.__setattr__(self, "q0", frozen_array(self.q0, (2,), "q0"))
        object.__setattr__(self, "u0", frozen_array(self.u0, (2,), "u0"))
        object.__setattr__(self, "S_m", _as_positive(self.S_m, "S_m"))
        object.__setattr__(self, "L", _as_positive(self.L, "L"))
        R = frozen_array(self.R_g, (3, 3), "R_g")
        if not (np.allclose(R.T @ R, np.eye(3), atol=1e-8) and np.linalg.det(R) > 0.0):
            raise ValueError("R_g must be a rotation matrix (orthonormal, det +1).")
        object.__setattr__(self, "R_g", R)

    def to_dict(self):
        """Flat, JSON-friendly dictionary of plain floats.

        Returns
        -------
        d : dict
            ``C11, C12, C21, C22`` (rad), ``q0_1, q0_2`` (deg), ``u0_1, u0_2``
            (rad), ``S_m`` (deg), ``L`` (mm) and ``rg_x, rg_y, rg_z``: the
            rotation vector of ``R_g`` (rad, angle in [0, pi]).
        """
        rg = _rotvec(self.R_g)
        return {
            "C11": float(self.C[0, 0]),
            "C12": float(self.C[0, 1]),
            "C21": float(self.C[1, 0]),
            "C22": float(self.C[1, 1]),
            "q0_1": float(self.q0[0]),
            "q0_2": float(self.q0[1]),
            "u0_1": float(self.u0[0]),
            "u0_2": float(self.u0[1]),
            "S_m": float(self.S_m),
            "L": float(self.L),
            "rg_x": float(rg[0]),
            "rg_y": float(rg[1]),
            "rg_z": float(rg[2]),
        }

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : mapping
            The keys written by :meth:`to_dict`.

        Returns
        -------
        params : PCCParams
        """
        return cls(
            C=[[d["C11"], d["C12"]], [d["C21"], d["C22"]]],
            q0=[d["q0_1"], d["q0_2"]],
            u0=[d["u0_1"], d["u0_2"]],
            S_m=d["S_m"],
            L=d["L"],
            R_g=_so3_exp(np.array([d["rg_x"], d["rg_y"], d["rg_z"]], dtype=float)),
        )

    def pack(self):
        """The parameters as the flat vector that :func:`pcc_kernel` reads.

        Returns
        -------
        theta : ndarray of shape (PCC_PACKED_SIZE,)
            float64, laid out by the offsets ``PCC_*`` of this module: ``q0``
            (deg), ``S_m`` (deg), ``C`` row by row, ``u0`` (rad), ``L R_g``
            row by row (mm), and the Taylor coefficients in ``alpha^2`` of
            ``(1 - cos alpha) / alpha^2`` and ``sin alpha / alpha``, highest
            power first.
        """
        theta = np.empty(PCC_PACKED_SIZE)
        theta[PCC_Q0 : PCC_Q0 + 2] = self.q0
        theta[PCC_S_M] = self.S_m
        theta[PCC_C : PCC_C + 4] = self.C.ravel()
        theta[PCC_U0 : PCC_U0 + 2] = self.u0
        theta[PCC_LR : PCC_LR + 9] = (self.L * self.R_g).ravel()
        theta[PCC_F_SERIES : PCC_F_SERIES + _N_TERMS] = _TABLE[0, ::-1]
        theta[PCC_S_SERIES : PCC_S_SERIES + _N_TERMS] = _TABLE[1, ::-1]
        return theta


# ---------------------------------------------------------------------------
# model
# ---------------------------------------------------------------------------
def _check_q(q, name="q"):
    """Motor angles as a float (n, 2) array (a single (2,) sample becomes (1, 2))."""
    arr = np.asarray(q, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == 2:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(
            f"{name} must have shape (n, 2) (motor angles q1, q2 in deg); got {np.shape(q)}."
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (motor angles in deg).")
    return arr


@tip_kernel("PCCParams")
def pcc_kernel(theta, q1, q2):
    """Tip of the PCC backbone for one motor sample: the one scalar form of eq. pcc.

    Plain ``math`` on floats, compiled by numba where it is available (see
    :mod:`skcath._kernel`); :func:`pcc_tip` runs it on every row and the
    streaming estimator on every sample.
    """
    v1 = (q1 - theta[PCC_Q0]) / theta[PCC_S_M]
    v2 = (q2 - theta[PCC_Q0 + 1]) / theta[PCC_S_M]
    u1 = v1 * theta[PCC_C] + v2 * theta[PCC_C + 1] + theta[PCC_U0]
    u2 = v1 * theta[PCC_C + 2] + v2 * theta[PCC_C + 3] + theta[PCC_U0 + 1]
    x = u1 * u1 + u2 * u2
    if x < _SERIES_MAX:  # Taylor series in x = alpha^2, as _arc_ratios
        fs, ss = PCC_F_SERIES, PCC_S_SERIES
        f, s = theta[fs], theta[ss]
        for k in range(1, _N_TERMS):
            f = f * x + theta[fs + k]
            s = s * x + theta[ss + k]
    else:
        a = math.sqrt(x)
        f = 2.0 * math.sin(0.5 * a) ** 2 / x
        s = math.sin(a) / a
    h1, h2 = u1 * f, u2 * f
    R = PCC_LR
    return (
        theta[R] * h1 + theta[R + 1] * h2 + theta[R + 2] * s,
        theta[R + 3] * h1 + theta[R + 4] * h2 + theta[R + 5] * s,
        theta[R + 6] * h1 + theta[R + 7] * h2 + theta[R + 8] * s,
    )


_PCC_ROWS = row_loop(pcc_kernel)


def _tip_and_jacobian(v, C, u0, L, w):
    """Tip (n, 3) and Jacobian (n, 3, 9) for the roll-free ``R_g = exp([w1, w2, 0]^)``.

    See :func:`pcc_jacobian` for the column order.
    """
    wv = np.array([w[0], w[1], 0.0])
    R = _so3_exp(wv)
    return _tip_and_jacobian_R(v, C, u0, L, R, wv)


def _tip_and_jacobian_R(v, C, u0, L, R, wv=None):
    r"""Tips of many rows at once, and their Jacobian for ``R = exp([wv]^) R_z``.

    The vectorised form of eq. pcc that the calibration evaluates, because
    the Jacobian needs its intermediates; :func:`pcc_kernel` is the form
    evaluated everywhere else. Without ``wv`` only the tips are returned.
    The roll ``R_z`` is held fixed: with ``h(u) = [u f, s]``,
    ``dh/du = [[f + F u1^2, F u1 u2], [F u1 u2, f + F u2^2], [S u1, S u2]]``;
    ``du_i / dC_jk = delta_ij v_k``, ``du / du0 = I``; ``dg/dL = R h``;
    ``dg/dw_k = (J_l(w) e_k) x g``.
    """
    n = v.shape[0]
    u = v @ C.T + u0
    ratios = _arc_ratios(np.einsum("ij,ij->i", u, u), derivatives=wv is not None)
    f, s = ratios[0], ratios[1]
    h = np.empty((n, 3))
    h[:, :2] = u * f[:, None]
    h[:, 2] = s
    Rh = h @ R.T
    tip = L * Rh
    if wv is None:
        return tip
    F, S = ratios[2], ratios[3]
    # dh/du in the arc frame, (n, 3, 2)
    M = np.empty((n, 3, 2))
    Fu = F[:, None] * u
    M[:, :2, :] = Fu[:, :, None] * u[:, None, :]
    M[:, 0, 0] += f
    M[:, 1, 1] += f
    M[:, 2, :] = S[:, None] * u
    Mw = (L * R) @ M  # d tip / du in frame B, (n, 3, 2)
    J = np.empty((n, 3, 9))
    J[:, :, 0:2] = Mw[:, :, 0:1] * v[:, None, :]
    J[:, :, 2:4] = Mw[:, :, 1:2] * v[:, None, :]
    J[:, :, 4:6] = Mw
    J[:, :, 6] = Rh
    Jl = _so3_left_jacobian(wv)
    J[:, :, 7] = np.cross(Jl[:, 0], tip)
    J[:, :, 8] = np.cross(Jl[:, 1], tip)
    return tip, J


@validate_params({"q": ["array-like"], "params": [PCCParams]}, prefer_skip_nested_validation=True)
def pcc_tip(q, params):
    r"""Tip position of the PCC backbone (paper eqs. pcc-input and pcc).

    .. math::

        \mathbf u = C (\mathbf q - \mathbf q_0) / S_m + \mathbf u_0,\quad
        \alpha = \lVert\mathbf u\rVert,\quad
        g = L R_g [u_1 (1-\cos\alpha)/\alpha^2,\;
                   u_2 (1-\cos\alpha)/\alpha^2,\; \sin\alpha/\alpha]^T.

    The ratios take their continuous limits at ``alpha = 0`` (``1/2`` and
    ``1``), so ``g = L R_g e_z`` there. Every row is evaluated by
    :func:`pcc_kernel`, in a loop compiled by numba where it is available and
    in Python otherwise.

    Parameters
    ----------
    q : array-like of shape (n, 2) or (2,)
        Motor angles (deg).
    params : PCCParams
        Backbone parameters.

    Returns
    -------
    tip : ndarray of shape (n, 3)
        Tip positions in the base frame ``B`` (mm).
    """
    q = _check_q(q)
    return evaluate_rows(_PCC_ROWS, params.pack(), q)


@validate_params({"q": ["array-like"], "params": [PCCParams]}, prefer_skip_nested_validation=True)
def pcc_jacobian(q, params):
    r"""Tip position and its analytic Jacobian with respect to the free parameters.

    ``R_g`` is written ``exp([w1, w2, 0]^) R_z(gamma)`` (a tilt, then a roll
    about z); the roll is held fixed and the tilt ``(w1, w2)`` is varied, using
    the left Jacobian of the exponential map:
    ``d g / d w_k = (J_l(w) e_k) x g`` with
    ``J_l(w) = I + (1 - cos t)/t^2 [w]^ + (t - sin t)/t^3 [w]^2``, ``t = |w|``.
    The other columns are ``d g / d C_jk = L R_g (dh/du_j) v_k``,
    ``d g / d u0 = L R_g dh/du`` and ``d g / d L = R_g h``, with
    ``v = (q - q0) / S_m``, ``h(u)`` the bracket of eq. pcc and

    .. math::

        \frac{\partial h}{\partial \mathbf u} =
        \begin{bmatrix} f I + F\, \mathbf u \mathbf u^T \\ S\, \mathbf u^T \end{bmatrix},\quad
        f = \frac{1-\cos\alpha}{\alpha^2},\;
        F = \frac{f'(\alpha)}{\alpha},\;
        S = \frac{1}{\alpha}\frac{d}{d\alpha}\frac{\sin\alpha}{\alpha}.

    Parameters
    ----------
    q : array-like of shape (n, 2) or (2,)
        Motor angles (deg).
    params : PCCParams
        Backbone parameters (``q0`` and ``S_m`` are held fixed).

    Returns
    -------
    tip : ndarray of shape (n, 3)
        Tip positions in the base frame ``B`` (mm), as :func:`pcc_tip`.
    J : ndarray of shape (n, 3, 9)
        ``d tip / d theta`` with ``theta`` ordered as
        :data:`PCC_FREE_PARAMETERS` = ``(C11, C12, C21, C22, u0_1, u0_2, L,
        w1, w2)``; units mm per rad (``C``, ``u0``, ``w``) and mm/mm (``L``).
    """
    q = _check_q(q)
    v = (q - params.q0) / params.S_m
    w, _ = _roll_free_split(params.R_g)
    wv = np.array([w[0], w[1], 0.0])
    _, J = _tip_and_jacobian_R(v, params.C, params.u0, params.L, params.R_g, wv)
    return evaluate_rows(_PCC_ROWS, params.pack(), q), J


# ---------------------------------------------------------------------------
# calibration
# ---------------------------------------------------------------------------
def _pack(C, u0, L, w):
    """Free-parameter vector ``(C11, C12, C21, C22, u0_1, u0_2, L, w1, w2)``."""
    return np.concatenate([np.ravel(C), u0, [L], w])


def _unpack(x):
    """Inverse of :func:`_pack`: ``C`` (2, 2), ``u0`` (2,), ``L``, ``w`` (2,) as views."""
    return x[0:4].reshape(2, 2), x[4:6], x[6], x[7:9]


def _initial_guess(v, p):
    r"""Free parameters from the data alone (no iteration).

    1. Neutral tip ``p_n``: mean of the rows with ``|v|`` within
       ``_NEUTRAL_BAND`` of the smallest ``|v|`` (``v = (q - q0) / S_m``).
       ``L = |p_n|`` and ``R_g`` is the smallest rotation taking ``e_z`` to
       ``p_n / |p_n|``.
    2. Per row, in the frame of ``R_g``: the tip vector of a PCC arc is
       inclined from ``e_z`` by ``alpha / 2`` and its azimuth is the bend
       direction, so ``u_i = 2 beta_i (x_i, y_i) / |(x_i, y_i)|`` with
       ``beta_i = atan2(|(x_i, y_i)|, z_i)``.
    3. ``C``, ``u0`` by linear least squares ``u_i ~ C v_i + u0``.
    """
    rho = np.hypot(v[:, 0], v[:, 1])
    neutral = rho <= rho.min() + _NEUTRAL_BAND
    p_n = p[neutral].mean(axis=0)
    L = float(np.linalg.norm(p_n))
    if not L > 0.0:
        raise ValueError("The neutral tip position is at the origin; cannot initialise L.")
    w = _tilt_vector(p_n)
    R = _so3_exp(np.array([w[0], w[1], 0.0]))
    local = p @ R  # R^T p_i
    radial = np.hypot(local[:, 0], local[:, 1])
    beta = np.arctan2(radial, local[:, 2])
    scale = np.divide(2.0 * beta, radial, out=np.full_like(radial, 2.0 / L), where=radial > 0.0)
    u = local[:, :2] * scale[:, None]
    design = np.column_stack([v, np.ones(len(v))])
    coef = np.linalg.lstsq(design, u, rcond=None)[0]  # rows: C^T (2), u0 (1)
    return _pack(coef[:2].T, coef[2], L, w)


def _from_init(init, q0, S_m):
    """Free parameters of ``init`` re-expressed with the fixed ``q0``, ``S_m`` and no roll.

    ``u = C (q - q0') / S' + u0' = (C S/S') (q - q0)/S + [u0' + C (q0 - q0')/S']``
    and ``R_z(gamma) h(u) = h(Q u)``.
    """
    C = init.C * (S_m / init.S_m)
    u0 = init.u0 + init.C @ (q0 - init.q0) / init.S_m
    w, Q = _roll_free_split(init.R_g)
    return _pack(Q @ C, Q @ u0, init.L, w)


def _params_from_free(x, q0, S_m):
    """PCCParams from the free parameters, with ``L > 0`` and ``R_g`` without roll.

    A negative length is folded back exactly: ``-h(u) = R_x(pi) h(D u)`` with
    ``D = diag(-1, 1)``, so ``(C, u0, -L, R)`` equals
    ``(D C, D u0, L, R R_x(pi))``; the roll of the new rotation is then moved
    into ``C`` and ``u0``.
    """
    C, u0, L, w = _unpack(x)
    R = _so3_exp(np.array([w[0], w[1], 0.0]))
    if L < 0.0:
        D = np.diag([-1.0, 1.0])
        C, u0, L, R = D @ C, D @ u0, -L, R @ np.diag([1.0, -1.0, -1.0])
        w, Q = _roll_free_split(R)
        C, u0, R = Q @ C, Q @ u0, _so3_exp(np.array([w[0], w[1], 0.0]))
    return PCCParams(C=C, q0=q0, u0=u0, S_m=S_m, L=L, R_g=R)


def _check_p(p, n):
    """Tip positions as a float (n, 3) array; NaN allowed (missing), +-inf not."""
    arr = np.asarray(p, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"p must have shape (n, 3) (tip positions in mm); got {np.shape(p)}.")
    if arr.shape[0] != n:
        raise ValueError(f"p has {arr.shape[0]} rows but q has {n}; they must match.")
    if np.any(np.isinf(arr)):
        raise ValueError("p must not contain +-inf (NaN marks a missing sample).")
    return arr


@validate_params(
    {
        "q": ["array-like"],
        "p": ["array-like"],
        "q0": ["array-like", None],
        "S_m": [Interval(Real, 0, None, closed="neither"), None],
        "init": [PCCParams, None],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "return_info": ["boolean"],
        "solver": [callable, None],
    },
    prefer_skip_nested_validation=True,
)
def calibrate_pcc(
    q, p, *, q0=None, S_m=None, init=None, max_iter=100, return_info=False, solver=None
):
    r"""Fit the PCC backbone to paired motor angles and tip positions.

    Minimises ``sum_i |g(q_i) - p_i|^2`` over the nine free parameters
    ``(C, u0, L, w)`` (:data:`PCC_FREE_PARAMETERS`) with
    :func:`~skcath.backbones._lm.levenberg_marquardt` and the analytic
    Jacobian of :func:`pcc_jacobian`; ``q0`` and ``S_m`` are fixed and
    ``R_g = exp([w1, w2, 0]^)`` carries no roll (see the module docstring).

    Parameters
    ----------
    q : array-like of shape (n, 2)
        Motor angles (deg); must be finite.
    p : array-like of shape (n, 3)
        Reference tip positions in the base frame (mm). Rows with a NaN are
        ignored.
    q0 : array-like of shape (2,), optional
        Motor reference (deg): the neutral motor angles of the sweep. Default
        ``init.q0`` if ``init`` is given, else zeros.
    S_m : float, optional
        Motor-angle scale (deg): the sweep amplitude. Default ``init.S_m`` if
        ``init`` is given, else ``max_i |q_i - q0|`` over the rows used.
    init : PCCParams, optional
        Starting point; it is re-expressed exactly with the fixed ``q0``,
        ``S_m`` and without roll. Default: a data-driven guess (neutral tip
        direction and length, then per-sample inversion of the arc and a
        linear fit of ``C`` and ``u0``).
    max_iter : int
        Largest number of accepted Levenberg-Marquardt steps.
    return_info : bool
        Whether to return a dictionary of diagnostics as well.
    solver : callable, default=None
        The least-squares solver, called as
        :func:`~skcath.backbones.levenberg_marquardt` is (same arguments,
        an :class:`~skcath.backbones.LMResult` back); None means
        :func:`~skcath.backbones.levenberg_marquardt`. Lets another solver
        run on the same residuals, Jacobian and initial guess.

    Returns
    -------
    params : PCCParams
        Fitted parameters, ``R_g`` without roll about its z axis.
    info : dict
        Only if ``return_info``: ``cost`` (``0.5 sum r^2``, mm^2),
        ``rmse_mm`` (root mean squared Euclidean tip error over the rows
        used, mm), ``n_iter`` (Jacobian evaluations), ``converged`` (bool)
        and ``n_samples`` (rows used).

    Raises
    ------
    ValueError
        On malformed shapes, non-finite ``q``, or fewer than 10 rows with a
        finite ``p``.
    """
    q = _check_q(q)
    p = _check_p(p, q.shape[0])
    keep = ~np.isnan(p).any(axis=1)
    n_used = int(keep.sum())
    if n_used < _MIN_ROWS:
        raise ValueError(
            f"p has {n_used} row(s) without NaN; calibrate_pcc needs at least {_MIN_ROWS}."
        )
    q, p = q[keep], p[keep]
    if q0 is None:
        q0 = init.q0 if init is not None else np.zeros(2)
    q0 = frozen_array(q0, (2,), "q0")
    if S_m is None:
        if init is not None:
            S_m = init.S_m
        else:
            S_m = float(np.max(np.hypot(q[:, 0] - q0[0], q[:, 1] - q0[1])))
            if not S_m > 0.0:
                raise ValueError("S_m cannot default to max |q - q0|: every used q equals q0.")
    S_m = _as_positive(S_m, "S_m")
    v = (q - q0) / S_m
    x0 = _from_init(init, q0, S_m) if init is not None else _initial_guess(v, p)
    target = p.ravel()

    def residuals(x, jac=True):
        C, u0, L, w = _unpack(x)
        if jac:
            tip, J = _tip_and_jacobian(v, C, u0, L, w)
            return tip.ravel() - target, J.reshape(-1, 9)
        R = _so3_exp(np.array([w[0], w[1], 0.0]))
        return _tip_and_jacobian_R(v, C, u0, L, R).ravel() - target

    result = (solver or levenberg_marquardt)(residuals, x0, max_iter=max_iter)
    params = _params_from_free(result.x, q0, S_m)
    if not return_info:
        return params
    info = {
        "cost": float(result.cost),
        "rmse_mm": math.sqrt(2.0 * result.cost / n_used),
        "n_iter": int(result.n_iter),
        "converged": bool(result.converged),
        "n_samples": n_used,
    }
    return params, info
