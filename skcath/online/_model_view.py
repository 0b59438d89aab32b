"""The model's next tip at candidate angles: a look-ahead view of a started estimator's step.

A controller inverts the model of an :class:`~skcath.online.OnlineEstimator`:
it asks for the tip the model would estimate for the next sample at
candidate effective motor angles (the angles the backbone reads, after the
hysteresis in front of it), from the state the stream has reached, without
advancing that state. :class:`ModelView` gives that on the estimator's own
packed step (the one function both engines run,
:func:`~skcath.online._kernels.step`):

* :meth:`ModelView.advance` sets the stream's state aside and steps the
  model, with its hysteresis, by samples commanded but not observed yet;
  evaluations start from the state reached;
* :meth:`ModelView.tip` is the model's tip at effective angles from that
  state, the hysteresis skipped (:func:`~skcath.online._layout.without_hysteresis`, the one place
  that switches it off), the state restored after the evaluation;
* :meth:`ModelView.restore` gives the stream its state back.

:meth:`ModelView.compiled` gives the same on the numba engine as arrays and
compiled kernels (:mod:`skcath.online._model_view_jit`) that compiled code
calls without going back to Python.
"""

from __future__ import annotations

import numpy as np

from .._kernel import kernel
from ._layout import F_PLAY_WIDTH, M_ANGLES, without_hysteresis

__all__ = ["ModelView"]


class ModelView:
    """Look-ahead evaluations of a started estimator's step; see the module's docstring.

    Parameters
    ----------
    packed : PackedStep
        The estimator's packed step (its engine's subclass); its state is
        read, and restored after every evaluation.
    backbone : callable
        ``backbone(*angles) -> (x, y, z)``: the backbone's nominal tip (mm)
        at motor angles (deg), without the residual or the hysteresis.

    Attributes
    ----------
    n_motors : int
        Number of motors.
    engine : str
        The estimator's engine, ``"numpy"`` or ``"numba"``.
    play_width : float
        Half-width of the play in front of the backbone (deg); 0 without.
    effective : ndarray of shape (n_motors,)
        Effective angles of the last step (deg): the angles the backbone read,
        played where there is a play; a view of the step's state.
    n_evaluations : int
        Evaluations of :meth:`tip` so far (the compiled kernels do not count).
    """

    def __init__(self, packed, backbone):
        self._call = packed.call  # call(out, sample, check)
        self._packed = packed
        self._f, self._buf = packed.f, packed.buf
        self._saved = (packed.f.copy(), packed.buf.copy())
        self._f0, self._buf0 = packed.f.copy(), packed.buf.copy()
        self.backbone = backbone
        self.n_motors = packed.play.size
        self.engine = packed.engine
        self.play_width = float(packed.f[F_PLAY_WIDTH])
        self.n_evaluations = 0
        at = int(packed.meta[M_ANGLES])  # the angles the backbone read last: played, or as sampled
        self.effective = packed.f[at : at + self.n_motors]

    def advance(self, samples):
        """Set the stream's state aside and step the model by ``samples``; evaluations start there.

        Parameters
        ----------
        samples : sequence of tuple of float
            The samples commanded but not observed yet (each the channels
            of the estimator), oldest first; stepped with the hysteresis.
        """
        np.copyto(self._saved[0], self._f)
        np.copyto(self._saved[1], self._buf)
        out = np.empty(3)
        for sample in samples:
            self._call(out, tuple(sample), False)
        np.copyto(self._f0, self._f)
        np.copyto(self._buf0, self._buf)

    def restore(self):
        """Give the stream the state it had before :meth:`advance`."""
        np.copyto(self._f, self._saved[0])
        np.copyto(self._buf, self._saved[1])

    def tip(self, z, torques, out):
        """Model tip (mm) of the next sample at effective angles ``z`` (deg), into ``out``.

        ``torques`` are the sample's torques (a tuple, empty without them).
        From the state of :meth:`advance`, the hysteresis skipped; that
        state is restored after the evaluation.
        """
        without_hysteresis(self._f)
        self._call(out, (*z.tolist(), *torques), False)
        np.copyto(self._f, self._f0)
        np.copyto(self._buf, self._buf0)
        self.n_evaluations += 1
        return out

    def compiled(self):
        """The arrays and kernels of the same evaluations for compiled code (numba engine only).

        Returns
        -------
        arrays : tuple of ndarray
            ``(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0)``: the
            step's arrays (:class:`~skcath.online._jit.JitStep`, ``f``
            first in ``a64``, ``buf`` first in ``anet``), then the stream's
            state set aside and the state evaluations start from.
        advance, restore, tip : numba dispatchers
            :func:`~skcath.online._model_view_jit.advance`,
            :func:`~skcath.online._model_view_jit.restore` and
            :func:`~skcath.online._model_view_jit.tip`, called on
            ``*arrays`` first (see there).
        """
        if self.engine != "numba":
            raise ValueError(f"compiled look-ahead kernels need the numba engine; this step runs on {self.engine}.")
        from ._model_view_jit import kernels

        p = self._packed
        arrays = (p.meta, p.a64, p.anet, p.w32, *self._saved, self._f0, self._buf0)
        return (arrays, *kernels())
