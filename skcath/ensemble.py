"""Predictive uncertainty from a seed ensemble, and its calibration.

:class:`SeedEnsembleRegressor` fits several copies of one estimator that
differ only in their random seeds (weight initialisation and batch order of
a residual learner) and returns the member mean as the estimate and the
spread of the members as its uncertainty, per sample and per coordinate.
:func:`coverage` checks that uncertainty on held-out data: the fraction of
errors within ``k`` standard deviations, to be compared with the Gaussian
68.3 % (``k=1``) and 95.4 % (``k=2``). See ``docs/uncertainty.rst``.
"""

from __future__ import annotations

import copy
from numbers import Integral, Real

import numpy as np
from scipy.special import erf
from scipy.stats import chi2
from sklearn.base import BaseEstimator, MetaEstimatorMixin, RegressorMixin, _fit_context, clone
from sklearn.exceptions import NotFittedError
from sklearn.pipeline import Pipeline
from sklearn.utils import check_random_state, get_tags
from sklearn.utils._param_validation import HasMethods, Interval, StrOptions, validate_params
from sklearn.utils.parallel import Parallel, delayed
from sklearn.utils.validation import check_is_fitted

from ._base import RecordingsMixin

__all__ = ["SeedEnsembleRegressor", "coverage", "random_state_params"]


def random_state_params(estimator):
    """Names of the seed parameters of ``estimator``, nested ones included.

    A seed parameter is one named ``random_state`` or ending in
    ``__random_state`` in ``estimator.get_params(deep=True)``, such as
    ``"residual__random_state"`` in a pipeline whose step ``"residual"``
    takes a seed.

    Parameters
    ----------
    estimator : estimator instance

    Returns
    -------
    names : list of str
        Sorted parameter names; empty when the estimator takes no seed.
    """
    return sorted(
        key
        for key in estimator.get_params(deep=True)
        if key == "random_state" or key.endswith("__random_state")
    )


def _fit_member(member, X, y, fit_params):
    return member.fit(X, y, **fit_params)


def _predict_member(member, X):
    return np.asarray(member.predict(X), dtype=np.float64)


def _final_step(estimator):
    """The last step of a (nested) Pipeline, or the estimator itself."""
    while isinstance(estimator, Pipeline):
        estimator = estimator.steps[-1][1]
    return estimator


class SeedEnsembleRegressor(MetaEstimatorMixin, RegressorMixin, BaseEstimator):
    """Ensemble of one regressor fitted with different seeds; mean and spread.

    ``fit`` clones ``estimator`` ``n_estimators`` times and gives every
    clone (member) its own seeds: each parameter of the clone named
    ``random_state`` or ending in ``__random_state`` (see
    :func:`random_state_params`) is set to an integer drawn from
    ``random_state``. The members are otherwise identical and see the same
    data, so they differ only by what the seeds control: for a residual
    learner, the weight initialisation, the order of the training batches and
    the validation split. With members :math:`f_1, \\dots, f_K`, the
    estimate and its uncertainty for a sample :math:`x` are, per output
    coordinate,

    .. math::

        \\mu(x) = \\frac{1}{K} \\sum_{k=1}^{K} f_k(x), \\qquad
        \\sigma(x) = \\sqrt{\\frac{1}{K - 1} \\sum_{k=1}^{K}
        \\bigl(f_k(x) - \\mu(x)\\bigr)^2},

    the member mean and the sample standard deviation of the members
    (``ddof=1``, in the unit of the target: mm for tip positions).

    :math:`\\sigma` measures how much the fitted model depends on the seed,
    which is only part of the error: it does not see the error shared by
    all members (the backbone's, or what the training data cannot teach).
    Check it on held-out data with :func:`coverage` before relying on it.

    Parameters
    ----------
    estimator : estimator instance
        The regressor to fit ``n_estimators`` times, for instance a
        residual learner such as :class:`~skcath.residuals.GRUResidual`, or
        a whole :class:`~sklearn.pipeline.Pipeline` of a backbone and a
        residual learner. It must take at least one seed parameter; without
        one all members would be the same model.
    n_estimators : int, default=5
        Number of members :math:`K`, at least 2.
    random_state : int, RandomState instance or None, default=None
        Draws the seeds of the members. An int gives the same members, hence
        the same predictions, on every fit (for estimators that are
        reproducible with a fixed seed). None draws them from numpy's global
        random state.
    n_jobs : int or None, default=None
        Members fitted (and predicted) in parallel with joblib. None means 1
        unless in a :obj:`joblib.parallel_backend` context; -1 uses all
        processors. With torch models, give each member one thread (e.g.
        ``GRUResidual(n_threads=1)``) when members run in parallel.

    Attributes
    ----------
    estimators_ : list of estimators
        The fitted members, in the order of their seeds.
    seeds_ : list of dict
        The seed parameters given to each member (``{name: int}``).
    n_features_in_ : int
        Number of features (columns) seen in ``fit``, from the first member.
    feature_names_in_ : ndarray of str
        Names of the features seen in ``fit``, from the first member, when it
        has them.

    See Also
    --------
    coverage : Fraction of held-out errors within ``k`` standard deviations.

    Notes
    -----
    For a pipeline of a backbone and a residual learner, the backbone is
    deterministic (it is calibrated on each run's own sweep). Putting the
    ensemble *inside* the pipeline, as its last step, calibrates the
    backbone once instead of once per member and gives the same mean and
    spread::

        Pipeline([("backbone", PDLBackbone()),
                  ("residual", SeedEnsembleRegressor(GRUResidual()))])

    :meth:`sklearn.pipeline.Pipeline.predict` passes ``return_std=True`` on
    to its last step, so ``pipe.predict(X, return_std=True)`` works in both
    arrangements.

    ``score`` follows the members' estimator: for the estimators of
    recordings in skcath (a pipeline ending in one) it is the negated mean
    per-run RMSE of the ensemble mean over motion rows, otherwise the
    coefficient of determination :math:`R^2`.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn.tree import DecisionTreeRegressor
    >>> from skcath.ensemble import SeedEnsembleRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.normal(size=(100, 4))
    >>> y = X[:, 0] + 0.1 * rng.normal(size=100)
    >>> ensemble = SeedEnsembleRegressor(
    ...     DecisionTreeRegressor(max_features=2, max_depth=3), random_state=0
    ... ).fit(X, y)
    >>> mean, std = ensemble.predict(X[:3], return_std=True)
    >>> mean.shape, std.shape
    ((3,), (3,))
    """

    _parameter_constraints: dict = {
        "estimator": [HasMethods(["fit", "predict"])],
        "n_estimators": [Interval(Integral, 2, None, closed="left")],
        "random_state": ["random_state"],
        "n_jobs": [None, Integral],
    }

    def __init__(self, estimator, *, n_estimators=5, random_state=None, n_jobs=None):
        self.estimator = estimator
        self.n_estimators = n_estimators
        self.random_state = random_state
        self.n_jobs = n_jobs

    def _member_seeds(self):
        """One ``{parameter: int}`` per member, drawn from ``random_state``."""
        names = random_state_params(self.estimator)
        if not names:
            raise ValueError(
                f"{type(self).__name__} needs an estimator with a seed parameter "
                "(random_state, or a nested parameter ending in __random_state), but "
                f"{type(self.estimator).__name__} has none, so all "
                f"{self.n_estimators} members would be the same model. Use an "
                "estimator that takes random_state."
            )
        rng = check_random_state(self.random_state)
        top = np.iinfo(np.int32).max
        return [{name: int(rng.randint(top)) for name in names} for _ in range(self.n_estimators)]

    @_fit_context(prefer_skip_nested_validation=False)  # the members validate their own
    def fit(self, X, y, **fit_params):
        """Fit ``n_estimators`` clones of ``estimator``, each with its own seeds.

        Parameters
        ----------
        X : array-like or pandas.DataFrame
            Training input, passed unchanged to every member (recordings in
            the long format for skcath's estimators).
        y : array-like of shape (n_samples,) or (n_samples, n_outputs)
            Training targets (mm for tip positions), passed unchanged.
        **fit_params : dict
            Passed to the ``fit`` of every member.

        Returns
        -------
        self : object
            The fitted ensemble.
        """
        seeds = self._member_seeds()
        members = [clone(self.estimator).set_params(**seed) for seed in seeds]
        self.estimators_ = Parallel(n_jobs=self.n_jobs)(
            delayed(_fit_member)(member, X, y, fit_params) for member in members
        )
        self.seeds_ = seeds
        return self

    def predict_members(self, X):
        """Predictions of every member.

        Parameters
        ----------
        X : array-like or pandas.DataFrame
            Input, passed unchanged to every member.

        Returns
        -------
        y_members : ndarray of shape (n_estimators, n_samples) or \
(n_estimators, n_samples, n_outputs)
            ``y_members[k]`` is ``estimators_[k].predict(X)`` as floats.
        """
        check_is_fitted(self)
        preds = Parallel(n_jobs=self.n_jobs)(
            delayed(_predict_member)(member, X) for member in self.estimators_
        )
        shapes = {p.shape for p in preds}
        if len(shapes) != 1:
            raise ValueError(
                f"The members predicted arrays of different shapes {sorted(shapes)}; "
                "they must agree to be averaged."
            )
        return np.stack(preds)

    def predict(self, X, return_std=False):
        """Member mean, and optionally the member standard deviation.

        Parameters
        ----------
        X : array-like or pandas.DataFrame
            Input, passed unchanged to every member.
        return_std : bool, default=False
            Also return the standard deviation of the members (``ddof=1``).

        Returns
        -------
        y_mean : ndarray of shape (n_samples,) or (n_samples, n_outputs)
            Mean of the members' predictions (mm for tip positions).
        y_std : ndarray of the same shape as ``y_mean``
            Standard deviation of the members' predictions per sample and
            output, in the unit of ``y_mean``; only with ``return_std=True``.
        """
        members = self.predict_members(X)
        mean = members.mean(axis=0)
        if not return_std:
            return mean
        return mean, members.std(axis=0, ddof=1)

    def score(self, X, y, sample_weight=None):
        """Score of the ensemble mean, as the members' estimator scores.

        For skcath's estimators of recordings (or a pipeline that ends in
        one) the negated mean per-run RMSE (mm) over motion rows, as their
        own ``score``; otherwise :math:`R^2` (see
        :meth:`sklearn.base.RegressorMixin.score`).

        Parameters
        ----------
        X : array-like or pandas.DataFrame
            Test input.
        y : array-like of shape (n_samples,) or (n_samples, n_outputs)
            True targets.
        sample_weight : array-like of shape (n_samples,), default=None
            Sample weights for :math:`R^2`; not supported for recordings.

        Returns
        -------
        score : float
        """
        if isinstance(_final_step(self.estimator), RecordingsMixin):
            return RecordingsMixin.score(self, X, y, sample_weight=sample_weight)
        return super().score(X, y, sample_weight=sample_weight)

    def _from_first_member(self, name):
        """Attribute ``name`` of the first fitted member; AttributeError before ``fit``."""
        try:
            check_is_fitted(self)
        except NotFittedError as exc:
            raise AttributeError(
                f"{type(self).__name__} object has no {name} attribute before fit."
            ) from exc
        return getattr(self.estimators_[0], name)

    @property
    def n_features_in_(self):
        """Number of features seen in ``fit`` (from the first member)."""
        return self._from_first_member("n_features_in_")

    @property
    def feature_names_in_(self):
        """Names of the features seen in ``fit`` (from the first member)."""
        return self._from_first_member("feature_names_in_")

    def __sklearn_is_fitted__(self):
        return hasattr(self, "estimators_")

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        inner = get_tags(self.estimator)
        tags.input_tags = copy.deepcopy(inner.input_tags)
        tags.target_tags = copy.deepcopy(inner.target_tags)
        tags.non_deterministic = inner.non_deterministic
        return tags


def _as_2d(values, name, shape=None):
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(
            f"{name} must have shape (n_samples,) or (n_samples, n_outputs); got {arr.shape}."
        )
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have the shape of y_true, {shape}; got {arr.shape}.")
    return arr


def _check_k(k):
    scalar = np.ndim(k) == 0
    values = np.atleast_1d(np.asarray(k, dtype=np.float64))
    if values.ndim != 1 or values.size == 0 or not (np.isfinite(values) & (values > 0)).all():
        raise ValueError(f"k must be a positive number or a sequence of them; got {k!r}.")
    return values, scalar


@validate_params(
    {
        "y_true": ["array-like"],
        "y_mean": ["array-like"],
        "y_std": ["array-like"],
        "k": [Real, "array-like"],  # positive: checked with the values
        "runs": ["array-like", None],
        "joint": "no_validation",  # True or False: checked below
        "multioutput": [StrOptions({"uniform_average", "raw_values"})],
    },
    prefer_skip_nested_validation=True,
)
def coverage(y_true, y_mean, y_std, *, k=(1.0, 2.0), runs=None, joint=False,
             multioutput="uniform_average"):
    """Fraction of errors within ``k`` predicted standard deviations.

    Per coordinate (``joint=False``), a sample's error is covered at ``k``
    when :math:`|y - \\mu| \\le k \\sigma`. For a calibrated Gaussian
    prediction the fraction is :math:`\\mathrm{erf}(k / \\sqrt{2})`: 68.3 %
    at ``k=1`` and 95.4 % at ``k=2``. Fractions below that mean
    over-confidence (:math:`\\sigma` too small), above it under-confidence.

    With ``joint=True`` a sample (a 3-D tip) is covered when its normalised
    squared error is within the chi-square quantile of the same
    probability,

    .. math::

        \\sum_{j=1}^{d} \\Bigl(\\frac{y_j - \\mu_j}{\\sigma_j}\\Bigr)^2 \\le
        \\chi^2_d\\bigl(\\mathrm{erf}(k / \\sqrt{2})\\bigr),

    with :math:`d` the number of outputs (3 for tip positions), so that the
    Gaussian reference is again 68.3 % and 95.4 % (the radii are 1.88 and
    2.83 for :math:`d = 3`, taking the coordinates as independent).

    Parameters
    ----------
    y_true : array-like of shape (n_samples,) or (n_samples, n_outputs)
        True values (mm for tip positions). Rows with a NaN (tracker
        dropouts) are not scored.
    y_mean : array-like of the same shape
        Predicted means, e.g. the first output of
        ``SeedEnsembleRegressor.predict(X, return_std=True)``.
    y_std : array-like of the same shape
        Predicted standard deviations, non-negative. Where it is 0 only an
        exact prediction is covered.
    k : float or sequence of float, default=(1.0, 2.0)
        Multiples of ``y_std`` at which to measure coverage, positive.
    runs : array-like of shape (n_samples,), default=None
        Run id of every sample. When given, the fraction is computed per run
        and the runs are averaged with equal weights (runs without a scored
        sample are left out), as skcath's error metrics do. Select the rows
        to score beforehand (motion rows for tip estimates: a residual
        learner predicts the backbone on sweep rows, where its members
        agree).
    joint : bool, default=False
        Measure the joint coverage of all outputs per sample (above) instead
        of each coordinate separately.
    multioutput : {"uniform_average", "raw_values"}, default="uniform_average"
        Per-coordinate coverage averaged over the outputs, or one value per
        output. Must be "uniform_average" with ``joint=True``.

    Returns
    -------
    fraction : float or ndarray
        Fraction (0-1) of covered errors: of shape ``(len(k),)`` for a
        sequence ``k`` (``(len(k), n_outputs)`` with ``"raw_values"``), a
        float (``(n_outputs,)``) for a scalar ``k``.

    Examples
    --------
    >>> import numpy as np
    >>> from skcath.ensemble import coverage
    >>> rng = np.random.default_rng(0)
    >>> y_true = rng.normal(0.0, 2.0, (100_000, 3))
    >>> coverage(y_true, np.zeros((100_000, 3)), np.full((100_000, 3), 2.0)).round(3)
    array([0.682, 0.954])
    """
    if not isinstance(joint, (bool, np.bool_)):
        raise TypeError(f"joint must be True or False; got {joint!r}.")
    if joint and multioutput != "uniform_average":
        raise ValueError("joint=True gives one value per k; leave multioutput='uniform_average'.")
    ks, scalar = _check_k(k)
    y_true = _as_2d(y_true, "y_true")
    y_mean = _as_2d(y_mean, "y_mean", y_true.shape)
    y_std = _as_2d(y_std, "y_std", y_true.shape)
    for name, arr in (("y_mean", y_mean), ("y_std", y_std)):
        if not np.isfinite(arr).all():
            raise ValueError(
                f"{name} contains NaN or infinite values; a value is expected for every sample."
            )
    if (y_std < 0).any():
        raise ValueError("y_std must be non-negative (standard deviations).")
    n, d = y_true.shape
    if runs is None:
        codes = np.zeros(n, dtype=np.intp)
    else:
        runs = np.asarray(runs)
        if runs.shape != (n,):
            raise ValueError(
                f"runs must hold one run id per sample, shape ({n},); got {runs.shape}."
            )
        codes = np.unique(runs, return_inverse=True)[1].reshape(n)
    n_runs = int(codes.max()) + 1 if n else 0
    err = np.abs(y_true - y_mean)
    if joint:
        scored = np.isfinite(y_true).all(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            z2 = np.where(err == 0.0, 0.0, (err / y_std) ** 2).sum(axis=1)
        radius2 = chi2.ppf(erf(ks / np.sqrt(2.0)), df=d)
        covered = z2[None, :] <= radius2[:, None]  # (n_k, n)
        result = _run_average(covered[..., None], scored[:, None], codes, n_runs)[:, 0]
    else:
        scored = np.isfinite(y_true)
        covered = err[None] <= ks[:, None, None] * y_std[None]  # (n_k, n, d)
        result = _run_average(covered, scored, codes, n_runs)
        if multioutput == "uniform_average":
            result = result.mean(axis=1)
    if scalar:
        result = result[0]
        return float(result) if np.ndim(result) == 0 else result
    return result


def _run_average(covered, scored, codes, n_runs):
    """Equal-weight mean over runs of the covered fraction, per k and output.

    ``covered`` has shape (n_k, n, d), ``scored`` (n, d); returns (n_k, d).
    """
    n_k, _, d = covered.shape
    out = np.empty((n_k, d))
    for j in range(d):
        rows = scored[:, j]
        counts = np.bincount(codes[rows], minlength=n_runs)
        if not counts.any():
            raise ValueError("y_true has no finite value to score.")
        has = counts > 0
        for i in range(n_k):
            hits = np.bincount(codes[rows], weights=covered[i, rows, j], minlength=n_runs)
            out[i, j] = np.mean(hits[has] / counts[has])
    return out
