"""Conversion between the long recording format and padded per-run arrays.

Sequence models (recurrent networks, temporal convolutions) consume one
sequence per run. :func:`to_padded` gathers the rows of every run, in row
(= time) order, into a zero-padded array of shape ``(n_runs, T_max,
n_features)`` with a boolean mask; :func:`from_padded` scatters per-step
outputs back to the rows of the original frame. Rows of different runs are
never mixed: padded row ``k`` holds only rows of the ``k``-th run.

Both conversions are vectorised (one gather / one scatter over all rows).

A sequence model counts time in samples. :func:`run_rates` gives the sample
rate of every run, and :func:`resample_runs` brings runs to one rate (linear
interpolation in time on a uniform grid), the rule the residual learners
apply themselves to a run recorded at another rate than their training runs
(``docs/residuals.rst``, *Sample rates*).

Examples
--------
>>> padded = to_padded(X, ["q1", "q2"], y=y, phase="motion")  # doctest: +SKIP
>>> out = model(torch.from_numpy(padded.values))              # doctest: +SKIP
>>> per_row = from_padded(out.detach().cpu().numpy(), padded)  # doctest: +SKIP
"""

from ._rate import resample_runs, run_rates
from ._runs import PaddedRuns, from_padded, to_padded

__all__ = ["PaddedRuns", "from_padded", "resample_runs", "run_rates", "to_padded"]
