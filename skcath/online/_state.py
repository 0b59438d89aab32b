"""A started :class:`~skcath.online.OnlineEstimator` as plain data, for the pickle-free format.

skops stores numpy arrays, numbers, strings and the containers and
estimators made of them, but not a pandas DataFrame, and a started
estimator keeps the sweep it was calibrated on as one. Before
:func:`skcath.persist.save` hands an estimator to skops,
:func:`skcath._torch_state.to_plain` replaces each ``OnlineEstimator`` by an
:class:`OnlineEstimatorState`: the estimator's pickled state (the pipeline,
the calibration, the sweep context, the folded weights taken at ``start``
and the running state of the stream, see ``OnlineEstimator.__getstate__``)
with each DataFrame in it as a :class:`FrameState` and each residual learner
as its :class:`~skcath._torch_state.ResidualLearnerState`. Loading builds the
estimator with ``OnlineEstimator.__setstate__``, as unpickling does, so the
stream resumes bit for bit where it was saved.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ._estimator import OnlineEstimator

__all__ = ["FrameState", "OnlineEstimatorState"]


def _values(values):
    """The values of an index or a column: a numeric array, or a list of Python scalars."""
    dtype = values.dtype
    if isinstance(dtype, np.dtype) and dtype.kind in "biufcmM":
        return {"array": np.asarray(values).copy()}
    items = values.tolist()
    for item in items:
        if not (item is None or isinstance(item, (str, int, float, bool))):
            raise TypeError(f"a DataFrame holds a {type(item).__name__}, not a number or a string")
    return {"items": items, "dtype": str(dtype)}


def _rebuilt(stored, name=None):
    """The inverse of :func:`_values`, as a pandas Index."""
    if "array" in stored:
        return pd.Index(stored["array"], name=name, copy=True)
    return pd.Index(stored["items"], dtype=stored["dtype"], name=name)


def _index(index):
    if type(index) is pd.RangeIndex:
        return {"range": [index.start, index.stop, index.step], "name": index.name}
    return {**_values(index), "name": index.name}


def _column(series):
    dtype = series.dtype
    if isinstance(dtype, pd.CategoricalDtype):
        return {"codes": np.asarray(series.cat.codes).copy(),
                "categories": _values(dtype.categories), "ordered": bool(dtype.ordered)}
    return _values(series)


class FrameState:
    """A pandas DataFrame as arrays, lists and strings.

    Categorical columns keep their codes, categories and order; numeric
    columns their numpy dtype; other columns (strings) their values and
    dtype. Built by :meth:`of`; :meth:`build` makes the frame again.

    Attributes
    ----------
    columns : dict
        The column labels, as stored by the index rule below.
    index : dict
        ``{"range": [start, stop, step]}`` for a RangeIndex, else its values.
    data : list of dict
        The columns, in order.
    """

    @classmethod
    def of(cls, frame):
        """The state of ``frame`` (left unchanged).

        Raises
        ------
        TypeError
            A value is neither a number nor a string.
        """
        state = cls()
        state.columns = _index(frame.columns)
        state.index = _index(frame.index)
        state.data = [_column(frame.iloc[:, j]) for j in range(frame.shape[1])]
        return state

    def build(self):
        """The DataFrame this state was made of."""
        index = self.index
        if "range" in index:
            rows = pd.RangeIndex(*index["range"], name=index["name"])
        else:
            rows = _rebuilt(index, index["name"])
        columns = self.columns
        if "range" in columns:
            labels = pd.RangeIndex(*columns["range"], name=columns["name"])
        else:
            labels = _rebuilt(columns, columns["name"])
        data = {}
        for j, stored in enumerate(self.data):
            if "codes" in stored:
                values = pd.Categorical.from_codes(
                    stored["codes"], categories=_rebuilt(stored["categories"]),
                    ordered=stored["ordered"],
                )
            else:
                values = _rebuilt(stored)
            data[j] = pd.Series(values, index=rows, copy=False)
        frame = pd.DataFrame(data, index=rows)
        frame.columns = labels
        return frame


class OnlineEstimatorState:
    """An :class:`~skcath.online.OnlineEstimator` (started or not) as plain data.

    Built by :meth:`of`; :meth:`build` makes the estimator again with its
    ``__setstate__``, which packs the step from the kept calibration and
    weights and restores the stream's state.

    Attributes
    ----------
    state : dict
        The estimator's ``__getstate__``, DataFrames as :class:`FrameState`
        and residual learners as their state.
    """

    @classmethod
    def of(cls, estimator, to_plain):
        """The state of ``estimator`` (left unchanged); ``to_plain`` converts what it holds."""
        state = cls()
        frames = {k: FrameState.of(v) if isinstance(v, pd.DataFrame) else v
                  for k, v in estimator.__getstate__().items()}
        state.state = to_plain(frames)
        return state

    def build(self, from_plain):
        """The estimator; ``from_plain`` builds what its state holds."""
        state = {k: v.build() if isinstance(v, FrameState) else v
                 for k, v in from_plain(self.state).items()}
        estimator = OnlineEstimator.__new__(OnlineEstimator)
        estimator.__setstate__(state)
        return estimator
