"""What every estimator over recordings shares: checks, fit, the run-RMSE score and the tags."""

import warnings

import numpy as np
from sklearn.base import _fit_context

from ._validation import check_recordings, check_target
from ._version import current_version
from .exceptions import InconsistentVersionWarning
from .metrics import mean_per_run_rmse

__all__ = ["RecordingsMixin"]


class RecordingsMixin:
    """Mixin of the estimators that take long-format recordings and predict tips.

    ``fit`` validates the recordings and records their columns (estimators
    that learn across runs override it), ``score`` is the negated mean per-run
    RMSE over motion rows, and the tags declare long-format input (strings,
    categories and NaN allowed) and a 3-column target. Subclasses set
    ``_target_required`` and extend ``_check_X`` with the columns they need.

    Pickling stores the skcath version in the state (``_skcath_version``);
    unpickling under another version warns with
    :class:`skcath.exceptions.InconsistentVersionWarning`.
    """

    _target_required = False

    def _check_X(self, X, y=None):
        """The checked recordings ``X`` (and tip positions ``y``, if given) of a call."""
        return check_recordings(X, y)

    def _record_columns(self, X):
        """Remember the columns of the recordings seen in ``fit``."""
        self.feature_names_in_ = np.asarray(X.columns, dtype=object)
        self.n_features_in_ = X.shape[1]

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Validate the recordings and remember their columns; nothing is learned across runs.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format (``docs/data_format.rst``) with the
            columns the estimator reads.
        y : array-like of shape (n_samples, 3), optional
            Tip positions (mm); validated if given, otherwise unused.

        Returns
        -------
        self : object
        """
        X, _ = self._check_X(X, y)
        self._record_columns(X)
        return self

    def score(self, X, y, sample_weight=None):
        """Negated mean per-run RMSE (mm) over motion rows (greater is better).

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format.
        y : array-like of shape (n_samples, 3)
            Measured tip positions (mm).
        sample_weight : None
            Not supported: runs have equal weights.

        Returns
        -------
        score : float
        """
        if sample_weight is not None:
            raise ValueError("sample_weight is not supported: the metric weights runs equally.")
        y = check_target(y, len(X))
        return -mean_per_run_rmse(y, self.predict(X), X)

    def __getstate__(self):
        # the next class in the MRO (BaseEstimator, or skorch's NeuralNet that
        # serializes the torch modules) builds the state
        state = super().__getstate__()
        if state is None or not isinstance(state, dict):  # pragma: no cover - no __dict__
            return state
        return {**state, "_skcath_version": current_version()}

    def __setstate__(self, state):
        if isinstance(state, dict) and "_skcath_version" in state:
            state = dict(state)
            saved = state.pop("_skcath_version")
            if saved != current_version():
                warnings.warn(
                    InconsistentVersionWarning(
                        estimator_name=type(self).__name__,
                        original_version=saved,
                        current_version=current_version(),
                    ),
                    stacklevel=2,
                )
        parent = getattr(super(), "__setstate__", None)
        if parent is not None:
            parent(state)
        else:  # pragma: no cover - BaseEstimator and skorch NeuralNet both define it
            self.__dict__.update(state)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True
        tags.input_tags.string = True
        tags.input_tags.categorical = True
        tags.target_tags.required = self._target_required
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = False
        return tags
