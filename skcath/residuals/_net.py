"""The shared machinery of the residual learners: a skorch net over runs of recordings.

The learners of :mod:`skcath.residuals._estimators` (:class:`GRUResidual`,
:class:`MLPResidual`) are this net with their own network. It checks the
recordings, prepares the motion and sweep sequences of every run (in each
run's sweep frame with ``frame="sweep"``), fits the normalisation
statistics, cuts the training windows, and predicts the clipped residual.
"""

from __future__ import annotations

import copy
from numbers import Integral, Real

import numpy as np
import pandas as pd
import torch
from sklearn import get_config
from sklearn.base import _fit_context
from sklearn.exceptions import NotFittedError
from sklearn.frozen import FrozenEstimator
from sklearn.utils import check_random_state
from sklearn.utils._param_validation import Interval, StrOptions, validate_parameter_constraints
from sklearn.utils.validation import _check_sample_weight
from skorch import NeuralNetRegressor
from skorch.callbacks import EarlyStopping, LRScheduler, ProgressBar
from skorch.dataset import Dataset
from skorch.utils import is_dataset, to_tensor

from .. import _format as fmt
from .._base import RecordingsMixin
from .._rate import RATE_TOLERANCE, to_model_rate, training_rate
from .._runs import group_positions
from .._validation import check_recordings, check_sweeps, motor_columns
from ..backbones import BACKBONE_COLUMNS
from ..frames import FRAMES, sweep_frame
from ..sequences import from_padded, to_padded
from ._backbone_columns import check_backbone_columns, nominal_tip
from ._context import _sweep_pooling, context_input, encode_sweeps
from ._features import (
    Standardizer,
    cut_windows,
    feature_frame,
    step_feature_names,
    sweep_feature_names,
    weighted_mean_std,
)
from ._modules import MaskedNormalizedMSE
from ._runtime import _not_prepared, _SettingHoldout, _silent, _torch_runtime, check_device
from ._same_network import check_same_network
from ._time_scales import at_model_rate, check_renamed, time_scales

__all__ = []

#: The parameter values with which a residual learner reads each run's sweep:
#: the sweep frame is fitted on it, the context encoded from it.
_SWEEP_READERS = {"frame": "sweep", "use_context": True}


class _ResidualNet(RecordingsMixin, NeuralNetRegressor):
    """Shared machinery of the residual learners (not for direct use)."""

    _target_required = True

    _parameter_constraints: dict = {
        "window_s": [Interval(Real, 0, None, closed="neither"), None],
        "window_step_s": [Interval(Real, 0, None, closed="neither"), None],
        "burn_in_s": [Interval(Real, 0, None, closed="left")],
        "sweep_stride_s": [Interval(Real, 0, None, closed="neither")],
        "rate_hz": [Interval(Real, 0, None, closed="neither"), None],
        "sweep_pooling": [StrOptions({"mean", "subsample"})],
        "use_torque": ["boolean"],
        "use_context": ["boolean"],
        "frame": [StrOptions(set(FRAMES))],
        "clip": [Interval(Real, 0, None, closed="neither"), None],
        "validation_fraction": [Interval(Real, 0, 1, closed="neither"), None],
        "n_iter_no_change": [Interval(Integral, 1, None, closed="left")],
        "n_threads": [Interval(Integral, 1, None, closed="left"), None],
        "random_state": ["random_state"],
        "max_epochs": [Interval(Integral, 0, None, closed="left")],
        "batch_size": [Interval(Integral, 1, None, closed="left"), StrOptions({"-1"})],
        "lr": [Interval(Real, 0, None, closed="neither")],
        "lr_schedule": [StrOptions({"cosine", "constant"})],
    }

    def __init__(
        self,
        module,
        *,
        criterion=MaskedNormalizedMSE,
        optimizer=torch.optim.Adam,
        lr=1e-2,
        lr_schedule="cosine",
        max_epochs=40,
        batch_size=64,
        window_s=20.0,
        window_step_s=None,
        burn_in_s=5.0,
        sweep_stride_s=4.0,
        rate_hz=10.0,
        sweep_pooling="mean",
        use_torque=True,
        use_context=True,
        frame="sweep",
        clip=25.0,
        pretrained=None,
        validation_fraction=None,
        n_iter_no_change=5,
        n_threads=None,
        random_state=None,
        train_split=None,
        verbose=0,
        **kwargs,
    ):
        check_renamed(type(self).__name__, kwargs)
        kwargs.setdefault("iterator_train__shuffle", True)
        kwargs.setdefault("optimizer__weight_decay", 1e-4)
        super().__init__(
            module,
            criterion=criterion,
            optimizer=optimizer,
            lr=lr,
            max_epochs=max_epochs,
            batch_size=batch_size,
            train_split=train_split,
            verbose=verbose,
            **kwargs,
        )
        self.lr_schedule = lr_schedule
        self.window_s = window_s
        self.window_step_s = window_step_s
        self.burn_in_s = burn_in_s
        self.sweep_stride_s = sweep_stride_s
        self.rate_hz = rate_hz
        self.sweep_pooling = sweep_pooling
        self.use_torque = use_torque
        self.use_context = use_context
        self.frame = frame
        self.clip = clip
        self.pretrained = pretrained
        self.validation_fraction = validation_fraction
        self.n_iter_no_change = n_iter_no_change
        self.n_threads = n_threads
        self.random_state = random_state

    def set_params(self, **kwargs):
        check_renamed(type(self).__name__, kwargs, ValueError)
        return super().set_params(**kwargs)

    # ------------------------------------------------------------------ skorch hooks
    def get_default_callbacks(self):
        callbacks = list(super().get_default_callbacks())
        if self.lr_schedule == "cosine":
            callbacks.append(
                (
                    "lr_scheduler",
                    LRScheduler(
                        policy=torch.optim.lr_scheduler.CosineAnnealingLR,
                        # validated in fit; a bad value must not break set_params
                        T_max=self.max_epochs
                        if isinstance(self.max_epochs, Integral) and self.max_epochs > 0
                        else 1,
                    ),
                )
            )
        if self.validation_fraction is not None:
            callbacks.append(
                (
                    "early_stopping",
                    EarlyStopping(
                        monitor="valid_loss",
                        patience=self.n_iter_no_change,
                        load_best=True,
                        sink=print if self.verbose else _silent,
                    ),
                )
            )
        if self.verbose:
            callbacks.append(("progress_bar", ProgressBar()))
        return callbacks

    def initialize_module(self):
        kwargs = self.get_params_for("module")
        kwargs.update(
            n_features=len(step_feature_names(self.use_torque, self._n_motors())),
            n_sweep_features=len(sweep_feature_names(self.use_torque, self._n_motors())),
            use_context=self.use_context,
        )
        self.module_ = self.initialized_instance(self.module, kwargs)
        return self

    def get_split_datasets(self, X, y=None, **fit_params):
        if self.validation_fraction is None:
            return super().get_split_datasets(X, y, **fit_params)
        dataset = self.get_dataset(X, y)
        return _SettingHoldout(self.validation_fraction, self._split_seed_)(dataset)

    def get_dataset(self, X, y=None):
        if not is_dataset(X) and not (isinstance(X, dict) and "features" in X):
            raise TypeError(_not_prepared(self, X))
        return super().get_dataset(X, y)

    def infer(self, x, **fit_params):
        x = to_tensor(x, device=self.device)
        if not isinstance(x, dict) or "features" not in x:
            raise TypeError(_not_prepared(self, x))
        return self.module_(x["features"], x.get("sweep"), x.get("sweep_length"))

    @property
    def predict_proba(self):
        """Not offered: a residual learner is a regressor (raises ``AttributeError``)."""
        raise AttributeError(
            f"{type(self).__name__} has no predict_proba: it is a regressor of tip positions. "
            "Use predict (tip positions, mm) or predict_residual (residual, mm)."
        )

    def get_loss(self, y_pred, y_true, X=None, training=False):
        y_true = to_tensor(y_true, device=self.device)
        mask = to_tensor(X["mask"], device=self.device)
        return self.criterion_(y_pred, y_true, mask)

    # ------------------------------------------------------------------ validation
    def _validate_params(self):
        """Check the parameters: what :func:`sklearn.base._fit_context` runs before ``fit``.

        skorch's check of the argument names, which needs the initialised
        components (skorch runs it in ``initialize`` and in ``set_params`` of
        an initialised net), then the constraints of the learner's own
        parameters and of their combinations. The latter are not checked again
        inside a ``fit`` that has validated them already, nor where
        scikit-learn's ``skip_parameter_validation`` is set.
        """
        if hasattr(self, "module_"):
            super()._validate_params()
        if get_config()["skip_parameter_validation"]:
            return
        params = {key: getattr(self, key) for key in self._parameter_constraints}
        validate_parameter_constraints(
            self._parameter_constraints, params, caller_name=type(self).__name__
        )
        if self.window_s is not None and self.burn_in_s >= self.window_s:
            raise ValueError(
                f"burn_in_s must be shorter than window_s; got burn_in_s={self.burn_in_s} s, "
                f"window_s={self.window_s} s."
            )
        if self.window_step_s is not None and (
            self.window_s is None or self.window_step_s > self.window_s
        ):
            raise ValueError(
                "window_step_s must be at most window_s so that the windows cover every "
                f"motion step; got window_step_s={self.window_step_s}, window_s={self.window_s}."
            )

    def _check_X(self, X, y=None):
        X, y = check_recordings(X, y, require_sweep=False)
        check_backbone_columns(X, type(self).__name__)
        self._check_torques(*motor_columns(X))
        reading = [f"{key}={getattr(self, key)!r}" for key, value in _SWEEP_READERS.items()
                   if getattr(self, key) == value]
        if reading:
            check_sweeps(
                X,
                f"{type(self).__name__}({', '.join(reading)})",
                "For recordings without a sweep phase (every row 'motion'), pass "
                "frame='base' and use_context=False.",
            )
        return X, y

    def _n_motors(self):
        """Motors of the network's input: ``n_motors_`` (two before any fit)."""
        return getattr(self, "n_motors_", 2)

    def _check_torques(self, motors, torques):
        """Raise if ``use_torque`` is True and the recordings have no torque column.

        ``motors`` and ``torques`` are the channel columns of the recordings
        (:func:`skcath.motor_columns`).
        """
        if self.use_torque and not torques:
            expected = list(fmt.torque_names(len(motors)))
            raise ValueError(
                f"{type(self).__name__} has use_torque=True and reads the drive torques "
                f"{expected} of the {len(motors)} motor(s), but the recordings have no "
                "torque column. Pass use_torque=False for a rig without torque sensing, "
                "or add the torques."
            )

    def _check_motor_count(self, motors):
        """Raise unless the recordings' motor columns ``motors`` are those of the fitted network (``n_motors_``)."""
        if len(motors) != self._n_motors():
            raise ValueError(
                f"This {type(self).__name__} was fitted on recordings of {self._n_motors()} "
                f"motor(s) (q1 .. q{self._n_motors()}); X has {len(motors)} "
                f"({', '.join(motors)}). Its network takes the features of "
                f"{self._n_motors()} motor(s) only; fit it on recordings of this instrument."
            )

    def _check_training_data(self, X, y, sample_weight, method):
        """The checked recordings, targets and sample weights of ``fit`` or ``partial_fit``."""
        if y is None:
            raise ValueError(
                f"{type(self).__name__} requires y to be passed, but the target y is "
                f"None: {method} needs the tip positions y."
            )
        X, y = self._check_X(X, y)
        if sample_weight is not None:
            sample_weight = _check_sample_weight(
                sample_weight, X, dtype=np.float64, ensure_non_negative=True
            )
        return X, y, sample_weight

    def _pretrained_source(self):
        """The fitted residual whose weights and statistics start training, or None."""
        source = self.pretrained
        if source is None:
            return None
        if isinstance(source, FrozenEstimator):
            source = source.estimator
        if type(source) is not type(self):
            raise TypeError(
                f"pretrained must be a fitted {type(self).__name__} (optionally wrapped in "
                f"sklearn.frozen.FrozenEstimator), got {type(source).__name__}."
            )
        if not getattr(source, "initialized_", False) or not hasattr(source, "sigma_e_"):
            raise NotFittedError(
                f"pretrained is an unfitted {type(self).__name__}. Fit it first; inside "
                "cross_validate or GridSearchCV wrap it in sklearn.frozen.FrozenEstimator, "
                "because clone() drops the weights of a plain fitted estimator."
            )
        if source._n_motors() != self._n_motors():
            raise ValueError(
                f"pretrained was fitted on recordings of {source._n_motors()} motor(s) but "
                f"X has {self._n_motors()}; they must match."
            )
        keys = ["use_torque", "use_context", "frame"]
        if self.use_context:  # the encoder learned sweeps shortened this way
            keys += ["sweep_stride_s", "sweep_pooling"]
        for key in keys:
            theirs = _sweep_pooling(source) if key == "sweep_pooling" else getattr(source, key)
            if theirs != getattr(self, key):
                raise ValueError(
                    f"pretrained was fitted with {key}={theirs!r} but this "
                    f"estimator has {key}={getattr(self, key)!r}; they must match."
                )
        return source

    # ------------------------------------------------------------------ data
    def _row_rotations(self, F, codes, runs):
        """Rotation ``R_SB`` of every row's run (``frame="sweep"``), or None (``"base"``)."""
        if self.frame == "base":
            return None
        is_sweep = (F[fmt.PHASE] == fmt.SWEEP).to_numpy()
        q = F[list(fmt.motor_names(self._n_motors()))].to_numpy()
        b = F[list(BACKBONE_COLUMNS)].to_numpy()
        order, bounds = group_positions(codes[is_sweep], len(runs))
        sweep_rows = np.flatnonzero(is_sweep)[order]
        rotations = np.empty((len(runs), 3, 3))
        for k in range(len(runs)):  # _check_X ensures every run has a sweep (frame="sweep")
            rows = sweep_rows[bounds[k] : bounds[k + 1]]
            rotations[k] = sweep_frame(q[rows], b[rows], run=runs[k], n_motors=q.shape[1])
        return rotations[codes]

    def _sequences(self, X, y=None, dtype=np.float32):
        """Padded motion features, sweep features, and residual targets.

        With ``frame="sweep"`` the nominal tip ``b`` among the features and
        the residual ``e`` are expressed in each run's sweep frame. Returns the
        feature frame, the padded motion and sweep sequences, the residual of
        every row (None without ``y``) and the per-row rotations (or None).
        ``dtype`` is the precision of the padded sequences.
        """
        F, codes, runs = feature_frame(X)
        x_names = step_feature_names(self.use_torque, self._n_motors())
        s_names = sweep_feature_names(self.use_torque, self._n_motors())
        b = F[list(BACKBONE_COLUMNS)].to_numpy()
        rotations = self._row_rotations(F, codes, runs)
        if rotations is not None:
            F[list(BACKBONE_COLUMNS)] = np.einsum("nij,nj->ni", rotations, b)
        e = None
        if y is not None:
            e = y - b
            if rotations is not None:
                e = np.einsum("nij,nj->ni", rotations, e)
        motion = to_padded(F, x_names, y=e, phase=fmt.MOTION, dtype=dtype)
        sweep = to_padded(F, s_names, phase=fmt.SWEEP, dtype=dtype)
        return F, motion, sweep, e, rotations

    def _fit_statistics(self, F, e, sample_weight=None):
        """Normalisation statistics and ``sigma_e_``, weighted by ``sample_weight`` if given."""
        x_names = list(step_feature_names(self.use_torque, self._n_motors()))
        s_names = list(sweep_feature_names(self.use_torque, self._n_motors()))
        is_motion = (F[fmt.PHASE] == fmt.MOTION).to_numpy()
        is_sweep = (F[fmt.PHASE] == fmt.SWEEP).to_numpy()
        w = np.ones(len(F)) if sample_weight is None else sample_weight
        e = e[is_motion]
        finite = np.isfinite(e).all(axis=1) & (w[is_motion] > 0)
        if not finite.any():
            raise ValueError(
                "y has no finite tip position on a motion row"
                + ("" if sample_weight is None else " of positive sample_weight")
                + ": the residual learner needs measured tip positions during motion to "
                "learn from."
            )
        weights = {}
        if sample_weight is not None:
            weights = {"motion": w[is_motion], "sweep": w[is_sweep], "e": w[is_motion][finite]}
        self.x_scaler_ = Standardizer.fit(
            F.loc[is_motion, x_names].to_numpy(), weights.get("motion")
        )
        # without sweep rows (a rig without a sweep phase, use_context=False) there is
        # no sweep statistic, and no context needs one
        self.s_scaler_ = (
            Standardizer.fit(F.loc[is_sweep, s_names].to_numpy(), weights.get("sweep"))
            if is_sweep.any() else None
        )
        _, sigma = weighted_mean_std(e[finite], weights.get("e"))
        self.sigma_e_ = np.maximum(sigma, max(1e-6, 1e-6 * float(sigma.max())))

    def _context_input(self, sweep, dtype=np.float32):
        """Normalised sweep pooled over blocks of ``sweep_stride_``, and its valid lengths."""
        return context_input(self, sweep.values, sweep.lengths, dtype)

    def _training_windows(self, X, motion, sweep, sample_weight=None):
        """Inputs and targets of the training windows, one item per window.

        With ``sample_weight``, the loss mask of every step is multiplied by
        the weight of its row, and windows whose rows all have weight 0 are
        left out: they would contribute no gradient.
        """
        features = self.x_scaler_.transform(motion.values).astype(np.float32)
        features[~motion.mask] = 0.0
        target = (motion.target / self.sigma_e_).astype(np.float32)
        run_index, start = cut_windows(motion.lengths, self.window_, self.window_step_)
        if run_index.size == 0:
            raise ValueError("No run of X has motion rows to train on.")
        width = motion.max_length if self.window_ is None else self.window_
        steps = start[:, None] + np.arange(width)[None, :]
        inside = steps < motion.lengths[run_index][:, None]
        steps = np.minimum(steps, motion.max_length - 1)
        rows = run_index[:, None]
        window_features = np.where(inside[..., None], features[rows, steps], 0.0)
        window_target = np.where(inside[..., None], target[rows, steps], 0.0)
        loss_mask = inside & motion.target_mask[rows, steps]
        # Windows that start inside a run begin from a zero hidden state that
        # the run never had: their first burn_in steps only warm the state up.
        warm = (start > 0)[:, None] & (np.arange(width)[None, :] < self.burn_in_)
        loss_mask = (loss_mask & ~warm).astype(np.float32)
        keep = slice(None)
        if sample_weight is not None:
            row = np.where(motion.mask, motion.positions, 0)
            step_weight = np.where(motion.mask, sample_weight[row], 0.0)
            window_weight = np.where(inside, step_weight[rows, steps], 0.0)
            loss_mask *= window_weight.astype(np.float32)
            keep = np.flatnonzero((window_weight > 0).any(axis=1))
            if keep.size == 0:
                raise ValueError("No motion row of X has a positive sample_weight to train on.")
        group = _setting_codes(X, motion.runs)[run_index]
        data = {
            "features": window_features.astype(np.float32)[keep],
            "mask": loss_mask[keep],
            "group": group.astype(np.int64)[keep],
        }
        if self.use_context:
            sweep_values, sweep_lengths = self._context_input(sweep)
            data["sweep"] = sweep_values[run_index][keep]
            data["sweep_length"] = sweep_lengths[run_index][keep]
        return data, window_target.astype(np.float32)[keep]

    # ------------------------------------------------------------------ training
    def _start_training(self):
        """Initialise the network and the statistics: from ``pretrained``, or afresh.

        A fresh start draws its weights from ``random_state``; the statistics
        are then computed from the first training data.
        """
        with _torch_runtime(self.n_threads, self._seed()):
            self.initialize()
            source = self._pretrained_source()
            if source is not None:
                check_same_network(self, source)
                self.module_.load_state_dict(copy.deepcopy(source.module_.state_dict()))
                self.x_scaler_, self.s_scaler_ = source.x_scaler_, source.s_scaler_
                self.sigma_e_ = source.sigma_e_.copy()
                self.rate_hz_ = getattr(source, "rate_hz_", None)
            else:
                for name in ("x_scaler_", "s_scaler_", "sigma_e_", "rate_hz_"):
                    self.__dict__.pop(name, None)

    def _record_rate(self, X):
        """Set ``rate_hz_`` from the training runs, or check them against it.

        The rate is set by the first training data (or taken from
        ``pretrained``); later training data must be at that rate within
        ``skcath._rate.RATE_TOLERANCE`` (10 %).
        """
        name = type(self).__name__
        rate = training_rate(X, name)
        known = getattr(self, "rate_hz_", None)
        if known is None:
            self.rate_hz_ = rate
        elif rate is not None and abs(rate / known - 1.0) > RATE_TOLERANCE:
            raise ValueError(
                f"This {name} counts time in samples at {known:.4g} Hz, the rate it was first "
                f"fitted (or pretrained) at, but these training runs are at {rate:.4g} Hz. "
                f"Pass rate_hz={known:.4g} to train on them resampled to that rate, or fit a "
                "new model."
            )
        scales = time_scales(self, self.rate_hz_)  # in samples at the fitted rate
        self.window_, self.window_step_ = scales.window, scales.window_step
        self.burn_in_, self.sweep_stride_ = scales.burn_in, scales.sweep_stride

    def _partial_fit(self, X, y, sample_weight=None, **fit_params):
        """Train the initialised network for ``max_epochs`` on checked recordings."""
        given = X  # its columns are those predict checks
        X, y, sample_weight = at_model_rate(X, y, sample_weight, self.rate_hz, type(self).__name__)
        self._record_rate(X)
        F, motion, sweep, e, _ = self._sequences(X, y)
        if not hasattr(self, "sigma_e_"):
            self._fit_statistics(F, e, sample_weight)
        data, target = self._training_windows(X, motion, sweep, sample_weight)
        self._record_columns(given)
        seed = self._seed()
        self._split_seed_ = None if seed is None else seed + 1
        if seed is not None:
            seed += len(self.history_ or [])
        with _torch_runtime(self.n_threads, seed):
            super().partial_fit(data, target, **fit_params)
        return self

    # ------------------------------------------------------------------ public API
    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y, sample_weight=None, **fit_params):
        """Learn the residual ``e = y - b`` on the motion rows.

        The network starts from ``pretrained`` or from a random initialisation,
        unless ``warm_start`` is True and it is initialised already.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format with the backbone columns ``b_x``,
            ``b_y``, ``b_z`` (the output of a backbone's ``transform``).
        y : array-like of shape (n_samples, 3)
            Measured tip positions (mm); only motion rows are used, NaN rows
            (tracker dropouts) are skipped.
        sample_weight : array-like of shape (n_samples,), default=None
            Non-negative weight of every row, matched to the rows of ``X`` by
            position. The weights of the motion rows multiply their terms in
            the masked loss (a weighted mean over the steps of each batch);
            the normalisation statistics and ``sigma_e_`` are weighted means
            (the sweep statistics with the weights of the sweep rows).
            Training windows whose rows all have weight 0 are left out, so a
            run of weight 0 gives no window and no gradient, and does not
            enter the statistics. None weighs every row equally. (``score``
            does not take weights: its metric weighs runs equally.)
        **fit_params : dict
            Passed to skorch's ``partial_fit``.

        Returns
        -------
        self : object
        """
        check_device(self.device, type(self).__name__)
        X, y, sample_weight = self._check_training_data(X, y, sample_weight, "fit")
        motors, _ = motor_columns(X)
        if not self.warm_start or not self.initialized_:
            self.n_motors_ = len(motors)
            self._start_training()
        self._check_motor_count(motors)
        return self._partial_fit(X, y, sample_weight, **fit_params)

    @_fit_context(prefer_skip_nested_validation=True)
    def partial_fit(self, X, y, classes=None, sample_weight=None, **fit_params):
        """Train for ``max_epochs`` more epochs without re-initialising the network.

        The first call starts the network as :meth:`fit` does and validates
        the parameters; later calls check only the data, as scikit-learn's
        ``partial_fit`` methods do. Normalisation statistics are computed on
        the first call (or taken from ``pretrained``) and kept afterwards.
        Parameters as in :meth:`fit` (``sample_weight`` weighs the statistics
        on the first call only, and the loss on every call).
        """
        check_device(self.device, type(self).__name__)
        X, y, sample_weight = self._check_training_data(X, y, sample_weight, "partial_fit")
        motors, _ = motor_columns(X)
        if not self.initialized_:
            self.n_motors_ = len(motors)
            self._start_training()
        self._check_motor_count(motors)
        return self._partial_fit(X, y, sample_weight, **fit_params)

    def _seed(self):
        if self.random_state is None:
            return None
        if isinstance(self.random_state, Integral):
            return int(self.random_state)
        return int(check_random_state(self.random_state).randint(2**31 - 1))

    def _module_dtype(self):
        """Numpy dtype of the network's parameters (float32 unless converted)."""
        param = next(self.module_.parameters(), None)
        if param is None:
            return np.dtype(np.float32)
        return torch.empty((), dtype=param.dtype).numpy().dtype

    def predict_residual(self, X):
        """Applied residual ``r`` (mm) of every row: clipped on motion rows, 0 on sweep rows.

        The network runs in the precision of its parameters: float32 as
        trained, or float64 after ``module_.double()`` (used to check the
        streaming estimator of :mod:`skcath.online` without float32
        rounding).

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format with the backbone columns; the
            network reads the motion rows and the run's sweep rows.

        Returns
        -------
        r : ndarray of shape (n_samples, 3)
            Residual (mm) in the base frame, each coordinate within ``clip``.

        Notes
        -----
        A run recorded at another rate than ``rate_hz_``, or unevenly, is
        brought to the model's rate first: the network runs on the run
        resampled onto its ticks at ``rate_hz_``, and the residual is
        interpolated back to the run's own times
        (``skcath._rate.to_model_rate``, ``docs/residuals.rst``,
        *Sample rates*).
        """
        if not self.initialized_ or not hasattr(self, "sigma_e_"):
            raise NotFittedError(
                f"This {type(self).__name__} instance is not fitted yet; call fit first."
            )
        check_device(self.device, type(self).__name__)
        X, _ = self._check_X(X)
        self._check_motor_count(motor_columns(X)[0])
        at_rate = to_model_rate(X, getattr(self, "rate_hz_", None), type(self).__name__)
        if at_rate is None:
            return self._residual(X)
        return at_rate.to_rows(self._residual(at_rate.X))

    def _residual(self, X):
        """:meth:`predict_residual` of checked recordings at the model's rate."""
        # the network's own precision: float32, or float64 after module_.double()
        dtype = self._module_dtype()
        F, motion, sweep, _, rotations = self._sequences(X, dtype=dtype)
        if motion.max_length == 0:  # no motion row: nothing to correct
            return np.zeros((len(X), 3))
        data = {"features": self.x_scaler_.transform(motion.values).astype(dtype)}
        data["features"][~motion.mask] = 0.0
        if self.use_context:
            data["sweep"], data["sweep_length"] = self._context_input(sweep, dtype)
        # fork_rng: iterating a DataLoader draws a seed from torch's global
        # generator, which prediction must leave alone
        with _torch_runtime(self.n_threads, None), torch.random.fork_rng(devices=[]):
            out = self.forward(Dataset(data, None)).numpy().astype(np.float64)
        r = from_padded(out * self.sigma_e_, motion)
        if rotations is not None:  # back from the sweep frame to the base frame
            r = np.einsum("nji,nj->ni", rotations, r)
        if self.clip is not None:
            r = np.clip(r, -self.clip, self.clip)
        return np.where(np.isnan(r), 0.0, r)

    def encode_context(self, X, dtype=None):
        """Sweep context ``z`` of every run of ``X``, as the network computes it in ``predict``.

        The sweep rows of each run are gathered (:func:`skcath.sequences.to_padded`,
        in float64), pooled over blocks of ``sweep_stride_`` samples and
        normalised as in ``predict``, then encoded by the network's encoder
        on the CPU (a CPU copy of the encoder when the network was trained on
        another ``device``).

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format; only the sweep rows are read (the
            backbone columns are not needed).
        dtype : {None, "float32", "float64"}, default=None
            Precision of the encoder: None for the network's own precision;
            a copy of the encoder runs in the other one.

        Returns
        -------
        z : ndarray of shape (n_runs, context_size)
            Context of every run (float64), runs in order of first appearance.
        """
        if not self.initialized_ or not hasattr(self, "sigma_e_"):
            raise NotFittedError(
                f"This {type(self).__name__} instance is not fitted yet; call fit first."
            )
        if not self.use_context:
            raise ValueError(
                f"This {type(self).__name__} has use_context=False: it encodes no sweep context."
            )
        X, _ = check_recordings(X)
        motors, torques = motor_columns(X)
        self._check_torques(motors, torques)
        self._check_motor_count(motors)
        at_rate = to_model_rate(X, getattr(self, "rate_hz_", None), type(self).__name__)
        if at_rate is not None:
            X = at_rate.X
        dtype = self._module_dtype() if dtype is None else np.dtype(dtype)
        names = sweep_feature_names(self.use_torque, self._n_motors())
        sweep = to_padded(X, names, phase=fmt.SWEEP, dtype=np.float64)
        return encode_sweeps(self, sweep.values, sweep.lengths, dtype)

    def predict(self, X):
        """Tip position ``b + r`` (mm): the backbone's nominal tip plus the residual.

        Motion rows get the learned, clipped residual; sweep rows, where the
        network does not run, get the nominal tip ``b``.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format with the nominal tip ``b`` in the
            backbone columns ``b_x``, ``b_y``, ``b_z``.

        Returns
        -------
        y_pred : ndarray of shape (n_samples, 3)
            Estimated tip positions (mm) in the base frame.
        """
        return self.predict_residual(X) + nominal_tip(X)


def _setting_codes(X, runs):
    """Code of the (catheter, setting) pair of every run, for group-aware validation."""
    cols = [c for c in (fmt.CATHETER, fmt.SETTING) if c in X.columns]
    first = X.groupby(fmt.RUN, observed=True, sort=False)[cols].first()
    keys = first.loc[list(runs)].astype(str).agg("/".join, axis=1)
    return pd.factorize(keys)[0]
