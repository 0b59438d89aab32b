"""Several PDL calibrations of one sweep, all their rays refined together.

The searches of a hysteresis (:func:`~skcath.backbones.identify_play_width`,
:func:`~skcath.backbones._pi_sweep.identify_sweep_pi`) calibrate the backbone
on the sweep's angles passed through a grid of half-widths. Those
calibrations share the reference tips, the neutral rows and the rays; only
the effective motor angles differ. Their rays are independent least-squares
problems, so :func:`_calibrate_pdl_batch` refines the rays of all of them in
one :func:`~skcath.backbones._lm._batched_levenberg_marquardt`, each ray with
exactly the steps (and results) that
:func:`~skcath.backbones.levenberg_marquardt` takes on it alone: every
calibration equals :func:`~skcath.backbones.calibrate_pdl` on its angles, bit
for bit, while the per-call cost of a step is paid once for all the rays
still being refined.
"""

import numpy as np

from ._lm import _batched_levenberg_marquardt
from ._pdl import FTOL, _RayBatch, _RayFits

__all__ = []


def _calibrate_pdl_batch(qs, p, labels, directions, neutral, *, q_neutral=None, max_iter=50):
    """``calibrate_pdl(q, p, labels, directions, neutral, return_info=True)`` for every ``q`` of ``qs``.

    The calibrations share the reference tips and the neutral rows, hence
    the neutral tip ``p0`` and the basis; their rays (each with its
    calibration's ``rho0``) are refined in one batched solve, and the
    numbers are those of :func:`~skcath.backbones.calibrate_pdl` on each
    ``q`` alone.

    Parameters
    ----------
    qs : list of array-like of shape (n_samples, 2)
        Motor angles of the sweep (deg), one array per calibration.
    p, labels, directions, neutral, q_neutral, max_iter
        As in :func:`~skcath.backbones.calibrate_pdl`, shared by all the
        calibrations.

    Returns
    -------
    calibrations : list of (PDLParams, dict)
        ``(params, info)`` of each ``q``, in the order of ``qs``.
    """
    fits = [_RayFits(q, p, labels, directions, neutral, q_neutral) for q in qs]
    if not fits:
        return []
    batch = _RayBatch([r for fit in fits for r in fit.rho], [p for fit in fits for p in fit.p_ref],
                      fits[0].p0, fits[0].basis, [fit.rho0 for fit in fits for _ in fit.rho])
    c0 = np.array([c for fit in fits for c in fit.c0])
    results = _batched_levenberg_marquardt(batch, c0, max_iter=max_iter, ftol=FTOL)
    ends = np.cumsum([len(fit.rho) for fit in fits]).tolist()
    return [fit.result(results[end - len(fit.rho):end], True) for fit, end in zip(fits, ends)]
