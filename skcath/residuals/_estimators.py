"""Residual learners on top of a backbone: skorch nets over runs of recordings.

The estimators are the last step of a :class:`~sklearn.pipeline.Pipeline`
whose previous step is a backbone: they receive the recordings with the
backbone's nominal tip ``b_x, b_y, b_z`` appended, learn the residual
``e = y - b`` on the motion rows, and predict ``b + r`` with the applied
residual ``r`` clipped per coordinate. Training is done by skorch
(:class:`skorch.NeuralNetRegressor`) on windows cut from the motion sequences
of every run; prediction runs every motion sequence from its start.

This module holds the two learners and their documentation; what they share
(checks, sequences, statistics, windows, training and prediction) is the
net of :mod:`skcath.residuals._net`, and the sweep context is encoded by
:mod:`skcath.residuals._context`.
"""

from __future__ import annotations

from ._backbone_columns import check_backbone_columns, nominal_tip
from ._modules import GRUResidualModule, MLPResidualModule
from ._net import _ResidualNet
from ._runtime import available_devices, check_device

__all__ = [
    "GRUResidual",
    "MLPResidual",
    "available_devices",
    "check_backbone_columns",
    "check_device",
    "nominal_tip",
]
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
