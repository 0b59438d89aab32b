"""The look-ahead evaluations of :class:`~skcath.online._model_view.ModelView` compiled by numba.

Both kernels take the arrays of :meth:`ModelView.compiled
<skcath.online._model_view.ModelView.compiled>` first, ``meta, a64, anet,
w32`` (the step's arrays on the numba engine, ``f`` first in ``a64`` and
``buf`` first in ``anet``), ``saved_f, saved_buf`` (the stream's state set
aside) and ``f0, buf0`` (the state evaluations start from), and run the
estimator's compiled step (:data:`skcath.online._jit.step_kernel`) on them,
as the methods of :class:`~skcath.online._model_view.ModelView` do in
Python. They are declared kernels (:func:`~skcath._kernel.kernel`), so that
compiled code calls them by name and numba's cache knows their source.
Imported only on the numba engine (it imports numba).
"""

from __future__ import annotations

from .._kernel import compiled, kernel
from ._jit import step_kernel
from ._layout import M_ANGLES, without_hysteresis

__all__ = ["advance", "kernels", "restore", "tip"]


@kernel
def advance(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0, samples, count, torques, sample, out,
            effective):
    """Set the stream's state aside, step it by ``samples[:count]`` (hysteresis on); state of ``f0, buf0``.

    ``samples`` holds motor angles (deg), one row per sample, oldest first;
    each is stepped with ``torques`` (their channels after the angles).
    ``effective`` receives the effective angles of the state reached
    (:attr:`ModelView.effective <skcath.online._model_view.ModelView.effective>`).
    ``sample`` (n_channels,) and ``out`` (3,) are scratch.
    """
    nf, nb = f0.shape[0], buf0.shape[0]
    saved_f[:] = a64[:nf]
    saved_buf[:] = anet[:nb]
    n = samples.shape[1]
    for k in range(count):
        for j in range(n):
            sample[j] = samples[k, j]
        for j in range(torques.shape[0]):
            sample[n + j] = torques[j]
        step_kernel(meta, a64, anet, w32, out, sample, False)
    f0[:] = a64[:nf]
    buf0[:] = anet[:nb]
    at = meta[M_ANGLES]
    for j in range(effective.shape[0]):
        effective[j] = f0[at + j]


@kernel
def restore(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0):
    """Give the stream the state :func:`advance` set aside."""
    a64[: saved_f.shape[0]] = saved_f
    anet[: saved_buf.shape[0]] = saved_buf


@kernel
def tip(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0, z, torques, sample, out):
    """Model tip (mm) of the next sample at effective angles ``z`` (deg), into ``out``.

    From the state ``f0, buf0``, the hysteresis skipped; the state is
    restored after the evaluation. ``sample`` (n_channels,) is scratch.
    """
    n = z.shape[0]
    for j in range(n):
        sample[j] = z[j]
    for j in range(torques.shape[0]):
        sample[n + j] = torques[j]
    without_hysteresis(a64)
    step_kernel(meta, a64, anet, w32, out, sample, False)
    a64[: f0.shape[0]] = f0
    anet[: buf0.shape[0]] = buf0


_kernels = {}


def kernels():
    """``(advance, restore, tip)`` compiled (loaded from numba's cache when compiled before)."""
    if not _kernels:
        _kernels.update(advance=compiled(advance), restore=compiled(restore), tip=compiled(tip))
    return _kernels["advance"], _kernels["restore"], _kernels["tip"]
