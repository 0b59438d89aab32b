"""The numba engine of the streaming estimator: the step compiled.

:func:`~skcath.online._kernels.step` compiled by numba, with the compiled
implementations of its vector primitives (:mod:`skcath._kernel`), on the
packed arrays of the run in flat storage
(:class:`~skcath.online._layout.FlatStore`): one call from Python per step,
no array allocated. Numbers differ from the numpy engine's by rounding only:
the order of the additions inside a matrix-vector product, and the
nonlinearities, which compiled code evaluates in float64 whatever the
network's dtype.

numba is an optional dependency (``pip install "skcath[fast]"``); this module
imports it and is imported only when the numba engine is selected.
"""

from __future__ import annotations

import time

import numba
import numpy as np

from .._kernel import compiled, load_numba
from . import _kernels
from ._layout import FlatStore, PackedStep

__all__ = ["JitStep", "step_kernel"]

load_numba()
#: The compiled step (numba's cache: compiled once per machine and dtype).
step_kernel = compiled(_kernels.step)
if step_kernel is None:
    raise ImportError("numba's compiler is disabled (NUMBA_DISABLE_JIT is set)")
_exp = compiled(_kernels._exp)
_tanh = compiled(_kernels._tanh)


class JitStep(PackedStep):
    """The step of one run on the numba engine; parameters as :class:`~skcath.online._layout.PackedStep`.

    ``compile_seconds`` is the time taken to compile the step for these
    arrays, or to load it from numba's cache (s).
    """

    engine = "numba"
    store = FlatStore

    def _bind(self):
        arrays = (self.meta, self.f, self.theta, self.w, self.w32, self.buf)
        self.compile_seconds = _compile(arrays, self.last.size)
        return (step_kernel, *arrays)


def _compile(arrays, n_channels):
    """Compile (or load from numba's cache) the kernel for these arrays; seconds taken.

    The sample is a tuple of ``n_channels`` floats: one compiled step per
    number of channels. Done when the run starts, so that the first step
    does not pay for it.
    """
    t0 = time.perf_counter()
    sample = numba.types.UniTuple(numba.float64, n_channels)
    sig = (*(numba.typeof(a) for a in (*arrays, np.empty(3))), sample)
    step_kernel.compile(sig)
    return time.perf_counter() - t0
