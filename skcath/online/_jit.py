"""The numba engine of the streaming estimator: the step compiled.

:func:`~skcath.online._kernels.step` compiled by numba, with the compiled
implementations of its vector primitives (:mod:`skcath._kernel`), on the
packed arrays of the run in flat storage
(:class:`~skcath.online._layout.FlatStore`): one call from Python per step,
no array allocated. Numbers differ from the numpy engine's by rounding only:
the order of the additions inside a matrix-vector product (each product
added with one rounding, a fused multiply-add), and the
nonlinearities, which compiled code evaluates in the network's dtype with
exponentials of its own (:mod:`skcath.online._nonlinear`).

numba is an optional dependency (``pip install "skcath[fast]"``); this module
imports it and is imported only when the numba engine is selected.
"""

from __future__ import annotations

import functools
import time

import numba
import numpy as np

from .._kernel import compiled, kernel, load_numba
from . import _kernels, _nonlinear
from ._layout import M_THETA, M_W, FlatStore, PackedStep

__all__ = ["JitStep", "step_kernel"]

kernel(_kernels.step)


def _stored_together(meta, a64, anet, w32, out, sample, check):
    """:func:`~skcath.online._kernels.step` on the arrays of :meth:`JitStep._merge`.

    ``a64`` holds ``f`` then ``theta`` (from ``meta[M_THETA]``), ``anet``
    ``buf`` then ``w`` (from ``meta[M_W]``).
    """
    nf, nb = meta[M_THETA], meta[M_W]
    return _kernels.step(meta, a64[:nf], a64[nf:], anet[nb:], w32, anet[:nb], out, sample, check)


load_numba()
#: The compiled step (numba's cache: compiled once per machine and dtype).
step_kernel = compiled(_stored_together)
if step_kernel is None:
    raise ImportError("numba's compiler is disabled (NUMBA_DISABLE_JIT is set)")
_exp = compiled(_nonlinear.exp_array)
_tanh = compiled(_nonlinear.tanh_array)


class JitStep(PackedStep):
    """The step of one run on the numba engine; parameters as :class:`~skcath.online._layout.PackedStep`.

    ``compile_seconds`` is the time taken to compile the step for these
    arrays, or to load it from numba's cache (s).
    """

    engine = "numba"
    store = FlatStore
    fused = True

    def _merge(self):
        # two float arrays in place of four: fewer arguments for numba to convert at each step
        self.a64 = np.concatenate([self.f, self.theta])
        self.f, self.theta = self.a64[: self.f.size], self.a64[self.f.size :]
        self.anet = np.concatenate([self.buf, self.w])
        self.buf, self.w = self.anet[: self.buf.size], self.anet[self.buf.size :]

    def _bind(self):
        arrays = (self.meta, self.a64, self.anet, self.w32)
        self.compile_seconds, entry = _compile(arrays, self.last.size)
        # the compiled step's entry point, not numba's dispatcher: the dispatcher would
        # work out the numba type of all seven arguments at every call, to find this
        # same entry point (0.3 us a step); the arguments' types are known here
        return functools.partial(entry, *arrays)


def _compile(arrays, n_channels):
    """Compile (or load from numba's cache) the kernel for these arrays; seconds taken, entry point.

    The sample is a tuple of ``n_channels`` floats, then whether to check it:
    one compiled step per number of channels. Done when the run starts, so that the first step
    does not pay for it.

    The entry point converts its arguments to the types compiled for
    without checking them first: ``out`` must be a C-contiguous float64
    array of shape (3,) and the sample a tuple of ``n_channels`` numbers
    (anything else raises ``TypeError``, but a strided ``out`` would be
    written as if it were contiguous).
    """
    t0 = time.perf_counter()
    sample = numba.types.UniTuple(numba.float64, n_channels)
    sig = (*(numba.typeof(a) for a in (*arrays, np.empty(3))), sample, numba.boolean)
    entry = step_kernel.compile(sig)
    return time.perf_counter() - t0, entry
