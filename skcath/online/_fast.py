"""The numpy engine of the streaming estimator: the step run as Python.

:func:`~skcath.online._kernels.step` runs as Python on the packed arrays of
the run, the matrices kept whole in a list (:class:`~skcath.online._layout.MatrixStore`)
and multiplied by :func:`numpy.dot`, the vectors of ``buf`` written by numpy
calls with output arguments, so that a steady-state loop allocates no arrays.
The small arrays that Python indexes item by item (``meta``, the backbone's
``theta``) are passed as lists, whose items Python reads faster.
"""

from __future__ import annotations

import functools

from ._kernels import BackboneStep, _gru_vectors_sliced, _head_vectors_sliced, step
from ._layout import (
    F_LIMIT2,
    GRU_RECORD,
    HEAD_RECORD,
    M_HEADER,
    M_N_GRU,
    M_N_HEAD,
    M_N_MOTORS,
    M_NEUTRAL,
    MatrixStore,
    PackedStep,
)

__all__ = ["BackboneStep", "NumpyStep"]


class _Meta(list):
    """``meta`` as Python reads it: a list of its ints, ``views``, the vectors of every layer.

    ``neutral`` and ``limit2`` are the neutral motor angles and the squared
    limit of :func:`~skcath.online._kernels.accepted`, as floats.

    ``views`` maps each GRU and head record to the views of ``buf`` that
    :func:`~skcath.online._kernels.gru_vectors` and
    :func:`~skcath.online._kernels.head_vectors` give, sliced once here by the
    functions that compiled code runs, rather than at every step.
    """


class NumpyStep(PackedStep):
    """The step of one run on the numpy engine; parameters as :class:`~skcath.online._layout.PackedStep`."""

    engine = "numpy"
    compile_seconds = 0.0
    store = MatrixStore

    def _bind(self):
        # lists: Python reads their items faster than an array's
        meta = _Meta(self.meta.tolist())
        meta.views = {}
        at = meta[M_NEUTRAL]
        meta.neutral = tuple(self.f[at : at + meta[M_N_MOTORS]].tolist())
        meta.limit2 = float(self.f[F_LIMIT2])
        first_head = M_HEADER + GRU_RECORD * meta[M_N_GRU]
        for k in range(meta[M_N_GRU]):
            rec = M_HEADER + GRU_RECORD * k
            meta.views[rec] = _gru_vectors_sliced(meta, self.buf, rec)
        for k in range(meta[M_N_HEAD]):
            rec = first_head + HEAD_RECORD * k
            meta.views[rec] = _head_vectors_sliced(meta, self.buf, rec)
        return functools.partial(step, meta, self.f, self.theta.tolist(), self.w, self.w32,
                                 self.buf)
