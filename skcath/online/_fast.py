"""The numpy engine of the streaming estimator: the step run as Python.

:func:`~skcath.online._kernels.step` runs as Python on the packed arrays of
the run, the matrices kept whole in a list (:class:`~skcath.online._layout.MatrixStore`)
and multiplied by :func:`numpy.dot`, the vectors of ``buf`` written by numpy
calls with output arguments, so that a steady-state loop allocates no arrays.
The small arrays that Python indexes item by item (``meta``, the backbone's
``theta``) are passed as lists, whose items Python reads faster.
"""

from __future__ import annotations

from ._kernels import BackboneStep, step
from ._layout import MatrixStore, PackedStep

__all__ = ["BackboneStep", "NumpyStep"]


class NumpyStep(PackedStep):
    """The step of one run on the numpy engine; parameters as :class:`~skcath.online._layout.PackedStep`."""

    engine = "numpy"
    compile_seconds = 0.0
    store = MatrixStore

    def _bind(self):
        # lists: Python reads their items faster than an array's
        return (step, self.meta.tolist(), self.f, self.theta.tolist(), self.w, self.w32, self.buf)
