"""Per-direction linear (PDL) backbone: tip position from motor angles along sweep rays.

With the motor input written in polar form about the neutral motor angles
:math:`q_n` (degrees),

.. math::

    \\rho = \\lVert q - q_n \\rVert_2, \\qquad
    \\psi = \\operatorname{atan2}(q_2 - q_{n,2},\\, q_1 - q_{n,1}),

the model (paper eq. 5) describes the tip along each sweep ray :math:`k` of
direction :math:`\\psi_k` by three responses that are linear in their
coefficients,

.. math::

    \\gamma(\\rho) &= a_\\gamma \\rho + b_\\gamma \\rho^2, \\\\
    d(\\rho) &= a_d \\rho + b_d \\rho^2, \\\\
    \\varphi(\\rho) &= \\varphi_0 + s_\\varphi (\\rho - \\rho_0),

where :math:`\\gamma` (rad) is twice the inclination of the tip vector (from
the origin of the base frame B to the tip) from the neutral tip direction
:math:`n_0 = p_0 / \\lVert p_0 \\rVert`, :math:`d` (mm) the distance of the
tip from the neutral tip :math:`p_0`, :math:`\\varphi` (rad) the azimuth of
the tip vector about :math:`n_0` in a fixed basis :math:`(e_1, e_2)`
perpendicular to :math:`n_0`, and :math:`\\rho_0` (degrees) a fixed reference
magnitude. Between two neighbouring rays the six coefficients are
interpolated linearly in :math:`\\psi`, periodically across :math:`\\pm\\pi`;
the azimuth offsets :math:`\\varphi_0` are unwrapped from ray to ray so that
the interpolation never jumps by :math:`2\\pi`.

The tip is reconstructed from its direction and its distance to the neutral
tip: with :math:`h = \\gamma / 2`, :math:`P = \\lVert p_0 \\rVert` and

.. math::

    u = \\cos h \\, n_0 + \\sin h \\, (\\cos\\varphi \\, e_1 + \\sin\\varphi \\, e_2),

the tip is :math:`p = r u` with :math:`\\lVert r u - p_0 \\rVert = d`, the far
root

.. math::

    r = P \\cos h + \\operatorname{sgn}(D) \\sqrt{|D|}, \\qquad D = d^2 - P^2 \\sin^2 h.

Where the sphere of radius :math:`d` about the neutral tip misses the tip
direction (:math:`D < 0`, which the fit can reach on hysteretic sweeps), the
root is continued monotonically through the closest point of the ray rather
than held there, so that the cost has no flat region.

All lengths are in mm, motor angles and :math:`\\rho` in degrees, the other
angles in radians.
"""

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
from sklearn.utils._param_validation import Interval, validate_params

from .._kernel import bisect_right, evaluate_rows, kernel, offsets, row_loop, tip_kernel
from ._arrays import frozen_array
from ._lm import _batched_levenberg_marquardt

__all__ = ["COEF_NAMES", "PDLParams", "calibrate_pdl", "pdl_kernel", "pdl_tip"]

#: Names of the six per-ray coefficients, in the column order of ``PDLParams.coef``:
#: ``a_g`` (rad/deg), ``b_g`` (rad/deg^2), ``a_d`` (mm/deg), ``b_d`` (mm/deg^2),
#: ``phi0`` (rad), ``s_phi`` (rad/deg).
COEF_NAMES = ("a_g", "b_g", "a_d", "b_d", "phi0", "s_phi")
_N_COEF = len(COEF_NAMES)
_PHI0 = COEF_NAMES.index("phi0")
_TWO_PI = 2.0 * np.pi
_AXES = ("x", "y", "z")
_BASIS_ROWS = ("e1", "e2", "n0")

#: Fewest samples with finite references that a ray needs (one per coefficient).
MIN_RAY_SAMPLES = _N_COEF
#: The azimuth of the initial fit uses the samples beyond this fraction of the
#: ray's largest magnitude; closer to neutral the azimuth is poorly defined.
PHI_FIT_FRACTION = 0.2
#: Relative decrease of the cost below which a ray's Gauss-Newton refinement
#: stops. The square root of the reconstruction has a vertical tangent at
#: ``D = 0``, where the last steps creep; 1e-8 keeps the calibration within
#: its time budget and its cost within 1e-5 of scipy's (benchmarks/README.md).
FTOL = 1e-8
# Below this (relative to |p0|) the signed square root of the reconstruction
# has its derivatives taken as 0, so that they stay finite.
_SQRT_FLOOR = 1e-12

# Layout of the packed vector of PDLParams.pack(), read by pdl_kernel: offsets
# of the number of rays K, the neutral motor angles q_n (2, deg), the first
# ray direction (rad), rho0 (deg), |p0| (mm), p0 (3, mm), the basis rows e1,
# e2, n0 (9), then the blocks of the rays (see _ray_blocks).
(PDL_N_RAYS, PDL_Q_NEUTRAL, PDL_FIRST, PDL_RHO0, PDL_BIG_P, PDL_P0, PDL_BASIS, PDL_RAYS) = offsets(
    1, 2, 1, 1, 1, 3, 9
)


# ---------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PDLParams:
    """Calibrated parameters of the per-direction linear backbone.

    Attributes
    ----------
    p0 : ndarray of shape (3,)
        Neutral tip position in the base frame (mm).
    basis : ndarray of shape (3, 3)
        Orthonormal rows ``e1``, ``e2``, ``n0`` (right-handed,
        ``n0 = p0 / |p0|``); the azimuth ``phi`` is measured from ``e1``
        towards ``e2``.
    q_neutral : ndarray of shape (2,)
        Neutral motor angles ``q_n`` (degrees).
    directions : ndarray of shape (K,)
        Ray directions ``psi_k`` (rad), strictly increasing in ``[-pi, pi)``.
    coef : ndarray of shape (K, 6)
        Per-ray coefficients, columns :data:`COEF_NAMES`: ``a_g`` (rad/deg),
        ``b_g`` (rad/deg^2), ``a_d`` (mm/deg), ``b_d`` (mm/deg^2), ``phi0``
        (rad, unwrapped from ray to ray) and ``s_phi`` (rad/deg).
    rho0 : float
        Reference magnitude of the azimuth law (degrees).
    """

    p0: np.ndarray
    basis: np.ndarray
    q_neutral: np.ndarray
    directions: np.ndarray
    coef: np.ndarray
    rho0: float

    def __post_init__(self):
        p0 = frozen_array(self.p0, (3,), "p0")
        basis = frozen_array(self.basis, (3, 3), "basis")
        directions = np.array(self.directions, dtype=float, copy=True).ravel()
        directions = frozen_array(directions, directions.shape, "directions")
        n_rays = len(directions)
        _check_directions(directions)
        if not np.isfinite(self.rho0):
            raise ValueError(f"rho0 must be finite; got {self.rho0!r}.")
        object.__setattr__(self, "p0", p0)
        object.__setattr__(self, "basis", basis)
        object.__setattr__(self, "q_neutral", frozen_array(self.q_neutral, (2,), "q_neutral"))
        object.__setattr__(self, "directions", directions)
        object.__setattr__(self, "coef", frozen_array(self.coef, (n_rays, _N_COEF), "coef"))
        object.__setattr__(self, "rho0", float(self.rho0))

    @property
    def n_rays(self):
        """Number of rays ``K``."""
        return len(self.directions)

    def pack(self):
        """The parameters as the flat vector that :func:`pdl_kernel` reads.

        The offsets ``phi0`` are unwrapped from ray to ray, and each ray's
        upper neighbour is stored with its coefficients (the first ray's, with
        ``phi0`` shifted by the winding, for the last ray), so that the
        kernel interpolates between two stored rows.

        Returns
        -------
        theta : ndarray
            float64, laid out by the offsets ``PDL_*`` of this module and
            :func:`_ray_blocks`: ``K``, ``q_neutral`` (deg), the first
            direction (rad), ``rho0`` (deg), ``|p0|`` and ``p0`` (mm), the
            basis rows, then per ray the direction relative to the first ray
            (rad), the span to the next ray (rad), the coefficients and the
            upper neighbour's coefficients.
        """
        n_rays = self.n_rays
        coef = np.array(self.coef, copy=True)
        coef[:, _PHI0] = _unwrap_rays(coef[:, _PHI0], wrap_first=False)
        upper = coef[(np.arange(n_rays) + 1) % n_rays].copy()
        upper[-1, _PHI0] += _winding(coef[:, _PHI0])
        relative, span, lower_at, upper_at = _ray_blocks(n_rays)
        theta = np.empty(upper_at + _N_COEF * n_rays)
        theta[PDL_N_RAYS] = n_rays
        theta[PDL_Q_NEUTRAL : PDL_Q_NEUTRAL + 2] = self.q_neutral
        theta[PDL_FIRST] = self.directions[0]
        theta[PDL_RHO0] = self.rho0
        theta[PDL_BIG_P] = np.linalg.norm(self.p0)
        theta[PDL_P0 : PDL_P0 + 3] = self.p0
        theta[PDL_BASIS : PDL_BASIS + 9] = self.basis.ravel()
        theta[relative : relative + n_rays] = self.directions - self.directions[0]
        theta[span : span + n_rays] = np.diff(np.append(self.directions, self.directions[0] + _TWO_PI))
        theta[lower_at:upper_at] = coef.ravel()
        theta[upper_at:] = upper.ravel()
        return theta

    def to_dict(self):
        """Flat dictionary of plain Python scalars (JSON-friendly).

        Returns
        -------
        params : dict
            ``p0_x, p0_y, p0_z`` (mm); ``e1_x`` ... ``n0_z`` (the basis rows);
            ``q_neutral_1, q_neutral_2`` (deg); ``rho0`` (deg); ``n_rays``;
            and for every ray ``k``: ``direction_k`` (rad) and the six
            coefficients ``a_g_k, b_g_k, a_d_k, b_d_k, phi0_k, s_phi_k``.
            :meth:`from_dict` inverts it.
        """
        out = {f"p0_{a}": float(v) for a, v in zip(_AXES, self.p0)}
        for row, vec in zip(_BASIS_ROWS, self.basis):
            out.update({f"{row}_{a}": float(v) for a, v in zip(_AXES, vec)})
        out["q_neutral_1"], out["q_neutral_2"] = (float(v) for v in self.q_neutral)
        out["rho0"] = self.rho0
        out["n_rays"] = self.n_rays
        for k in range(self.n_rays):
            out[f"direction_{k}"] = float(self.directions[k])
            out.update({f"{name}_{k}": float(v) for name, v in zip(COEF_NAMES, self.coef[k])})
        return out

    @classmethod
    def from_dict(cls, params):
        """Parameters from the output of :meth:`to_dict`.

        Parameters
        ----------
        params : dict
            Flat dictionary as written by :meth:`to_dict`.

        Returns
        -------
        params : PDLParams
        """
        n_rays = int(params["n_rays"])
        return cls(
            p0=[params[f"p0_{a}"] for a in _AXES],
            basis=[[params[f"{row}_{a}"] for a in _AXES] for row in _BASIS_ROWS],
            q_neutral=[params["q_neutral_1"], params["q_neutral_2"]],
            directions=[params[f"direction_{k}"] for k in range(n_rays)],
            coef=[[params[f"{name}_{k}"] for name in COEF_NAMES] for k in range(n_rays)],
            rho0=params["rho0"],
        )


# ---------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------
def _wrap(angle):
    """Angle(s) wrapped into ``[-pi, pi)`` (rad)."""
    return (np.asarray(angle, dtype=float) + np.pi) % _TWO_PI - np.pi


def _check_directions(directions):
    """Raise unless ``directions`` has >= 2 strictly increasing angles in [-pi, pi)."""
    if directions.ndim != 1 or len(directions) < 2:
        raise ValueError(f"directions must hold at least 2 ray directions (rad); got {directions!r}.")
    if np.any(directions < -np.pi) or np.any(directions >= np.pi):
        raise ValueError(f"directions must lie in [-pi, pi) (rad); got {directions!r}.")
    if np.any(np.diff(directions) <= 0.0):
        raise ValueError(f"directions must be strictly increasing (rad); got {directions!r}.")


def _neutral_basis(p0):
    """Orthonormal basis ``(e1, e2, n0)`` attached to the neutral tip.

    ``n0 = p0 / |p0|``; ``e1`` is the normalised component of the x axis
    orthogonal to ``n0`` (the y axis when x is within about 25 deg of ``n0``);
    ``e2 = n0 x e1``, so that ``(e1, e2, n0)`` is right-handed.

    Parameters
    ----------
    p0 : array-like of shape (3,)
        Neutral tip position (mm), non-zero.

    Returns
    -------
    basis : ndarray of shape (3, 3)
        Rows ``e1``, ``e2``, ``n0``.
    """
    p0 = np.asarray(p0, dtype=float)
    norm = np.linalg.norm(p0)
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError(f"The neutral tip p0 must be finite and non-zero; got {p0!r} mm.")
    n0 = p0 / norm
    axis = np.array([1.0, 0.0, 0.0]) if abs(n0[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = axis - (axis @ n0) * n0
    e1 /= np.linalg.norm(e1)
    return np.vstack([e1, np.cross(n0, e1), n0])


def _polar(q, q_neutral):
    """Magnitude ``rho`` (deg) and direction ``psi`` (rad) of ``q - q_neutral``."""
    v = q - q_neutral
    return np.hypot(v[:, 0], v[:, 1]), np.arctan2(v[:, 1], v[:, 0])


def _winding(phi0):
    """Multiple of 2 pi added to ``phi0[0]`` when it follows the last ray (wrap-around).

    The offsets are unwrapped ray to ray, so the step from the last ray to the
    first is ``wrap(phi0[0] - phi0[-1])``; the winding is what makes the first
    ray's offset continue the last one's (+2 pi for a normal catheter, -2 pi
    for a mirrored one).
    """
    return phi0[-1] + _wrap(phi0[0] - phi0[-1]) - phi0[0]


def _unwrap_rays(phi0, *, wrap_first=True):
    """Offsets unwrapped from ray to ray (steps in ``[-pi, pi)``).

    The first offset is wrapped into ``[-pi, pi)``, or kept as is when
    ``wrap_first`` is False. Only multiples of 2 pi change, so the model is
    unchanged.
    """
    first = _wrap(phi0[0]) if wrap_first else phi0[0]
    return first + np.concatenate([[0.0], np.cumsum(_wrap(np.diff(phi0)))])


# ---------------------------------------------------------------------------
# model
# ---------------------------------------------------------------------------
def _responses(rho, c, rho0):
    """Responses ``gamma`` (rad), ``d`` (mm), ``phi`` (rad) for coefficients ``c``.

    Parameters
    ----------
    rho : ndarray of shape (n,)
        Motor-input magnitudes (deg).
    c : ndarray of shape (6,) or (n, 6)
        Coefficients (:data:`COEF_NAMES`), shared or per sample.
    rho0 : float
        Reference magnitude (deg).

    Returns
    -------
    gamma, dist, phi : ndarray of shape (n,)
        ``a_g rho + b_g rho^2``, ``a_d rho + b_d rho^2``,
        ``phi0 + s_phi (rho - rho0)``.
    """
    gamma = rho * (c[..., 0] + c[..., 1] * rho)
    dist = rho * (c[..., 2] + c[..., 3] * rho)
    phi = c[..., 4] + c[..., 5] * (rho - rho0)
    return gamma, dist, phi


class _Reconstruction:
    """Displacement of the tip from the neutral tip, in the basis ``(e1, e2, n0)``.

    With ``h = gamma / 2``, ``P = |p0|`` and

    .. math::

        s = \\operatorname{sgn}(D) \\sqrt{|D|}, \\quad D = d^2 - P^2 \\sin^2 h,
        \\quad r = P \\cos h + s,

    the tip ``p = r u`` (far root of ``|r u - p0| = d``) is written as
    ``p = p0 + delta`` with components

    .. math::

        \\delta_{e_1} = r \\sin h \\cos\\varphi, \\quad
        \\delta_{e_2} = r \\sin h \\sin\\varphi, \\quad
        \\delta_{n_0} = s \\cos h - P \\sin^2 h,

    which equals ``r u - p0`` without cancellation and is exactly 0 at
    ``gamma = d = 0``. Where ``|s|`` is below ``1e-12 P``, its derivatives
    are taken as 0 so that they stay finite.

    Parameters
    ----------
    gamma, dist, phi : ndarray of shape (n,)
        Twice the inclination (rad), distance to the neutral tip (mm), azimuth (rad).
    big_p : float
        Distance ``P`` of the neutral tip from the origin of B (mm).
    """

    def __init__(self, gamma, dist, phi, big_p):
        self.big_p = big_p
        self.dist = dist
        h = 0.5 * gamma
        self.ch, self.sh = np.cos(h), np.sin(h)
        self._set_azimuth(np.empty((2, len(phi))))
        np.cos(phi, out=self.cphi)
        np.sin(phi, out=self.sphi)
        lateral = big_p * self.sh
        disc = dist * dist - lateral**2
        self.s = np.sign(disc) * np.sqrt(np.abs(disc))
        self.r = big_p * self.ch + self.s
        self.across = self.r * self.sh
        self.along = self.s * self.ch - lateral * self.sh

    def _set_azimuth(self, cs):
        """``cos(phi)`` and ``sin(phi)`` as the rows of ``cs`` (2, n), to multiply both at once."""
        self.cs = cs
        self.cphi, self.sphi = cs

    def components(self):
        """``delta`` in the basis: rows ``e1``, ``e2``, ``n0``, shape (3, n) (mm)."""
        delta = np.empty((3, len(self.s)))
        np.multiply(self.across, self.cs, out=delta[:2])
        delta[2] = self.along
        return delta

    def derivatives(self):
        """Derivatives of the three components with respect to ``gamma``, ``d`` and ``phi``.

        Returns
        -------
        dgamma, dd, dphi : ndarrays of shape (3, n)
            Rows per component (``e1``, ``e2``, ``n0``): ``d delta / d gamma``
            (mm/rad), ``d delta / d d`` (mm/mm) and ``d delta / d phi`` (mm/rad).
        """
        big_p, ch, sh, s = self.big_p, self.ch, self.sh, self.s
        abs_s = np.abs(s)
        inv_s = np.divide(1.0, abs_s, out=np.zeros_like(s), where=abs_s > _SQRT_FLOOR * max(big_p, 1.0))
        ds_dd = self.dist * inv_s
        ds_dh = -(big_p * big_p) * sh * ch * inv_s
        dgamma, dd, dphi = np.empty((3, 3, len(s)))
        # d/dgamma = 0.5 d/dh
        np.multiply(0.5 * ((ds_dh - big_p * sh) * sh + self.r * ch), self.cs, out=dgamma[:2])
        dgamma[2] = 0.5 * (ds_dh * ch - s * sh - 2.0 * big_p * sh * ch)
        np.multiply(ds_dd * sh, self.cs, out=dd[:2])
        np.multiply(ds_dd, ch, out=dd[2])
        np.multiply(-self.across, self.sphi, out=dphi[0])
        np.multiply(self.across, self.cphi, out=dphi[1])
        dphi[2] = 0.0
        return dgamma, dd, dphi

    def take(self, index):
        """The reconstruction of the samples ``index`` only (the same values)."""
        part = object.__new__(_Reconstruction)
        part.big_p = self.big_p
        for name in ("dist", "ch", "sh", "s", "r", "across", "along"):
            setattr(part, name, getattr(self, name)[index])
        part._set_azimuth(self.cs[:, index])
        return part


class _JacobianFactors:
    """The factors ``rho``, ``rho^2`` and ``rho - rho0`` of :func:`_coef_jacobian`, formed once per ray set."""

    def __init__(self, rho, rho0):
        self.rho = rho
        self.rho2 = rho * rho
        self.drho = rho - rho0


def _coef_jacobian(rec, factors):
    """Jacobian ``d delta / d c`` of shape (3, n, 6) (components e1, e2, n0) by the chain rule.

    ``gamma`` depends on ``(a_g, b_g)`` through ``(rho, rho^2)``, ``d`` on
    ``(a_d, b_d)`` likewise, and ``phi`` on ``(phi0, s_phi)`` through
    ``(1, rho - rho0)``: the factors of ``factors`` (:class:`_JacobianFactors`).
    """
    dgamma, dd, dphi = rec.derivatives()
    rho, rho2, drho = factors.rho, factors.rho2, factors.drho
    jac = np.empty((3, len(rho), _N_COEF))
    np.multiply(dgamma, rho, out=jac[:, :, 0])
    np.multiply(dgamma, rho2, out=jac[:, :, 1])
    np.multiply(dd, rho, out=jac[:, :, 2])
    np.multiply(dd, rho2, out=jac[:, :, 3])
    jac[:, :, 4] = dphi
    np.multiply(dphi, drho, out=jac[:, :, 5])
    return jac


def _tip_from_coef(rho, c, p0, basis, rho0, jac=False):
    """Tip positions for magnitudes ``rho`` and shared or per-sample coefficients ``c``.

    Parameters
    ----------
    rho : ndarray of shape (n,)
        Motor-input magnitudes (deg).
    c : ndarray of shape (n, 6) or (6,)
        Coefficients (:data:`COEF_NAMES`).
    p0, basis, rho0
        As in :class:`PDLParams`.
    jac : bool
        Whether to return the Jacobian with respect to ``c``.

    Returns
    -------
    p : ndarray of shape (n, 3)
        Tip positions (mm); exactly ``p0`` where ``rho = 0``.
    dp_dc : ndarray of shape (n, 3, 6)
        Only if ``jac``: ``d p_i / d c_i`` (chain rule through ``gamma``,
        ``d`` and ``phi``).
    """
    rec = _Reconstruction(*_responses(rho, c, rho0), float(np.linalg.norm(p0)))
    p = p0 + np.ascontiguousarray(rec.components().T) @ basis
    if not jac:
        return p
    return p, np.einsum("anc,ax->nxc", _coef_jacobian(rec, _JacobianFactors(rho, rho0)), basis)


@kernel
def _ray_blocks(n_rays):
    """Offsets in :meth:`PDLParams.pack` of the blocks of ``n_rays`` rays.

    Returns
    -------
    relative, span, lower, upper : int
        The ray directions relative to the first one (``n_rays``), the spans
        to the next ray (``n_rays``), the coefficients of every ray, row by
        row (``6 n_rays``), and those of its upper neighbour (``6 n_rays``).
    """
    span = PDL_RAYS + n_rays
    lower = span + n_rays
    return PDL_RAYS, span, lower, lower + _N_COEF * n_rays


@kernel
def pdl_section(gamma, dist, phi, big_p):
    """Tip coordinates along the PDL basis from one ray's interpolated section.

    The scalar form of :class:`_Reconstruction` (which the calibration
    evaluates on many samples at once, with derivatives).

    Parameters
    ----------
    gamma : float
        Twice the inclination of the tip vector from ``n0`` (rad).
    dist : float
        Distance of the tip from the neutral tip (mm).
    phi : float
        Azimuth of the tip vector about ``n0`` (rad).
    big_p : float
        Distance of the neutral tip from the origin, ``|p0|`` (mm).

    Returns
    -------
    c1, c2, c3 : float
        Coordinates along ``e1``, ``e2``, ``n0`` (mm), before adding ``p0``.
    """
    h = 0.5 * gamma
    ch, sh = math.cos(h), math.sin(h)
    disc = dist * dist - (big_p * sh) ** 2
    s = math.copysign(math.sqrt(abs(disc)), disc) if disc != 0.0 else 0.0
    across = (big_p * ch + s) * sh
    return across * math.cos(phi), across * math.sin(phi), s * ch - big_p * sh * sh


@tip_kernel("PDLParams")
def pdl_kernel(theta, q1, q2):
    """Tip of the PDL backbone for one motor sample: the one scalar form of eq. 5.

    Polar input about ``q_n``, the ray at or before its direction (binary
    search), the coefficients interpolated linearly towards the next ray, the
    responses ``gamma``, ``d``, ``phi``, and the section's geometry
    (:func:`pdl_section`). Plain ``math`` on floats, compiled by numba where
    it is available (see :mod:`skcath._kernel`); :func:`pdl_tip` runs it on
    every row and the streaming estimator on every sample.
    """
    n = int(theta[PDL_N_RAYS])
    relative, span, lower_at, upper_at = _ray_blocks(n)
    v1 = q1 - theta[PDL_Q_NEUTRAL]
    v2 = q2 - theta[PDL_Q_NEUTRAL + 1]
    rho = math.hypot(v1, v2)
    offset = (math.atan2(v2, v1) - theta[PDL_FIRST]) % _TWO_PI
    k = bisect_right(theta, offset, relative, relative + n) - relative - 1
    k = min(max(k, 0), n - 1)
    w = (offset - theta[relative + k]) / theta[span + k]
    w = min(max(w, 0.0), 1.0)
    a = lower_at + _N_COEF * k
    b = upper_at + _N_COEF * k
    wl = 1.0 - w
    gamma = rho * ((wl * theta[a] + w * theta[b]) + (wl * theta[a + 1] + w * theta[b + 1]) * rho)
    dist = rho * ((wl * theta[a + 2] + w * theta[b + 2]) + (wl * theta[a + 3] + w * theta[b + 3]) * rho)
    phi = (wl * theta[a + 4] + w * theta[b + 4]) + (wl * theta[a + 5] + w * theta[b + 5]) * (
        rho - theta[PDL_RHO0]
    )
    c1, c2, c3 = pdl_section(gamma, dist, phi, theta[PDL_BIG_P])
    p, B = PDL_P0, PDL_BASIS
    return (
        theta[p] + c1 * theta[B] + c2 * theta[B + 3] + c3 * theta[B + 6],
        theta[p + 1] + c1 * theta[B + 1] + c2 * theta[B + 4] + c3 * theta[B + 7],
        theta[p + 2] + c1 * theta[B + 2] + c2 * theta[B + 5] + c3 * theta[B + 8],
    )


_PDL_ROWS = row_loop(pdl_kernel)


def _check_q(q):
    """Motor angles as a finite float array of shape (n, 2)."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2:
        raise ValueError(f"q must have shape (n_samples, 2) (motor angles, deg); got {q.shape}.")
    if not np.all(np.isfinite(q)):
        bad = np.flatnonzero(~np.all(np.isfinite(q), axis=1))
        raise ValueError(f"q must be finite; rows {bad[:10].tolist()} are not.")
    return q


@validate_params({"q": ["array-like"], "params": [PDLParams]}, prefer_skip_nested_validation=True)
def pdl_tip(q, params):
    """Nominal tip position of the per-direction linear backbone.

    For each sample, ``rho = |q - q_n|`` and ``psi = atan2`` of ``q - q_n``;
    the coefficients are interpolated linearly in ``psi`` between the two
    neighbouring rays (periodically, with unwrapped ``phi0``), the responses

    .. math::

        \\gamma = a_\\gamma \\rho + b_\\gamma \\rho^2, \\quad
        d = a_d \\rho + b_d \\rho^2, \\quad
        \\varphi = \\varphi_0 + s_\\varphi (\\rho - \\rho_0)

    are evaluated, and the tip is the point ``r u`` along the tip direction
    ``u = cos(gamma/2) n0 + sin(gamma/2) (cos(phi) e1 + sin(phi) e2)`` at
    distance ``d`` from the neutral tip ``p0`` (far root,
    ``r = P cos(gamma/2) + sgn(D) sqrt(|D|)``, ``D = d^2 - P^2 sin^2(gamma/2)``,
    ``P = |p0|``). At ``q = q_n`` the tip is ``p0`` exactly. Every row is
    evaluated by :func:`pdl_kernel`, in a loop compiled by numba where it is
    available and in Python otherwise.

    Parameters
    ----------
    q : array-like of shape (n_samples, 2)
        Motor angles (degrees).
    params : PDLParams
        Calibrated parameters (:func:`calibrate_pdl`).

    Returns
    -------
    p : ndarray of shape (n_samples, 3)
        Tip positions in the base frame (mm).
    """
    q = _check_q(q)
    return evaluate_rows(_PDL_ROWS, params.pack(), q)


# ---------------------------------------------------------------------------
# calibration
# ---------------------------------------------------------------------------
def _reference_responses(p, p0, basis):
    """Per-sample ``gamma`` (rad), ``d`` (mm) and ``phi`` (rad) of reference tips ``p`` (mm)."""
    local = p @ basis.T  # components along e1, e2, n0
    lateral = np.hypot(local[:, 0], local[:, 1])
    gamma = 2.0 * np.arctan2(lateral, local[:, 2])
    dist = np.linalg.norm(p - p0, axis=1)
    phi = np.arctan2(local[:, 1], local[:, 0])
    return gamma, dist, phi


def _linear_fit(design, target):
    """Least-squares coefficients of ``design @ x ~ target`` (minimum norm if rank-deficient)."""
    return np.linalg.lstsq(design, target, rcond=None)[0]


def _initial_ray_coef(rho, gamma, dist, phi, rho0):
    """Initial coefficients of one ray by linear least squares on the per-sample responses.

    The azimuth is unwrapped along the ray (samples in order of increasing
    ``rho``) and fitted on samples beyond ``PHI_FIT_FRACTION`` times the ray's
    largest magnitude (all samples with ``rho > 0`` if fewer than two qualify).

    Returns
    -------
    coef : ndarray of shape (6,)
    """
    quad = np.column_stack([rho, rho * rho])
    a_g, b_g = _linear_fit(quad, gamma)
    a_d, b_d = _linear_fit(quad, dist)
    far = rho > PHI_FIT_FRACTION * rho.max()
    if np.count_nonzero(far) < 2:
        far = rho > 0.0
    order = np.argsort(rho[far], kind="stable")
    rho_far = rho[far][order]
    phi_far = np.unwrap(phi[far][order])
    phi0, s_phi = _linear_fit(np.column_stack([np.ones_like(rho_far), rho_far - rho0]), phi_far)
    return np.array([a_g, b_g, a_d, b_d, phi0, s_phi])


class _RayProblem:
    """Residuals of one ray for :func:`levenberg_marquardt`, in the basis ``(e1, e2, n0)``.

    The residual of sample ``i`` is ``basis (p(rho_i; c) - p_i)``; the basis
    is orthonormal, so the cost equals the 3-D squared error (mm^2). The
    reconstruction computed for the trial step (``jac=False``) is kept and
    reused when the solver asks for the Jacobian at the accepted step.

    Parameters
    ----------
    rho : ndarray of shape (m,)
        Motor-input magnitudes of the ray's samples (deg).
    p_ref : ndarray of shape (m, 3)
        Reference tips (mm).
    p0, basis, rho0
        As in :class:`PDLParams`.
    """

    def __init__(self, rho, p_ref, p0, basis, rho0):
        self.rho = rho
        self.rho0 = rho0
        self.big_p = float(np.linalg.norm(p0))
        self.target = ((p_ref - p0) @ basis.T).T.copy()  # (3, m)
        self._factors = _JacobianFactors(rho, rho0)
        self._last = None

    def _evaluate(self, c):
        if self._last is not None and np.array_equal(self._last[0], c):
            return self._last[1], self._last[2]
        rec = _Reconstruction(*_responses(self.rho, c, self.rho0), self.big_p)
        res = (rec.components() - self.target).ravel()
        self._last = (np.array(c, copy=True), rec, res)
        return rec, res

    def __call__(self, c, jac=True):
        rec, res = self._evaluate(c)
        if not jac:
            return res
        return res, _coef_jacobian(rec, self._factors).reshape(-1, _N_COEF)


class _RayBatch:
    """Residuals of several rays for :func:`_batched_levenberg_marquardt`, evaluated together.

    Ray ``k`` has exactly the residuals and Jacobian of
    ``_RayProblem(rho[k], p_ref[k], p0, basis, rho0)``: the responses, the
    reconstruction and the Jacobian of the rays asked for are computed in
    one pass over their samples (element by element, as for one ray), then
    cut per ray.

    Parameters
    ----------
    rho, p_ref : list of ndarray
        Per ray, the ``rho`` (deg) and ``p_ref`` (mm) of :class:`_RayProblem`.
    p0, basis
        As in :class:`PDLParams`.
    rho0 : float or list of float
        As in :class:`PDLParams`, shared or per ray (rays of calibrations
        that share ``p0`` and the basis, e.g. of one sweep's angles played
        with several half-widths).
    """

    def __init__(self, rho, p_ref, p0, basis, rho0):
        self.rho, self.rho0 = rho, rho0
        self._per_ray = np.ndim(rho0) > 0
        self.big_p = float(np.linalg.norm(p0))
        self.target = [((p - p0) @ basis.T).T.copy() for p in p_ref]
        self._groups = {}
        self._last = None

    def _group(self, ids):
        """Samples of the rays ``ids`` one after the other: ``rho``, its powers and each ray's span."""
        key = tuple(ids)
        if key not in self._groups:
            sizes = [len(self.rho[k]) for k in ids]
            ends = np.cumsum(sizes).tolist()
            rho = np.concatenate([self.rho[k] for k in ids])
            spans = {k: slice(end - size, end) for k, size, end in zip(ids, sizes, ends)}
            # per ray: each sample's own rho0, so that rho - rho0 is the ray's alone
            rho0 = np.repeat([self.rho0[k] for k in ids], sizes) if self._per_ray else self.rho0
            self._groups[key] = (rho, sizes, spans, _JacobianFactors(rho, rho0), rho0)
        return self._groups[key]

    def residuals(self, ids, c):
        """Residual vectors of the rays ``ids`` for their coefficients, the rows of ``c``."""
        rho, sizes, spans, _, rho0 = self._group(ids)
        # one ray: its coefficients broadcast; several: (n, 6), each coefficient contiguous
        per_sample = c[0] if len(ids) == 1 else np.repeat(c.T, sizes, axis=1).T
        rec = _Reconstruction(*_responses(rho, per_sample, rho0), self.big_p)
        delta = rec.components()
        self._last = (rec, spans)
        return [(delta[:, spans[k]] - self.target[k]).ravel() for k in ids]

    def jacobians(self, ids):
        """Jacobians of the rays ``ids`` at the coefficients of the last :meth:`residuals`."""
        rec, last_spans = self._last
        _, _, spans, factors, _ = self._group(ids)
        if list(last_spans) != list(ids):
            rec = rec.take(np.concatenate([np.arange(last_spans[k].start, last_spans[k].stop) for k in ids]))
        jac = _coef_jacobian(rec, factors)
        return [np.ascontiguousarray(jac[:, spans[k]]).reshape(-1, _N_COEF) for k in ids]


def _check_calibration_inputs(q, p, labels, directions, neutral):
    """Validated float / int / bool copies of the inputs of :func:`calibrate_pdl`."""
    q = _check_q(q)
    n = len(q)
    p = np.array(p, dtype=float, copy=True)
    if p.shape != (n, 3):
        raise ValueError(f"p must have shape ({n}, 3) (reference tips, mm); got {p.shape}.")
    if np.any(np.isinf(p)):
        raise ValueError("p must be finite or NaN (missing reference); it contains +-inf.")
    labels = np.asarray(labels)
    if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be integers of shape ({n},); got {labels.dtype} {labels.shape}.")
    neutral = np.asarray(neutral)
    if neutral.shape != (n,) or neutral.dtype != bool:
        raise ValueError(f"neutral must be booleans of shape ({n},); got {neutral.dtype} {neutral.shape}.")
    directions = np.array(directions, dtype=float, copy=True)
    _check_directions(directions)
    bad = (labels < -1) | (labels >= len(directions))
    if np.any(bad):
        raise ValueError(
            f"labels must be -1 or a ray index in [0, {len(directions)}); "
            f"got {np.unique(labels[bad])[:10].tolist()}."
        )
    return q, p, labels, directions, neutral


class _RayFits:
    """One calibration of :func:`calibrate_pdl`: its rays' rows and starts, then its result.

    Steps 1-3 of :func:`calibrate_pdl` on validated copies of its inputs;
    :meth:`batch` or :meth:`problems` give the rays to refine (step 4),
    :meth:`result` the parameters and summary from their solver results.
    """

    def __init__(self, q, p, labels, directions, neutral, q_neutral=None, rho0=None):
        q, p, labels, directions, neutral = _check_calibration_inputs(q, p, labels, directions, neutral)
        keep = np.all(np.isfinite(p), axis=1)
        q, p, labels, neutral = q[keep], p[keep], labels[keep], neutral[keep]
        if not np.any(neutral):
            raise ValueError("No neutral row has a finite reference tip; p0 cannot be estimated.")
        q_neutral = q[neutral].mean(axis=0) if q_neutral is None else np.asarray(q_neutral, dtype=float)
        if q_neutral.shape != (2,) or not np.all(np.isfinite(q_neutral)):
            raise ValueError(f"q_neutral must be 2 finite motor angles (deg); got {q_neutral!r}.")
        self.p0 = p[neutral].mean(axis=0)
        self.basis = _neutral_basis(self.p0)
        rho, _ = _polar(q, q_neutral)
        self.rows = [np.flatnonzero((labels == k) & ~neutral) for k in range(len(directions))]
        for k, idx in enumerate(self.rows):
            if len(idx) < MIN_RAY_SAMPLES:
                raise ValueError(
                    f"The ray at {np.rad2deg(directions[k]):.1f} deg has {len(idx)} non-neutral rows "
                    f"with finite reference tips; at least {MIN_RAY_SAMPLES} are needed."
                )
        if rho0 is None:
            rho0 = 0.5 * max(float(rho[idx].max()) for idx in self.rows)
        if not np.isfinite(rho0):
            raise ValueError(f"rho0 must be finite (deg); got {rho0!r}.")
        gamma_i, dist_i, phi_i = _reference_responses(p, self.p0, self.basis)
        self.c0 = [_initial_ray_coef(rho[idx], gamma_i[idx], dist_i[idx], phi_i[idx], rho0) for idx in self.rows]
        self.rho = [rho[idx] for idx in self.rows]
        self.p_ref = [p[idx] for idx in self.rows]
        self.q_neutral, self.directions, self.rho0 = q_neutral, directions, rho0

    def batch(self):
        """The rays as one :class:`_RayBatch`."""
        return _RayBatch(self.rho, self.p_ref, self.p0, self.basis, self.rho0)

    def problems(self):
        """Each ray's :class:`_RayProblem` and start, in ray order."""
        for rho, p_ref, c0 in zip(self.rho, self.p_ref, self.c0):
            yield _RayProblem(rho, p_ref, self.p0, self.basis, self.rho0), c0

    def result(self, results, return_info):
        """Step 5 and the return value of :func:`calibrate_pdl` from one LMResult per ray."""
        coef = np.array([result.x for result in results])
        cost = np.array([result.cost for result in results])
        n_iter = np.array([result.n_iter for result in results], dtype=int)
        converged = np.array([result.converged for result in results], dtype=bool)
        coef[:, _PHI0] = _unwrap_rays(coef[:, _PHI0])
        params = PDLParams(p0=self.p0, basis=self.basis, q_neutral=self.q_neutral,
                           directions=self.directions, coef=coef, rho0=self.rho0)
        if not return_info:
            return params
        n_samples = np.array([len(idx) for idx in self.rows])
        info = {
            "cost": float(cost.sum()),
            "rmse_mm": float(np.sqrt(2.0 * cost.sum() / n_samples.sum())),
            "ray_rmse_mm": np.sqrt(2.0 * cost / n_samples),
            "n_samples": n_samples,
            "n_iter": int(n_iter.max()),
            "ray_n_iter": n_iter,
            "converged": bool(converged.all()),
            "ray_converged": converged,
        }
        return params, info


@validate_params(
    {
        "q": ["array-like"],
        "p": ["array-like"],
        "labels": ["array-like"],
        "directions": ["array-like"],
        "neutral": ["array-like"],
        "q_neutral": ["array-like", None],
        "rho0": [Real, None],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "return_info": ["boolean"],
        "solver": [callable, None],
    },
    prefer_skip_nested_validation=True,
)
def calibrate_pdl(
    q,
    p,
    labels,
    directions,
    neutral,
    *,
    q_neutral=None,
    rho0=None,
    max_iter=50,
    return_info=False,
    solver=None,
):
    """Calibrate the per-direction linear backbone on a multidirectional sweep.

    1. Rows whose reference tip has a NaN are dropped (never imputed); all
       statistics below use the remaining rows only.
    2. ``p0`` is the mean reference tip of the neutral rows (it averages the
       hysteresis offsets left by the different rays); the basis is
       ``n0 = p0 / |p0|``, ``e1`` the normalised component of the x axis (or
       y) orthogonal to ``n0``, ``e2 = n0 x e1``.
    3. For each ray ``k`` (rows with ``labels == k`` that are not neutral),
       the per-sample inclination ``gamma_i = 2 angle(p_i, n0)``, distance
       ``d_i = |p_i - p0|`` and azimuth ``phi_i`` give initial coefficients by
       linear least squares (``gamma, d ~ a rho + b rho^2``;
       ``phi ~ phi0 + s (rho - rho0)`` on unwrapped azimuths of the samples
       beyond 0.2 times the ray's largest ``rho``).
    4. The six coefficients of each ray are refined by damped Gauss-Newton
       (:func:`~skcath.backbones.levenberg_marquardt`) on the 3-D residuals
       ``p(rho_i) - p_i`` of its rows, with ``p0`` and the basis fixed and an
       analytic Jacobian. Rays are independent; they are solved together,
       each with exactly the steps (and results) that the solver takes on
       it alone, so that the per-call cost of each step is paid once for
       all the rays still being refined.
    5. ``phi0`` is unwrapped from ray to ray.

    Parameters
    ----------
    q : array-like of shape (n_samples, 2)
        Motor angles of the sweep (degrees).
    p : array-like of shape (n_samples, 3)
        Reference tip positions in the base frame (mm); rows with NaN are ignored.
    labels : array-like of int, shape (n_samples,)
        Ray index of each row (into ``directions``), or -1.
    directions : array-like of shape (K,)
        Ray directions (rad), strictly increasing in ``[-pi, pi)``, K >= 2.
    neutral : array-like of bool, shape (n_samples,)
        Rows at the neutral motor position.
    q_neutral : array-like of shape (2,), optional
        Neutral motor angles ``q_n`` (degrees); default: mean of ``q`` over
        the neutral rows.
    rho0 : float, optional
        Reference magnitude of the azimuth law (degrees); default: half the
        largest ``rho`` of the ray rows.
    max_iter : int
        Largest number of Gauss-Newton steps per ray.
    return_info : bool
        Whether to also return a summary of the fit.
    solver : callable, default=None
        The least-squares solver of every ray, as for
        :func:`~skcath.backbones.calibrate_pcc`, called on each ray in
        turn; None means :func:`~skcath.backbones.levenberg_marquardt` on all
        the rays together (the same numbers as passing it).

    Returns
    -------
    params : PDLParams
    info : dict
        Only if ``return_info``: ``cost`` (``0.5 sum |p(rho_i) - p_i|^2``
        over the ray rows, mm^2), ``rmse_mm`` (root mean squared 3-D error
        over the ray rows, mm), ``ray_rmse_mm`` (K,), ``n_samples`` (K,) rows
        per ray, ``n_iter`` (largest number of Jacobian evaluations of a ray),
        ``ray_n_iter`` (K,), ``converged`` (all rays) and ``ray_converged`` (K,).

    Raises
    ------
    ValueError
        On malformed inputs, without neutral rows, or when a ray has fewer
        than 6 rows with finite references (the message names its direction
        in degrees).
    """
    fit = _RayFits(q, p, labels, directions, neutral, q_neutral, rho0)
    if solver is None:  # the rays together, each with the steps of levenberg_marquardt
        results = _batched_levenberg_marquardt(fit.batch(), np.array(fit.c0), max_iter=max_iter, ftol=FTOL)
    else:
        results = [solver(problem, c0, max_iter=max_iter, ftol=FTOL) for problem, c0 in fit.problems()]
    return fit.result(results, return_info)
