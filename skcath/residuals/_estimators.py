"""Residual learners on top of a backbone: skorch nets over runs of recordings.

The estimators are the last step of a :class:`~sklearn.pipeline.Pipeline`
whose previous step is a backbone: they receive the recordings with the
backbone's nominal tip ``b_x, b_y, b_z`` appended, learn the residual
``e = y - b`` on the motion rows, and predict ``b + r`` with the applied
residual ``r`` clipped per coordinate. Training is done by skorch
(:class:`skorch.NeuralNetRegressor`) on windows cut from the motion sequences
of every run; prediction runs every motion sequence from its start.
"""

from __future__ import annotations

import copy
from contextlib import contextmanager
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
from ._features import (
    Standardizer,
    cut_windows,
    feature_frame,
    pool_sweep,
    step_feature_names,
    sweep_feature_names,
    weighted_mean_std,
)
from ._modules import GRUResidualModule, MaskedNormalizedMSE, MLPResidualModule, on_cpu
from ._same_network import check_same_network
from ._time_scales import at_model_rate, check_renamed, fitted_sweep_stride, time_scales

__all__ = [
    "GRUResidual",
    "MLPResidual",
    "available_devices",
    "check_backbone_columns",
    "check_device",
    "nominal_tip",
]


def check_backbone_columns(X: pd.DataFrame, owner: str) -> None:
    """Raise a clear error unless ``X`` carries finite backbone columns ``b_x, b_y, b_z``."""
    missing = [c for c in BACKBONE_COLUMNS if c not in X.columns]
    if missing:
        raise ValueError(
            f"{owner} needs the backbone's nominal tip position in the columns "
            f"{list(BACKBONE_COLUMNS)}, but X has no column {missing}. Put a backbone "
            f"before it: Pipeline([('backbone', PDLBackbone()), ('residual', {owner}())])."
        )
    for c in BACKBONE_COLUMNS:
        values = pd.to_numeric(X[c], errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"Column {c!r} must hold finite nominal tip positions (mm); row {i} "
                f"(run {X[fmt.RUN].iloc[i]!r}) holds {X[c].iloc[i]!r}."
            )


def nominal_tip(X: pd.DataFrame) -> np.ndarray:
    """The backbone columns ``b_x, b_y, b_z`` of ``X`` as an (n_samples, 3) float array (mm)."""
    return np.column_stack(
        [pd.to_numeric(X[c]).to_numpy(dtype=np.float64) for c in BACKBONE_COLUMNS]
    )


@contextmanager
def _torch_runtime(n_threads, seed):
    """Torch intra-op threads and a private, seeded random stream for one call."""
    previous = torch.get_num_threads()
    if n_threads is not None:
        torch.set_num_threads(int(n_threads))
    try:
        if seed is None:
            yield
        else:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(seed))
                yield
    finally:
        torch.set_num_threads(previous)


def available_devices():
    """The torch devices this machine can compute on: ``"cpu"``, then each GPU."""
    devices = ["cpu"]
    if torch.cuda.is_available():
        devices += [f"cuda:{k}" for k in range(torch.cuda.device_count())]
    if torch.backends.mps.is_available():
        devices.append("mps")
    return devices


def check_device(device, owner):
    """Raise a clear error unless torch can compute on ``device`` (a learner's parameter).

    Checked before any work, so that a missing GPU is reported before the
    data are prepared rather than by torch's own error at the first tensor.
    ``None`` (skorch: leave the network where it is) is accepted.
    """
    if device is None:
        return
    try:
        where = torch.device(device)
        if where.type != "cpu":
            torch.empty(0, device=where)
    except Exception as exc:  # torch raises RuntimeError, AssertionError, NotImplementedError
        raise ValueError(
            f"{owner} has device={device!r}, but torch cannot compute there on this "
            f"machine; the devices available are {available_devices()}. Pass "
            "device='cpu', or install a torch build for the GPU (docs/install.rst)."
        ) from exc


def _silent(*args, **kwargs):
    """Sink of the early-stopping message when ``verbose=0``."""


class _SettingHoldout:
    """Validation split that holds out whole shaft settings (all their repeats).

    Called by the net with the window dataset; ``X["group"]`` holds the code of
    the (catheter, setting) pair of every window.
    """

    def __init__(self, fraction, seed):
        self.fraction = fraction
        self.seed = seed

    def __call__(self, dataset, y=None, **kwargs):
        group = np.asarray(dataset.X["group"])
        unique = np.unique(group)
        if unique.size < 2:
            raise ValueError(
                "validation_fraction needs at least two shaft settings in the training "
                f"data to hold one out, got {unique.size}."
            )
        n_valid = min(max(1, round(self.fraction * unique.size)), unique.size - 1)
        rng = np.random.default_rng(self.seed)
        held = rng.choice(unique, size=n_valid, replace=False)
        is_valid = np.isin(group, held)
        train = torch.utils.data.Subset(dataset, np.flatnonzero(~is_valid).tolist())
        valid = torch.utils.data.Subset(dataset, np.flatnonzero(is_valid).tolist())
        return train, valid


def _not_prepared(learner, data):
    """Message for data given to the network that were not prepared from recordings."""
    name = type(learner).__name__
    return (
        f"{name} takes recordings in the long format (a DataFrame) in fit, predict and "
        f"predict_residual only; the network's methods (forward, forward_iter, infer) take "
        f"the input those prepare from recordings, not {type(data).__name__}. Use "
        f"{name}.predict for tip positions (mm) or predict_residual for the residual (mm)."
    )


#: The parameter values with which a residual learner reads each run's sweep:
#: the sweep frame is fitted on it, the context encoded from it.
_SWEEP_READERS = {"frame": "sweep", "use_context": True}


def _sweep_pooling(learner):
    """``sweep_pooling`` of a learner; those pickled before the parameter existed subsampled."""
    return getattr(learner, "sweep_pooling", "subsample")


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
        self._check_torques(X)
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

    def _check_torques(self, X):
        """Raise if ``use_torque`` is True and the recordings have no torque column."""
        motors, torques = motor_columns(X)
        if self.use_torque and not torques:
            expected = list(fmt.torque_names(len(motors)))
            raise ValueError(
                f"{type(self).__name__} has use_torque=True and reads the drive torques "
                f"{expected} of the {len(motors)} motor(s), but the recordings have no "
                "torque column. Pass use_torque=False for a rig without torque sensing, "
                "or add the torques."
            )

    def _check_motor_count(self, X):
        """Raise unless ``X`` has the motors of the fitted network (``n_motors_``)."""
        motors, _ = motor_columns(X)
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
        pooling = _sweep_pooling(self)
        stride = fitted_sweep_stride(self)
        pooled, lengths = pool_sweep(sweep.values, sweep.lengths, stride, pooling)
        values = self.s_scaler_.transform(pooled).astype(dtype)
        valid = np.arange(values.shape[1])[None, :] < lengths[:, None]
        values[~valid] = 0.0
        return values, np.maximum(lengths, 1).astype(np.int64)

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
        if not self.warm_start or not self.initialized_:
            self.n_motors_ = len(motor_columns(X)[0])
            self._start_training()
        self._check_motor_count(X)
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
        if not self.initialized_:
            self.n_motors_ = len(motor_columns(X)[0])
            self._start_training()
        self._check_motor_count(X)
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
        self._check_motor_count(X)
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
        self._check_torques(X)
        self._check_motor_count(X)
        at_rate = to_model_rate(X, getattr(self, "rate_hz_", None), type(self).__name__)
        if at_rate is not None:
            X = at_rate.X
        dtype = self._module_dtype() if dtype is None else np.dtype(dtype)
        names = sweep_feature_names(self.use_torque, self._n_motors())
        sweep = to_padded(X, names, phase=fmt.SWEEP, dtype=np.float64)
        torch_dtype = torch.float64 if dtype == np.float64 else torch.float32
        encoder = on_cpu(self.module_.encoder, torch_dtype)
        values, lengths = self._context_input(sweep, dtype)
        with torch.no_grad():
            z = encoder(torch.from_numpy(values), torch.from_numpy(lengths))
        return z.detach().cpu().to(torch.float64).numpy()

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


_COMMON_PARAMS = """
    lr : float, default=1e-2
        Initial Adam learning rate (annealed, see ``lr_schedule``). The
        paper's two stages use 1e-3 (pretraining) and 5e-4 (fine-tuning).
    lr_schedule : {"cosine", "constant"}, default="cosine"
        Learning rate over the epochs of one ``fit`` call: cosine annealing
        from ``lr`` towards 0 at ``max_epochs``, or constant.
    max_epochs : int, default=40
        Passes over the training windows per call of ``fit``.
    batch_size : int, default=64
        Windows per optimisation step (and runs per batch in ``predict``).
    window_s : float or None, default=20.0
        Length of the training windows (s). Every time scale is given in
        seconds and turned by ``fit`` into the nearest whole number of
        samples at the rate of the training runs, ``round(seconds *
        rate_hz_)`` (20.0 s: 200 samples at 10 Hz, 800 at 40 Hz), kept in
        ``window_``, ``window_step_``, ``burn_in_``, ``sweep_stride_``;
        recordings at another rate are brought to ``rate_hz_`` in
        ``predict`` (``docs/residuals.rst``, *Sample rates*). Whole motion
        sequences are cut into overlapping windows so that a batch holds
        many of them (at least 2 samples each); None trains on whole
        sequences (one item per run).
    window_step_s : float or None, default=None
        Time between window starts (s); None: ``window_s - burn_in_s`` (in
        samples). At most ``window_s``.
    burn_in_s : float, default=5.0
        Leading time of a window that starts inside a run, excluded from the
        loss (s): it warms the hidden state up from zero. Windows that start
        at the beginning of a motion sequence count from step 0, as in
        prediction. Shorter than ``window_s`` in samples.
    sweep_stride_s : float, default=4.0
        Time of the sweep per step of the context encoder (s; 40 samples at
        10 Hz, at least 1): the sweep sequence is shortened by this factor
        before encoding.
    rate_hz : float or None, default=10.0
        Rate at which the network steps (Hz): by default one step of the
        motor-step features and of the recurrent state is 0.1 s, at any
        recording rate. Training runs at another rate (beyond 10 %) are resampled onto
        ticks at this rate before training, as ``predict`` resamples any run
        at another rate (``docs/residuals.rst``, *Sample rates*;
        ``docs/studies/rates.rst`` measures it). None: the network steps at
        the rate of the training runs, whatever it is.
    sweep_pooling : {"mean", "subsample"}, default="mean"
        How the samples of a block of ``sweep_stride_s`` become one encoder
        step: their mean, which averages out the measurement noise of the
        drive torques, or the first of them (the earlier behaviour, kept for
        comparison).
    use_torque : bool, default=True
        Include the drive torques in the step features and the sweep
        features. Recordings without torque columns need False; with True
        they are refused with an error that names the missing columns.
    use_context : bool, default=True
        Condition on the sweep context ``z``; without it ``v = x``. With
        True every run needs its sweep rows.
    frame : {"sweep", "base"}, default="sweep"
        Frame in which the nominal tip ``b`` (a step feature) and the
        residual are expressed inside the network. ``"sweep"``: each run's
        sweep frame (:func:`skcath.frames.sweep_frame`, fitted to the
        nominal tip on the run's sweep rows), so that what the network
        learns does not depend on how the base sensor is mounted on a
        catheter; the predicted residual is rotated back to the base frame
        before it is clipped and added; every run needs its sweep rows.
        ``"base"``: the base frame B throughout, as in the paper. With
        ``use_context=False`` and ``frame="base"`` the learner reads no
        sweep and takes runs without one, all rows ``"motion"``
        (``docs/residuals.rst``, *Recordings without a sweep*).
    clip : float or None, default=25.0
        Bound of the applied residual per coordinate (mm); None disables.
    pretrained : fitted estimator of the same class, FrozenEstimator, or None
        Start from its weights and normalisation statistics instead of a
        random initialisation (fine-tuning). Use
        ``sklearn.frozen.FrozenEstimator(fitted)`` inside ``cross_validate``
        or ``GridSearchCV``, whose ``clone`` drops the weights of a plain
        fitted estimator. Its network must have the same size (the same
        ``module__*`` arguments); one that differs is named in the error.
    validation_fraction : float or None, default=None
        Fraction of the training shaft settings (all repeats of a setting
        together) held out as validation data for early stopping; the best
        weights are restored at the end. None trains on all data for
        ``max_epochs``.
    n_iter_no_change : int, default=5
        Early-stopping patience (epochs) when ``validation_fraction`` is set.
    n_threads : int or None, default=None
        Torch intra-op threads during ``fit`` and ``predict`` (restored
        afterwards); None keeps torch's setting. Use 1 when folds run in
        parallel.
    random_state : int, RandomState instance or None, default=None
        Seeds weight initialisation, batch order and the validation split;
        with an int, repeated fits on the CPU give identical predictions.
    verbose : int, default=0
        0 is silent; 1 prints skorch's epoch table and a progress bar.
    **kwargs
        Any other :class:`skorch.NeuralNetRegressor` parameter, e.g.
        ``module__hidden_size``, ``callbacks``, ``warm_start`` or ``device``
        (``"cpu"``, ``"cuda"``: where the network trains and predicts,
        checked by ``fit`` and ``predict`` before any work). ``optimizer__weight_decay`` (L2 penalty of Adam)
        defaults to 1e-4 and ``iterator_train__shuffle`` to True."""

_COMMON_ATTRIBUTES = """
    module_ : torch.nn.Module
        The trained network (returns the normalised residual ``F``).
    x_scaler_, s_scaler_ : Standardizer
        Means and standard deviations of the step features (training motion
        rows) and of the sweep features (training sweep rows); ``s_scaler_``
        is None when no training run has sweep rows.
    sigma_e_ : ndarray of shape (3,)
        Standard deviation of the training residual ``e`` per coordinate (mm)
        of the frame the network works in (see ``frame``).
    rate_hz_ : float or None
        Sample rate of the training runs (Hz): one over the median time
        step of their rows. The runs must share it within 10 %
        (``skcath._rate.RATE_TOLERANCE``); ``predict`` resamples a run
        recorded at another rate, or unevenly, onto ticks at this rate and
        refuses one slower than a fifth of it. None when no training run
        has two rows (the time scales then count at 10 Hz).
    window_, window_step_, burn_in_, sweep_stride_ : int or None
        ``window_s``, ``window_step_s`` (or its default), ``burn_in_s`` and
        ``sweep_stride_s`` in samples at ``rate_hz_``; ``window_`` and
        ``window_step_`` are None with ``window_s=None``.
    history_ : skorch.History
        Per-epoch training (and validation) loss.
    n_motors_ : int
        Number of motors ``N`` of the training recordings (``q1 .. qN``):
        the network reads ``3N + 3`` step features (``2N + 3`` without
        torques); recordings of another number of motors are refused.
    feature_names_in_ : ndarray of str
    n_features_in_ : int"""


class GRUResidual(_ResidualNet):
    __doc__ = f"""Sweep-context GRU residual learner (the paper's estimator).

    For every run, the normalised sweep features ``s = [q, tau]``, averaged
    over blocks of ``sweep_stride_s`` seconds, are encoded once into a context
    ``z``. Along the motion sequence, the per-step features

    .. math::

        x_t = [q_t, \\Delta q_t, \\tau_t, b_t] \\in \\mathbb{{R}}^{{3N + 3}}

    (the angles of the ``N`` motors in degrees, their per-sample differences,
    the drive torques and the backbone's nominal tip in mm; ``2N + 3``
    features with ``use_torque=False``, 9 for the default two motors) are
    normalised with training means and
    standard deviations and, with ``z``, drive a GRU whose hidden state starts
    from zero at the first motion sample:

    .. math::

        h_t = \\mathrm{{GRU}}([\\bar x_t; z], h_{{t-1}}), \\quad
        \\hat e_t = \\sigma_e \\odot H(h_t), \\quad
        \\hat p_t = b_t + \\mathrm{{clip}}(\\hat e_t, \\pm 25\\,\\mathrm{{mm}}).

    Training minimises the masked normalised residual loss
    ``sum m ||F - e / sigma_e||^2 / (3 sum m)`` with Adam on windows cut from
    the motion sequences (:class:`MaskedNormalizedMSE`); padding, tracker
    dropouts and burn-in steps are masked.

    Parameters
    ----------
    module : torch.nn.Module class, default=GRUResidualModule
        The network; its parameters are set with ``module__*`` (e.g.
        ``module__hidden_size=64``, ``module__context_size=16``,
        ``module__num_layers``, ``module__encoder_hidden_size``,
        ``module__head_hidden_size``). The input sizes and ``use_context``
        are set by the estimator.{_COMMON_PARAMS}

    Attributes
    ----------{_COMMON_ATTRIBUTES}

    See Also
    --------
    MLPResidual : the same inputs without recurrence.
    NoResidual : the backbone alone, for baselines in the same grid.

    Notes
    -----
    Two-stage training as in the paper: pretrain with ``lr=1e-3`` on data
    that excludes the test runs, then fine-tune with
    ``GRUResidual(lr=5e-4, pretrained=FrozenEstimator(pretrained_model))``.
    Fine-tuning keeps the pretrained normalisation statistics.

    Examples
    --------
    >>> from sklearn.pipeline import Pipeline
    >>> from skcath.backbones import PDLBackbone
    >>> from skcath.residuals import GRUResidual
    >>> pipe = Pipeline([("backbone", PDLBackbone()),
    ...                  ("residual", GRUResidual(random_state=0))])
    >>> pipe.fit(X_train, y_train).predict(X_test)  # doctest: +SKIP
    """

    def __init__(self, module=GRUResidualModule, **kwargs):
        super().__init__(module, **kwargs)


class MLPResidual(_ResidualNet):
    __doc__ = f"""Per-step MLP residual learner (the paper's ablation of the GRU).

    The same inputs as :class:`GRUResidual` (step features ``[q, dq, tau, b]``
    and the sweep context ``z``), mapped step by step by an MLP without
    recurrence: ``e_t = sigma_e * MLP([x_t; z])``. Training and prediction
    are as for :class:`GRUResidual`; ``window_s`` only groups steps into
    batches (``burn_in_s`` defaults to 0: no hidden state to warm up).

    Parameters
    ----------
    module : torch.nn.Module class, default=MLPResidualModule
        The network; ``module__hidden_size``, ``module__num_layers``,
        ``module__context_size``, ``module__encoder_hidden_size``.{_COMMON_PARAMS}

    Attributes
    ----------{_COMMON_ATTRIBUTES}

    See Also
    --------
    GRUResidual : the recurrent learner.
    """

    def __init__(self, module=MLPResidualModule, **kwargs):
        kwargs.setdefault("burn_in_s", 0.0)
        super().__init__(module, **kwargs)
