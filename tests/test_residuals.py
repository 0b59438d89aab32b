"""Tests of the residual learners GRUResidual, MLPResidual and NoResidual.

The learners are the last step of a pipeline whose backbone appends the
nominal tip ``b_x, b_y, b_z``; they learn ``e = y - b`` on the motion rows and
predict ``b + clip(r)``. These tests check the feature helpers and the torch
modules on their own, then the behaviour a user relies on: sweep rows keep
``b``, the applied residual is bounded, motion references and other runs are
never read, prediction is causal, seeding is reproducible and leaves torch's
global state alone, fine-tuning from a pretrained model, warm starts,
validation that holds out whole shaft settings, clear errors, and the
scikit-learn tools (Pipeline, clone, pickling, cross_validate, GridSearchCV).

The networks are tiny and train for one or two epochs on shortened runs, so
nothing here depends on a trained model's accuracy, except
``test_gru_beats_its_backbone_on_held_out_settings``.
"""

import copy
import io
import pickle

import joblib
import numpy as np
import pandas as pd
import pytest
import torch
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation
from sklearn.base import clone
from sklearn.dummy import DummyRegressor
from sklearn.exceptions import NotFittedError
from sklearn.frozen import FrozenEstimator
from sklearn.model_selection import GridSearchCV, GroupKFold, cross_validate
from sklearn.pipeline import Pipeline
from skorch.callbacks import Callback

from skcath.backbones import BACKBONE_COLUMNS, PCCBackbone, PDLBackbone, PolynomialBackbone
from skcath.datasets import make_benchmark
from skcath.metrics import mean_per_run_rmse, per_run_rmse, run_rmse_scorer
from skcath.residuals import (
    GRUResidual,
    GRUResidualModule,
    MaskedNormalizedMSE,
    MLPResidual,
    MLPResidualModule,
    NoResidual,
    Standardizer,
    SweepEncoder,
    step_feature_names,
    sweep_feature_names,
)
from skcath.residuals import _estimators, _net
from skcath.residuals._features import cut_windows, feature_frame, pool_sweep
from skcath.residuals._modules import on_cpu

from _helpers import instrument, tiny_residual

LEARNERS = [GRUResidual, MLPResidual]
B = list(BACKBONE_COLUMNS)
REF = ["ref_x", "ref_y", "ref_z"]
# Three shaft settings (one low, two high bends) and the motion rows kept of each run.
SMALL_SETTINGS = ["S02", "S09", "S13"]
N_MOTION = 300


# ---------------------------------------------------------------------------
# data and estimators
# ---------------------------------------------------------------------------
def _runs(X):
    """Run ids in order of first appearance."""
    return list(dict.fromkeys(X["run"].astype(str).tolist()))


def _motion(X):
    return (X["phase"] == "motion").to_numpy()


def _shorten(X, settings, n_motion):
    """Boolean rows: the runs of ``settings``, sweep and first ``n_motion`` motion rows."""
    motion = _motion(X)
    rank = pd.Series(motion, index=X.index).groupby(X["run"], observed=True).cumsum()
    keep = X["setting"].isin(settings).to_numpy() & (~motion | (rank.to_numpy() <= n_motion))
    return keep


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    home = tmp_path_factory.mktemp("skcath_data")
    return make_benchmark(n_catheters=1, n_runs=1, cache=True, data_home=home)


@pytest.fixture(scope="module")
def transformed(bench):
    """The PDL backbone's output for all 17 runs (computed once)."""
    return PDLBackbone().fit(bench.X).transform(bench.X)


@pytest.fixture(scope="module")
def small(bench, transformed):
    """(X, Xb, y): three shortened runs, raw and with the backbone columns."""
    keep = _shorten(bench.X, SMALL_SETTINGS, N_MOTION)
    return bench.X[keep], transformed[keep], bench.y[keep]


@pytest.fixture(scope="module")
def fitted(small):
    """Lazily fitted tiny learners on ``small`` and their (read-only) predictions."""
    _, Xb, y = small
    cache = {}

    def get(Est):
        if Est not in cache:
            est = tiny_residual(Est).fit(Xb, y)
            pred = est.predict(Xb)
            pred.flags.writeable = False
            cache[Est] = (est, pred)
        return cache[Est]

    return get


def _with_repeat(Xb, y, setting):
    """``Xb`` plus a second repeat of the run of ``setting`` (slightly different motion)."""
    rows = (Xb["setting"] == setting).to_numpy()
    extra = Xb[rows].copy()
    extra["run"] = extra["run"].astype(str).str.replace("-R1", "-R2")
    extra.loc[_motion(extra), "q1"] += 0.5
    out = pd.concat([Xb.astype({"run": str}), extra], ignore_index=True)
    return out, np.vstack([y, y[rows]])


# ---------------------------------------------------------------------------
# features
# ---------------------------------------------------------------------------


def test_pool_sweep_averages_blocks_of_each_run():
    rng = np.random.default_rng(0)
    values = rng.normal(size=(2, 10, 3))
    lengths = np.array([10, 7])
    values[1, 7:] = 99.0  # padding must not leak into the last block
    pooled, n_steps = pool_sweep(values, lengths, 4)
    assert_array_equal(n_steps, [3, 2])
    assert pooled.shape == (2, 3, 3)
    assert_allclose(pooled[0, 0], values[0, 0:4].mean(axis=0))
    assert_allclose(pooled[0, 2], values[0, 8:10].mean(axis=0))  # a partial block
    assert_allclose(pooled[1, 1], values[1, 4:7].mean(axis=0))
    assert_array_equal(pooled[1, 2], 0.0)  # after the run's last block
    sub, n_sub = pool_sweep(values, lengths, 4, "subsample")
    assert_array_equal(n_sub, n_steps)
    assert_array_equal(sub[0], values[0, ::4])
    assert_array_equal(sub[1, :2], values[1, [0, 4]])
    assert_array_equal(sub[1, 2], 0.0)
    assert_array_equal(values[1, 7:], 99.0)  # input untouched
    same, n_same = pool_sweep(values, lengths, 1)
    assert_array_equal(n_same, lengths)
    assert_allclose(same[0], values[0])


def test_pool_sweep_mean_averages_out_noise():
    rng = np.random.default_rng(1)
    slow = np.linspace(0.0, 50.0, 4000)[None, :, None]
    noisy = slow + rng.normal(scale=3.0, size=slow.shape)
    lengths = np.array([4000])
    mean, _ = pool_sweep(noisy, lengths, 40)
    sub, _ = pool_sweep(noisy, lengths, 40, "subsample")
    truth, _ = pool_sweep(slow, lengths, 40)
    err_mean = np.std(mean - truth)
    err_sub = np.std(sub - pool_sweep(slow, lengths, 40, "subsample")[0])
    assert err_mean < 0.25 * err_sub  # noise sd shrinks by about sqrt(40)


def test_pool_sweep_rejects_unknown_pooling():
    with pytest.raises(ValueError, match="pooling"):
        pool_sweep(np.zeros((1, 4, 2)), np.array([4]), 2, "median")


def test_sweep_pooling_changes_the_context(small):
    _, Xb, y = small
    mean = tiny_residual(GRUResidual, max_epochs=1).fit(Xb, y)
    sub = tiny_residual(GRUResidual, max_epochs=1, sweep_pooling="subsample").fit(Xb, y)
    assert not np.allclose(mean.predict(Xb), sub.predict(Xb))
    # a learner pickled before the parameter existed keeps subsampling
    old = pickle.loads(pickle.dumps(sub))
    del old.sweep_pooling
    assert_allclose(old.predict(Xb), sub.predict(Xb))

def test_feature_names():
    assert step_feature_names() == (
        "q1", "q2", "dq1", "dq2", "tau1", "tau2", "b_x", "b_y", "b_z"
    )  # fmt: skip
    assert step_feature_names(use_torque=False) == ("q1", "q2", "dq1", "dq2", "b_x", "b_y", "b_z")
    assert sweep_feature_names() == ("q1", "q2", "tau1", "tau2")
    assert sweep_feature_names(use_torque=False) == ("q1", "q2")


def test_first_motion_step_continues_from_the_sweep(small):
    _, Xb, _ = small
    F, codes, runs = feature_frame(Xb)
    assert len(runs) == len(SMALL_SETTINGS)
    motion = _motion(Xb)
    q = Xb[["q1", "q2"]].to_numpy()
    dq = F[["dq1", "dq2"]].to_numpy()
    for k in range(len(runs)):
        rows = np.flatnonzero(codes == k)
        first_motion = rows[motion[rows]][0]
        last_sweep = rows[~motion[rows]][-1]
        assert_array_equal(dq[rows[0]], [0.0, 0.0])
        assert_allclose(dq[first_motion], q[first_motion] - q[last_sweep], rtol=0, atol=1e-12)
        assert np.abs(dq[first_motion]).max() > 0
        # every later row is the step from the previous row of its run
        assert_allclose(dq[rows[1:]], np.diff(q[rows], axis=0), rtol=0, atol=1e-12)
    # the input frame is not modified
    assert "dq1" not in Xb.columns


def test_standardizer_ignores_nan_rows_and_constant_columns():
    values = np.array(
        [
            [1.0, 5.0, 2.0],
            [3.0, 5.0, 4.0],
            [np.nan, 5.0, 100.0],  # NaN and infinite rows are left out
            [5.0, 5.0, 6.0],
            [2.0, np.inf, 0.0],
        ]
    )
    s = Standardizer.fit(values)
    finite = values[[0, 1, 3]]
    assert_allclose(s.mean, finite.mean(axis=0))
    assert_allclose(s.scale[[0, 2]], finite.std(axis=0)[[0, 2]])
    assert s.scale[1] > 0  # constant column: no division by zero
    out = s.transform(finite)
    assert np.isfinite(out).all()
    assert_array_equal(out[:, 1], 0.0)
    assert_allclose(out.mean(axis=0), 0.0, atol=1e-12)
    assert_allclose(out[:, [0, 2]].std(axis=0), 1.0)
    # any leading shape; the dtype of the input is kept
    batch = np.stack([finite, finite]).astype(np.float32)
    out32 = s.transform(batch)
    assert out32.shape == batch.shape and out32.dtype == np.float32
    assert_allclose(out32[1], out, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="no finite row"):
        Standardizer.fit(np.full((3, 2), np.nan))


def _covered(lengths, run_index, start, window):
    covered = [np.zeros(n, dtype=bool) for n in lengths]
    for k, s in zip(run_index, start):
        covered[k][s : s + window] = True
    return covered


@pytest.mark.parametrize("window, step", [(4, 3), (4, None), (5, 1), (3, 3), (12, 5)])
def test_cut_windows_cover_every_step(window, step):
    lengths = np.array([10, 3, 0, 7, 4, 1])
    run_index, start = cut_windows(lengths, window, step)
    assert run_index.dtype.kind == "i" and start.dtype.kind == "i"
    assert 2 not in run_index  # a run without motion gives no window
    for k, n in enumerate(lengths):
        s = start[run_index == k]
        if n == 0:
            continue
        assert s[0] == 0
        assert np.all(np.diff(s) > 0)
        assert np.all(np.diff(s) <= (window if step is None else step))
        # the last window ends at the end of the run; a short run has one window
        assert s[-1] == max(n - window, 0)
        if n <= window:
            assert_array_equal(s, [0])
    assert all(c.all() for c in _covered(lengths, run_index, start, window))


def test_cut_windows_examples():
    run_index, start = cut_windows([10, 3], 4, 3)
    assert_array_equal(run_index, [0, 0, 0, 1])
    assert_array_equal(start, [0, 3, 6, 0])
    run_index, start = cut_windows([10], 4)
    assert_array_equal(start, [0, 4, 6])
    # None: one whole sequence per run with motion
    run_index, start = cut_windows([5, 0, 8], None)
    assert_array_equal(run_index, [0, 2])
    assert_array_equal(start, [0, 0])
    run_index, start = cut_windows([0, 0], 4)
    assert run_index.size == 0 and start.size == 0


# ---------------------------------------------------------------------------
# torch modules
# ---------------------------------------------------------------------------
def _seeded(factory, seed=0):
    """Build a module under a private seed (the global torch RNG is left alone)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return factory()


def _inputs(batch=2, T=30, L=12, n_features=9, n_sweep=4, seed=1):
    g = torch.Generator().manual_seed(seed)
    features = torch.randn(batch, T, n_features, generator=g)
    sweep = torch.randn(batch, L, n_sweep, generator=g)
    length = torch.tensor([5, L][:batch])
    return features, sweep, length


SMALL_MODULE = dict(hidden_size=8, context_size=4, encoder_hidden_size=8)
MODULES = [
    lambda **kw: GRUResidualModule(head_hidden_size=8, **{**SMALL_MODULE, **kw}),
    lambda **kw: MLPResidualModule(**{**SMALL_MODULE, **kw}),
]
MODULE_IDS = ["GRUResidualModule", "MLPResidualModule"]


@pytest.mark.parametrize("make", MODULES, ids=MODULE_IDS)
def test_module_output_shapes(make):
    features, sweep, length = _inputs()
    module = _seeded(make)
    assert module(features, sweep, length).shape == (2, 30, 3)
    small = _seeded(lambda: make(n_features=7, n_sweep_features=2))
    f7, s2, length = _inputs(n_features=7, n_sweep=2)
    assert small(f7, s2, length).shape == (2, 30, 3)
    encoder = _seeded(lambda: SweepEncoder(4, hidden_size=8, context_size=5))
    z = encoder(sweep, length)
    assert z.shape == (2, 5) and (z.abs() <= 1).all()


def test_masked_normalized_mse_matches_hand_computation():
    g = torch.Generator().manual_seed(0)
    prediction = torch.randn(2, 5, 3, generator=g)
    target = torch.randn(2, 5, 3, generator=g)
    mask = torch.tensor([[1, 1, 0, 1, 0], [0, 1, 1, 0, 0]], dtype=torch.float32)
    loss = MaskedNormalizedMSE()(prediction, target, mask)
    p, t, m = prediction.numpy(), target.numpy(), mask.numpy().astype(bool)
    expected = ((p[m] - t[m]) ** 2).sum() / (3 * m.sum())
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    # steps outside the mask do not count; a boolean mask works the same
    changed = prediction.clone()
    changed[~mask.bool()] += 100.0
    assert MaskedNormalizedMSE()(changed, target, mask.bool()).item() == pytest.approx(
        expected, rel=1e-6
    )
    # an empty mask gives 0, not NaN
    assert MaskedNormalizedMSE()(prediction, target, torch.zeros(2, 5)).item() == 0.0


@pytest.mark.parametrize("make", MODULES, ids=MODULE_IDS)
def test_module_is_causal_and_ignores_sweep_padding(make):
    module = _seeded(make)
    features, sweep, length = _inputs()
    with torch.no_grad():
        out = module(features, sweep, length)
        # steps after t do not change the output up to t
        t = 11
        later = features.clone()
        later[:, t + 1 :] += torch.randn_like(later[:, t + 1 :])
        out_later = module(later, sweep, length)
        assert_allclose(out_later[:, : t + 1].numpy(), out[:, : t + 1].numpy(), atol=1e-6)
        assert not torch.allclose(out_later[:, t + 1 :], out[:, t + 1 :])
        # padded sweep steps (beyond sweep_length) do not change the context
        padded = sweep.clone()
        padded[0, length[0] :] = 7.0
        assert_allclose(module(features, padded, length).numpy(), out.numpy(), atol=1e-6)
        # a valid sweep step does
        valid = sweep.clone()
        valid[0, length[0] - 1] += 1.0
        changed = module(features, valid, length)
        assert not torch.allclose(changed[0], out[0])
        assert_allclose(changed[1].numpy(), out[1].numpy(), atol=1e-6)


@pytest.mark.parametrize("make", MODULES, ids=MODULE_IDS)
def test_module_without_context_ignores_the_sweep(make):
    features, sweep, length = _inputs()
    module = _seeded(lambda: make(use_context=False))
    assert module.encoder is None
    with torch.no_grad():
        out = module(features)
        assert out.shape == (2, 30, 3)
        assert torch.equal(module(features, sweep, length), out)
        assert torch.equal(module(features, 5 * sweep, length), out)
    with_context = _seeded(make)
    with pytest.raises(ValueError, match="sweep"):
        with_context(features)


# ---------------------------------------------------------------------------
# fit / predict
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Est", LEARNERS)
def test_pipeline_fit_predict(Est, small, fitted):
    X, Xb, y = small
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", tiny_residual(Est))])
    assert pipe.fit(X, y) is pipe
    pred = pipe.predict(X)
    assert pred.shape == (len(X), 3) and pred.dtype == np.float64
    assert np.isfinite(pred).all()
    b = Xb[B].to_numpy()
    motion = _motion(X)
    # sweep rows get the nominal tip unchanged, motion rows a residual
    assert_array_equal(pred[~motion], b[~motion])
    assert np.abs(pred[motion] - b[motion]).min(axis=1).max() > 0
    # the pipeline is the backbone's output fed to the residual
    _, pred_direct = fitted(Est)
    assert_allclose(pred, pred_direct, rtol=0, atol=1e-9)
    assert pipe.score(X, y) == pytest.approx(-mean_per_run_rmse(y, pred, X))


@pytest.mark.parametrize("Est", LEARNERS)
def test_predict_residual_and_score(Est, small, fitted):
    _, Xb, y = small
    est, pred = fitted(Est)
    r = est.predict_residual(Xb)
    assert r.shape == (len(Xb), 3)
    assert_array_equal(r[~_motion(Xb)], 0.0)
    assert_allclose(Xb[B].to_numpy() + r, pred, rtol=0, atol=1e-12)
    assert est.score(Xb, y) == pytest.approx(-mean_per_run_rmse(y, pred, Xb))
    assert est.sigma_e_.shape == (3,) and (est.sigma_e_ > 0).all()
    assert est.x_scaler_.mean.shape == (9,) and est.s_scaler_.mean.shape == (4,)
    with pytest.raises(ValueError, match="sample_weight"):
        est.score(Xb, y, sample_weight=np.ones(len(Xb)))


@pytest.mark.parametrize("Est", LEARNERS)
def test_applied_residual_is_clipped(Est, small):
    _, Xb, y = small
    est = tiny_residual(Est, clip=0.5).fit(Xb, y)
    r = est.predict(Xb) - Xb[B].to_numpy()
    motion = _motion(Xb)
    assert np.abs(r[motion]).max() <= 0.5 + 1e-12
    assert np.abs(r[motion]).max() == pytest.approx(0.5)  # the bound is reached
    assert_array_equal(r[~motion], 0.0)
    # without a bound the same network goes further
    est.set_params(clip=None)
    assert np.abs(est.predict(Xb) - Xb[B].to_numpy())[motion].max() > 0.5


@pytest.mark.parametrize("Est", LEARNERS)
def test_predict_does_not_read_motion_references(Est, small, fitted):
    X, Xb, y = small
    est, pred = fitted(Est)
    motion = _motion(Xb)
    rng = np.random.default_rng(0)
    scrambled = Xb.copy()
    scrambled.loc[motion, REF] = rng.normal(0.0, 50.0, (motion.sum(), 3))
    assert_array_equal(est.predict(scrambled), pred)
    scrambled.loc[motion, REF] = np.nan
    assert_array_equal(est.predict(scrambled), pred)
    # through the pipeline as well (the backbone reads only sweep references)
    pipe = Pipeline([("backbone", PDLBackbone().fit(X)), ("residual", est)])
    raw = X.copy()
    raw.loc[motion, REF] = rng.normal(0.0, 50.0, (motion.sum(), 3))
    assert_allclose(pipe.predict(raw), pred, rtol=0, atol=1e-9)


@pytest.mark.parametrize("Est", LEARNERS)
def test_runs_are_predicted_independently(Est, small, fitted):
    _, Xb, _ = small
    est, pred = fitted(Est)
    for run in _runs(Xb):
        rows = (Xb["run"] == run).to_numpy()
        assert_allclose(est.predict(Xb[rows]), pred[rows], rtol=0, atol=1e-5)
    # rows of the runs interleaved (time order kept within each run)
    order = np.argsort(Xb["t"].to_numpy(), kind="stable")
    assert (Xb["run"].iloc[order[:3]].nunique()) > 1
    assert_allclose(est.predict(Xb.iloc[order]), pred[order], rtol=0, atol=1e-5)
    # runs in reverse order
    reverse = np.concatenate(
        [np.flatnonzero((Xb["run"] == r).to_numpy()) for r in _runs(Xb)[::-1]]
    )
    assert_allclose(est.predict(Xb.iloc[reverse]), pred[reverse], rtol=0, atol=1e-5)


@pytest.mark.parametrize("Est", LEARNERS)
def test_prediction_is_causal(Est, small, fitted):
    # the prediction of a motion row does not depend on later rows
    _, Xb, _ = small
    est, pred = fitted(Est)
    rows = np.flatnonzero((Xb["run"] == _runs(Xb)[1]).to_numpy())
    n_sweep = int((~_motion(Xb.iloc[rows])).sum())
    head = rows[: n_sweep + 120]
    assert_allclose(est.predict(Xb.iloc[head]), pred[head], rtol=0, atol=1e-5)
    # changing the motor angle of motion step 10 changes steps 10 and 11
    # (through dq), and the later steps of a recurrent learner only
    changed = Xb.iloc[rows].copy()
    changed.iloc[n_sweep + 10, changed.columns.get_loc("q1")] += 5.0
    diff = np.abs(est.predict(changed) - pred[rows]).max(axis=1)
    assert diff[: n_sweep + 10].max() < 1e-5
    assert diff[n_sweep + 10] > 1e-3 and diff[n_sweep + 11] > 1e-3
    assert (diff[n_sweep + 12 :].max() > 1e-3) == (Est is GRUResidual)


@pytest.mark.parametrize("Est", LEARNERS)
def test_runs_without_motion_get_the_backbone(Est, small, fitted):
    _, Xb, _ = small
    est, pred = fitted(Est)
    sweep = ~_motion(Xb)
    first = (Xb["run"] == _runs(Xb)[0]).to_numpy()
    # recordings that stop during the sweep: nothing to correct
    assert_array_equal(est.predict(Xb[first & sweep]), Xb.loc[first & sweep, B].to_numpy())
    assert_array_equal(est.predict(Xb[sweep]), Xb.loc[sweep, B].to_numpy())
    # next to runs with motion
    rows = (first & sweep) | ~first
    assert_allclose(est.predict(Xb[rows]), pred[rows], rtol=0, atol=1e-5)


@pytest.mark.parametrize("Est", LEARNERS)
def test_inputs_are_not_modified(Est, small):
    _, Xb, y = small
    X_before, y_before = Xb.copy(deep=True), y.copy()
    est = tiny_residual(Est).fit(Xb, y)
    est.predict(Xb)
    est.score(Xb, y)
    assert Xb.equals(X_before) and list(Xb.dtypes) == list(X_before.dtypes)
    assert_array_equal(y, y_before)


@pytest.mark.parametrize("Est", LEARNERS)
def test_random_state_makes_fits_reproducible(Est, small, fitted):
    _, Xb, y = small
    _, pred = fitted(Est)
    assert_array_equal(tiny_residual(Est).fit(Xb, y).predict(Xb), pred)
    assert np.abs(tiny_residual(Est, random_state=1).fit(Xb, y).predict(Xb) - pred).max() > 1e-3
    # a RandomState instance is accepted as well
    rs = tiny_residual(Est, random_state=np.random.RandomState(0)).fit(Xb, y).predict(Xb)
    assert rs.shape == pred.shape and np.isfinite(rs).all()


class _ThreadSpy(Callback):
    """Records torch's thread count at every epoch."""

    def initialize(self):
        self.seen = []
        return self

    def on_epoch_begin(self, net, **kwargs):
        self.seen.append(torch.get_num_threads())


def test_fit_restores_threads_and_global_random_state(small):
    _, Xb, y = small
    before = torch.get_num_threads()
    torch.set_num_threads(before + 1)
    try:
        torch_state = torch.get_rng_state()
        np_state = np.random.get_state()[1].copy()
        spy = _ThreadSpy()
        est = tiny_residual(GRUResidual, n_threads=1, callbacks=[("spy", spy)]).fit(Xb, y)
        assert spy.seen == [1, 1]  # training ran on one thread
        assert torch.get_num_threads() == before + 1
        assert torch.equal(torch.get_rng_state(), torch_state)
        est.predict(Xb)
        assert torch.get_num_threads() == before + 1
        # prediction does not draw from torch's global generator either
        assert torch.equal(torch.get_rng_state(), torch_state)
        assert_array_equal(np.random.get_state()[1], np_state)
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("Est", LEARNERS)
def test_pickle_and_joblib_round_trip(Est, small, fitted):
    _, Xb, _ = small
    est, pred = fitted(Est)
    assert_array_equal(pickle.loads(pickle.dumps(est)).predict(Xb), pred)
    buffer = io.BytesIO()
    joblib.dump(est, buffer)
    buffer.seek(0)
    assert_array_equal(joblib.load(buffer).predict(Xb), pred)


@pytest.mark.parametrize("Est", LEARNERS)
def test_clone_and_nested_params(Est, small, fitted):
    _, Xb, y = small
    est, pred = fitted(Est)
    keys = [
        "module__hidden_size", "module__context_size", "window_s", "burn_in_s", "sweep_stride_s",
        "lr", "max_epochs", "batch_size", "n_threads", "random_state", "clip", "use_torque",
    ]  # fmt: skip
    params = est.get_params()
    assert params["module__hidden_size"] == 8 and params["window_s"] == 5.0
    assert params["burn_in_s"] == 1.0
    cloned = clone(est)
    assert {k: cloned.get_params()[k] for k in keys} == {k: params[k] for k in keys}
    assert not cloned.initialized_ and not hasattr(cloned, "sigma_e_")
    assert_array_equal(cloned.fit(Xb, y).predict(Xb), pred)
    # module__ parameters reach the network
    other = tiny_residual(Est).set_params(module__hidden_size=6, window_s=4.0)
    assert other.get_params()["module__hidden_size"] == 6
    assert other.get_params()["window_s"] == 4.0
    other.fit(Xb, y)
    first = other.module_.gru if Est is GRUResidual else other.module_.mlp[0]
    assert (first.hidden_size if Est is GRUResidual else first.out_features) == 6


def test_default_parameters():
    gru, mlp = GRUResidual(), MLPResidual()
    assert gru.get_params()["burn_in_s"] == 5.0
    assert mlp.get_params()["burn_in_s"] == 0.0  # no hidden state to warm up
    for est in (gru, mlp):
        p = est.get_params()
        assert (p["window_s"], p["clip"], p["lr"], p["use_torque"], p["use_context"]) == (
            20.0, 25.0, 1e-2, True, True
        )
        assert (p["lr_schedule"], p["optimizer__weight_decay"]) == ("cosine", 1e-4)
        assert (p["sweep_stride_s"], p["sweep_pooling"]) == (4.0, "mean")
        assert p["window_step_s"] is None
    assert clone(mlp).get_params()["burn_in_s"] == 0.0


@pytest.mark.parametrize("Est", LEARNERS)
def test_fit_keeps_parameters(Est, small):
    _, Xb, y = small
    est = tiny_residual(Est)
    # skorch lists its callback instances (stateful once trained) among the
    # parameters; the estimator's own and the module's parameters must not change
    def own(params):
        return {k: v for k, v in params.items() if not k.startswith("callbacks")}

    before = joblib.hash(own(est.get_params()))
    assert est.fit(Xb, y) is est
    est.predict(Xb)
    after = joblib.hash(own(est.get_params()))
    assert after == before
    assert list(est.feature_names_in_) == list(Xb.columns)
    assert est.n_features_in_ == Xb.shape[1]


def test_fit_sets_only_private_or_trailing_underscore_attributes(small):
    _, Xb, y = small
    est = tiny_residual(GRUResidual)
    public_before = {k for k in vars(est) if not k.startswith("_")}
    est.fit(Xb, y)
    est.predict(Xb)
    added = {k for k in vars(est) if not k.startswith("_")} - public_before
    assert {"module_", "sigma_e_", "x_scaler_", "s_scaler_", "n_features_in_"} <= added
    assert all(k.endswith("_") for k in added)


@pytest.mark.parametrize("Est", [*LEARNERS, NoResidual])
def test_predict_does_not_change_the_estimator(Est, small, fitted):
    _, Xb, y = small
    est = fitted(Est)[0] if Est is not NoResidual else NoResidual().fit(Xb, y)
    before = dict(vars(est))
    weights = {}
    if Est is not NoResidual:
        weights = {k: v.clone() for k, v in est.module_.state_dict().items()}
    est.predict(Xb)
    est.score(Xb, y)
    after = vars(est)
    assert after.keys() == before.keys()
    assert all(after[k] is before[k] for k in before)
    for key, value in weights.items():
        assert torch.equal(est.module_.state_dict()[key], value)


@pytest.mark.parametrize("Est", LEARNERS)
def test_numeric_dtypes_of_recordings(Est, small, fitted):
    _, Xb, y = small
    est, pred = fitted(Est)
    X2 = Xb.astype({"tau1": np.float32, "tau2": np.float32, "b_x": np.float32})
    X2["q1"] = X2["q1"].astype(object)
    pred2 = est.predict(X2)
    assert pred2.dtype == np.float64
    assert np.abs(pred2 - pred).max() < 1e-3
    # integer torques train as well
    X3 = Xb.assign(tau1=Xb["tau1"].round().astype(np.int64), tau2=Xb["tau2"].round().astype(int))
    pred3 = tiny_residual(Est).fit(X3, y.astype(np.float32)).predict(X3)
    assert pred3.dtype == np.float64 and np.isfinite(pred3).all()


@pytest.mark.parametrize("Est", LEARNERS)
def test_read_only_recordings(Est, small, fitted):
    _, Xb, y = small
    _, pred = fitted(Est)
    arrays = {}
    for name in Xb.columns:
        values = Xb[name].to_numpy(copy=True)
        values.flags.writeable = False
        arrays[name] = values
    X_ro = pd.DataFrame(arrays, index=Xb.index, copy=False)
    y_ro = y.copy()
    y_ro.flags.writeable = False
    assert not X_ro["q1"].to_numpy().flags.writeable
    assert_array_equal(tiny_residual(Est).fit(X_ro, y_ro).predict(X_ro), pred)


@pytest.mark.parametrize("Est", [*LEARNERS, NoResidual])
def test_empty_and_non_dataframe_input(Est, small):
    _, Xb, y = small
    est = tiny_residual(Est) if Est is not NoResidual else NoResidual()
    with pytest.raises(ValueError, match="empty"):
        est.fit(Xb.iloc[:0], y[:0])
    with pytest.raises(TypeError, match="DataFrame"):
        est.fit(Xb.to_numpy(), y)


@pytest.mark.parametrize("Est", LEARNERS)
def test_fit_rejects_bad_targets(Est, small):
    _, Xb, y = small
    with pytest.raises(ValueError, match="rows"):
        tiny_residual(Est).fit(Xb, y[:-1])
    y_inf = y.copy()
    y_inf[-3, 1] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        tiny_residual(Est).fit(Xb, y_inf)
    with pytest.raises(ValueError):
        tiny_residual(Est).fit(Xb, y[:, :2])


def test_tracker_dropouts_in_y_are_skipped(small):
    _, Xb, y = small
    y_nan = y.copy()
    y_nan[::7] = np.nan
    est = tiny_residual(GRUResidual).fit(Xb, y_nan)
    assert np.isfinite(est.predict(Xb)).all()
    assert np.isfinite(est.history[:, "train_loss"]).all()
    y_none = y.copy()
    y_none[_motion(Xb)] = np.nan
    with pytest.raises(ValueError, match="no finite tip position"):
        tiny_residual(GRUResidual).fit(Xb, y_none)


# ---------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Est", [*LEARNERS, NoResidual])
def test_missing_backbone_columns(Est, small):
    X, _, y = small
    est = tiny_residual(Est) if Est is not NoResidual else NoResidual()
    with pytest.raises(ValueError, match="b_x") as info:
        est.fit(X, y)
    assert "PDLBackbone" in str(info.value) and "Pipeline" in str(info.value)


@pytest.mark.parametrize("Est", [*LEARNERS, NoResidual])
def test_bad_backbone_values_and_columns_at_predict(Est, small, fitted):
    _, Xb, y = small
    est = fitted(Est)[0] if Est is not NoResidual else NoResidual().fit(Xb, y)
    bad = Xb.copy()
    bad.iloc[5, bad.columns.get_loc("b_y")] = np.nan
    with pytest.raises(ValueError, match="b_y"):
        est.predict(bad)
    with pytest.raises(ValueError, match="tau1"):
        est.predict(Xb.drop(columns="tau1"))
    with pytest.raises(ValueError, match="b_z"):
        est.predict(Xb.drop(columns="b_z"))
    if Est is not NoResidual:
        with pytest.raises(ValueError, match="b_y"):
            tiny_residual(Est).fit(bad, y)


@pytest.mark.parametrize("Est", LEARNERS)
def test_fit_needs_y(Est, small):
    _, Xb, _ = small
    for method in ("fit", "partial_fit"):
        est = tiny_residual(Est)
        with pytest.raises(ValueError, match="tip positions y"):
            getattr(est, method)(Xb, None)
        assert not hasattr(est, "sigma_e_")


@pytest.mark.parametrize("Est", LEARNERS)
@pytest.mark.parametrize(
    "params, name",
    [
        (dict(window_s=0.1, burn_in_s=0.0), "window_s=0.1 s is 1 sample"),
        (dict(window_s=0.0), "window_s"),
        (dict(burn_in_s=5.0, window_s=5.0), "burn_in_s"),
        (dict(burn_in_s=-1.0), "burn_in_s"),
        (dict(burn_in_s=4.98, window_s=5.0), "burn_in_s=4.98 s is 50 samples"),
        (dict(window_step_s=6.0), "window_step_s"),
        (dict(window_step_s=0.01), "window_step_s=0.01 s is 0 sample"),
        (dict(sweep_stride_s=0.04), "sweep_stride_s=0.04 s is 0 sample"),
        (dict(validation_fraction=1.5), "validation_fraction"),
        (dict(validation_fraction=0.0), "validation_fraction"),
        (dict(clip=0.0), "clip"),
        (dict(sweep_stride_s=0.0), "sweep_stride_s"),
        (dict(sweep_pooling="max"), "sweep_pooling"),
        (dict(n_threads=0), "n_threads"),
        (dict(lr=-1.0), "lr"),
    ],
    ids=lambda v: str(v) if isinstance(v, str) else None,
)
def test_bad_parameters_raise_value_error(Est, params, name, small):
    _, Xb, y = small
    est = tiny_residual(Est, **params)
    with pytest.raises(ValueError, match=name):
        est.fit(Xb, y)
    assert not hasattr(est, "sigma_e_")


@pytest.mark.parametrize("Est", LEARNERS)
def test_fit_validates_parameters_and_input_once(Est, small, monkeypatch):
    _, Xb, y = small
    calls = {"params": 0, "X": 0}

    def count(key, function):
        def wrapper(*args, **kwargs):
            calls[key] += 1
            return function(*args, **kwargs)

        return wrapper

    monkeypatch.setattr(_net, "validate_parameter_constraints",
                        count("params", _net.validate_parameter_constraints))
    monkeypatch.setattr(_net, "check_recordings",
                        count("X", _net.check_recordings))
    est = tiny_residual(Est, max_epochs=1)
    est.fit(Xb, y)
    assert calls == {"params": 1, "X": 1}
    # a first partial_fit starts as fit does, validating once as well
    calls.update(params=0, X=0)
    tiny_residual(Est, max_epochs=1).partial_fit(Xb, y)
    assert calls == {"params": 1, "X": 1}
    # later calls of partial_fit check the data only (as scikit-learn's estimators do)
    calls.update(params=0, X=0)
    est.partial_fit(Xb, y)
    assert calls == {"params": 0, "X": 1}


@pytest.mark.parametrize("Est", LEARNERS)
def test_misspelled_skorch_arguments_are_still_refused(Est, small):
    _, Xb, y = small
    est = tiny_residual(Est, iterator_train_shuffle=False)
    with pytest.raises(ValueError, match="did you mean iterator_train__shuffle"):
        est.fit(Xb, y)
    # and set_params of an initialised net checks the names as skorch does
    est = tiny_residual(Est, max_epochs=1).fit(Xb, y)
    with pytest.raises(ValueError, match="did you mean optimizer__weight_decay"):
        est.set_params(optimizer_weight_decay=0.0, optimizer__lr=0.1)


@pytest.mark.parametrize("Est", LEARNERS)
def test_not_fitted(Est, small):
    _, Xb, y = small
    est = tiny_residual(Est)
    with pytest.raises(NotFittedError):
        est.predict(Xb)
    with pytest.raises(NotFittedError):
        est.predict_residual(Xb)
    with pytest.raises(NotFittedError):
        est.score(Xb, y)
    with pytest.raises(NotFittedError):
        NoResidual().predict(Xb)


# ---------------------------------------------------------------------------
# pretrained, warm start, validation
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Est", LEARNERS)
def test_pretrained_starts_from_the_fitted_weights(Est, small, fitted):
    _, Xb, y = small
    source, pred = fitted(Est)
    weights = {k: v.clone() for k, v in source.module_.state_dict().items()}
    # no training: the pretrained model's predictions, and its statistics
    same = tiny_residual(Est, max_epochs=0, pretrained=FrozenEstimator(source)).fit(Xb, y)
    assert_array_equal(same.predict(Xb), pred)
    assert_array_equal(same.sigma_e_, source.sigma_e_)
    assert same.module_ is not source.module_
    # fine-tuning changes the copy, not the source; the statistics are kept
    # even though the data are different
    tuned = tiny_residual(Est, max_epochs=1, lr=1e-2, pretrained=FrozenEstimator(source))
    part = (Xb["setting"] != "S02").to_numpy()
    tuned.fit(Xb[part], y[part])
    assert np.abs(tuned.predict(Xb) - pred).max() > 1e-4
    assert_array_equal(tuned.x_scaler_.mean, source.x_scaler_.mean)
    for key, value in source.module_.state_dict().items():
        assert torch.equal(value, weights[key])
    assert_array_equal(source.predict(Xb), pred)
    # FrozenEstimator survives clone; the fine-tuned start is not a random one
    from_clone = clone(tiny_residual(Est, max_epochs=0, pretrained=FrozenEstimator(source)))
    assert_array_equal(from_clone.fit(Xb, y).predict(Xb), pred)
    random_start = tiny_residual(Est, max_epochs=0, random_state=5).fit(Xb, y).predict(Xb)
    assert np.abs(random_start - pred).max() > 0


@pytest.mark.parametrize("Est", LEARNERS)
def test_pretrained_errors(Est, small, fitted):
    _, Xb, y = small
    source, _ = fitted(Est)
    with pytest.raises(NotFittedError, match="FrozenEstimator"):
        tiny_residual(Est, pretrained=Est()).fit(Xb, y)
    # a plain fitted estimator loses its weights when cloned
    with pytest.raises(NotFittedError, match="FrozenEstimator"):
        clone(tiny_residual(Est, pretrained=source)).fit(Xb, y)
    with pytest.raises(ValueError, match="use_torque"):
        tiny_residual(Est, use_torque=False, pretrained=FrozenEstimator(source)).fit(Xb, y)
    with pytest.raises(ValueError, match="use_context"):
        tiny_residual(Est, use_context=False, pretrained=source).fit(Xb, y)
    other = MLPResidual if Est is GRUResidual else GRUResidual
    with pytest.raises(TypeError, match=Est.__name__):
        tiny_residual(Est, pretrained=fitted(other)[0]).fit(Xb, y)
    with pytest.raises(ValueError, match="frame"):
        tiny_residual(Est, frame="base", pretrained=FrozenEstimator(source)).fit(Xb, y)
    # the encoder learned sweeps shortened in one way
    with pytest.raises(ValueError, match="sweep_stride_s=5.0"):
        tiny_residual(Est, sweep_stride_s=2.5, pretrained=FrozenEstimator(source)).fit(Xb, y)
    with pytest.raises(ValueError, match="sweep_pooling='mean'"):
        tiny_residual(Est, sweep_pooling="subsample", pretrained=FrozenEstimator(source)).fit(Xb, y)


@pytest.mark.parametrize("Est", LEARNERS)
def test_warm_start_continues_training(Est, small):
    _, Xb, y = small
    est = tiny_residual(Est, warm_start=True)
    est.fit(Xb, y)
    assert len(est.history) == 2
    module, scaler = est.module_, est.x_scaler_
    first = est.predict(Xb)
    est.fit(Xb, y)
    assert len(est.history) == 4
    assert est.module_ is module and est.x_scaler_ is scaler
    assert np.abs(est.predict(Xb) - first).max() > 0
    # partial_fit continues as well; without warm start, fit starts over
    est.partial_fit(Xb, y)
    assert len(est.history) == 6
    cold = tiny_residual(Est)
    cold.fit(Xb, y)
    cold.fit(Xb, y)
    assert len(cold.history) == 2
    assert_array_equal(cold.predict(Xb), first)


@pytest.mark.parametrize("Est", LEARNERS)
def test_whole_sequence_training(Est, small, monkeypatch):
    # window_s=None: one training item per run, every step in the loss
    _, Xb, y = small
    calls = []
    original = Est.get_split_datasets

    def spy(self, X, y=None, **fit_params):
        calls.append(X)
        return original(self, X, y, **fit_params)

    monkeypatch.setattr(Est, "get_split_datasets", spy)
    est = tiny_residual(Est, window_s=None, burn_in_s=50.0).fit(Xb, y)
    data = calls[0]
    assert data["features"].shape == (len(SMALL_SETTINGS), N_MOTION, 9)
    assert data["mask"].sum() == _motion(Xb).sum()
    pred = est.predict(Xb)
    assert np.isfinite(pred).all()
    assert np.abs(pred - Xb[B].to_numpy())[_motion(Xb)].max() > 0


@pytest.mark.parametrize("Est", LEARNERS)
def test_first_partial_fit_is_fit(Est, small, fitted):
    _, Xb, y = small
    source, pred = fitted(Est)
    est = tiny_residual(Est)
    assert est.partial_fit(Xb, y) is est
    assert len(est.history) == 2
    assert_array_equal(est.predict(Xb), pred)
    # including the start from a pretrained model
    tuned = tiny_residual(Est, max_epochs=0, pretrained=FrozenEstimator(source)).partial_fit(Xb, y)
    assert_array_equal(tuned.predict(Xb), pred)


def test_validation_holds_out_whole_settings(small, monkeypatch):
    _, Xb, y = small
    X4, y4 = _with_repeat(Xb, y, "S09")  # four runs, three settings
    calls = []
    original = GRUResidual.get_split_datasets

    def spy(self, X, y=None, **fit_params):
        out = original(self, X, y, **fit_params)
        calls.append((X, out))
        return out

    monkeypatch.setattr(GRUResidual, "get_split_datasets", spy)
    est = tiny_residual(GRUResidual, validation_fraction=0.3, max_epochs=3).fit(X4, y4)
    valid_loss = est.history[:, "valid_loss"]
    assert len(valid_loss) == 3 and np.isfinite(valid_loss).all()
    assert est.predict(X4).shape == (len(X4), 3)

    # the setting of every training window, from the run order and cut_windows
    data, (train, valid) = calls[0]
    runs = _runs(X4)
    lengths = [int((_motion(X4) & (X4["run"] == r).to_numpy()).sum()) for r in runs]
    run_index, _ = cut_windows(np.array(lengths), 50, 40)
    setting_of_run = np.array(
        [X4.loc[X4["run"] == r, "setting"].astype(str).iloc[0] for r in runs]
    )
    window_setting = setting_of_run[run_index]
    assert len(data["features"]) == len(window_setting)
    assert_array_equal(pd.factorize(window_setting)[0], data["group"])
    in_train = set(window_setting[train.indices])
    in_valid = set(window_setting[valid.indices])
    assert in_train and in_valid and not in_train & in_valid
    assert in_train | in_valid == set(SMALL_SETTINGS)
    assert len(train.indices) + len(valid.indices) == len(window_setting)
    # the split is seeded: the same settings are held out again
    tiny_residual(GRUResidual, validation_fraction=0.3, max_epochs=1).fit(X4, y4)
    assert_array_equal(calls[-1][1][1].indices, valid.indices)


def test_early_stopping_restores_the_best_epoch(small, monkeypatch):
    _, Xb, y = small
    calls = []
    original = MLPResidual.get_split_datasets

    def spy(self, X, y=None, **fit_params):
        out = original(self, X, y, **fit_params)
        calls.append((X, y, out))
        return out

    monkeypatch.setattr(MLPResidual, "get_split_datasets", spy)
    est = tiny_residual(
        MLPResidual, validation_fraction=0.3, n_iter_no_change=2, max_epochs=30, lr=0.3
    ).fit(Xb, y)
    valid_loss = np.asarray(est.history[:, "valid_loss"])
    assert len(valid_loss) < 30  # stopped early
    best = int(np.argmin(valid_loss))
    assert len(valid_loss) == best + 1 + 2  # after n_iter_no_change epochs without progress
    assert valid_loss[-1] > valid_loss[best]
    # the weights of the best epoch are restored: the validation windows (one
    # batch) have the best epoch's loss
    data, target, (_, valid) = calls[0]
    assert len(valid.indices) <= est.batch_size
    items = {k: v[valid.indices] for k, v in data.items()}
    with torch.no_grad():
        loss = est.get_loss(est.infer(items), target[valid.indices], items).item()
    assert loss == pytest.approx(valid_loss[best], rel=1e-4)


def test_validation_needs_two_settings(small):
    _, Xb, y = small
    rows = (Xb["setting"] == "S02").to_numpy()
    with pytest.raises(ValueError, match="two shaft settings"):
        tiny_residual(GRUResidual, validation_fraction=0.3).fit(Xb[rows], y[rows])


# ---------------------------------------------------------------------------
# inputs that must not matter
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Est", LEARNERS)
def test_without_torque_the_torques_are_not_used(Est, small, fitted):
    _, Xb, y = small
    rng = np.random.default_rng(1)
    other_tau = Xb.assign(
        tau1=rng.normal(0.0, 30.0, len(Xb)), tau2=rng.normal(0.0, 30.0, len(Xb))
    )
    est = tiny_residual(Est, use_torque=False).fit(Xb, y)
    assert est.x_scaler_.mean.shape == (7,) and est.s_scaler_.mean.shape == (2,)
    pred = est.predict(Xb)
    assert_array_equal(est.predict(other_tau), pred)
    # nor are they used in fit
    assert_array_equal(tiny_residual(Est, use_torque=False).fit(other_tau, y).predict(Xb), pred)
    # while the default learner does use them
    with_torque, pred_torque = fitted(Est)
    assert np.abs(with_torque.predict(other_tau) - pred_torque).max() > 1e-4


@pytest.mark.parametrize("Est", LEARNERS)
def test_without_context_the_sweep_is_not_used(Est, small, fitted):
    # fed directly with fixed backbone columns: a backbone would read the sweep
    _, Xb, y = small
    sweep = ~_motion(Xb)
    # the last sweep row of a run stays: the first motion step dq is taken from it
    last_sweep = sweep & ~np.roll(sweep, -1)
    change = sweep & ~last_sweep
    assert change.sum() == sweep.sum() - len(SMALL_SETTINGS)
    rng = np.random.default_rng(2)
    other_sweep = Xb.copy()
    for c in ("q1", "q2", "tau1", "tau2"):
        other_sweep.loc[change, c] = rng.normal(0.0, 20.0, change.sum())
    # frame="sweep" would read the sweep for the frame; the context must not
    est = tiny_residual(Est, use_context=False, frame="base").fit(Xb, y)
    assert est.module_.encoder is None
    pred = est.predict(Xb)
    assert_array_equal(est.predict(other_sweep), pred)
    with_context, pred_context = fitted(Est)
    assert np.abs(with_context.predict(other_sweep) - pred_context).max() > 1e-4


def _remounted(Xb, y, runs, rotations):
    """Recordings of ``runs`` seen from base sensors rotated by ``rotations`` (3x3 each)."""
    Xr, yr = Xb.copy(), y.copy()
    for run, G in zip(runs, rotations):
        rows = (Xb["run"].astype(str) == run).to_numpy()
        for cols in (B, REF):
            Xr.loc[rows, cols] = Xb.loc[rows, cols].to_numpy() @ G.T
        yr[rows] = y[rows] @ G.T
    return Xr, yr


@pytest.mark.parametrize("Est", LEARNERS)
def test_sweep_frame_makes_the_residual_independent_of_the_sensor_mount(Est, small):
    # a run seen from a rotated base sensor gets the same residual, rotated
    _, Xb, y = small
    runs = _runs(Xb)
    rng = np.random.default_rng(4)
    G = [Rotation.random(random_state=rng).as_matrix() for _ in runs]
    Xr, yr = _remounted(Xb, y, runs, G)
    codes = pd.factorize(Xb["run"].astype(str))[0]
    Gr = np.stack(G)[codes]

    def rotated(r):
        return np.einsum("nij,nj->ni", Gr, r)

    est = tiny_residual(Est, clip=None).fit(Xb, y)
    assert_allclose(est.predict_residual(Xr), rotated(est.predict_residual(Xb)), atol=1e-3)
    # and training on remounted catheters learns the same model
    remounted = tiny_residual(Est, clip=None).fit(Xr, yr)
    assert_allclose(remounted.predict_residual(Xr), rotated(est.predict_residual(Xb)), atol=1e-3)
    # in the base frame the network sees the mount, and the residual changes
    base = tiny_residual(Est, clip=None, frame="base").fit(Xb, y)
    moved = np.abs(base.predict_residual(Xr) - rotated(base.predict_residual(Xb)))
    assert moved.max() > 0.1


# ---------------------------------------------------------------------------
# sample weights
# ---------------------------------------------------------------------------
def test_masked_normalized_mse_weights_the_steps():
    g = torch.Generator().manual_seed(0)
    prediction = torch.randn(2, 5, 3, generator=g, requires_grad=True)
    target = torch.randn(2, 5, 3, generator=g)
    weight = torch.tensor([[0.5, 2.0, 0.0, 1.0, 0.0], [0.0, 0.25, 3.0, 0.0, 0.0]])
    loss = MaskedNormalizedMSE()(prediction, target, weight)
    p, t, w = prediction.detach().numpy(), target.numpy(), weight.numpy()
    expected = (w * ((p - t) ** 2).sum(axis=2)).sum() / (3 * w.sum())
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    # steps of weight 0 get no gradient, the others do
    loss.backward()
    assert (prediction.grad[weight == 0] == 0).all()
    assert (prediction.grad[weight > 0].abs().sum(dim=1) > 0).all()
    # weights below 1 in all are not rounded up
    small = MaskedNormalizedMSE()(prediction, target, weight / 100)
    assert small.item() == pytest.approx(expected, rel=1e-5)


def test_standardizer_weights_count_as_repeated_rows():
    rng = np.random.default_rng(0)
    values = rng.normal(size=(6, 3))
    weight = np.array([1.0, 2.0, 0.0, 3.0, 1.0, 1.0])
    weighted = Standardizer.fit(values, weight)
    repeated = Standardizer.fit(np.repeat(values, weight.astype(int), axis=0))
    assert_allclose(weighted.mean, repeated.mean, rtol=1e-12)
    assert_allclose(weighted.scale, repeated.scale, rtol=1e-12)
    unit = Standardizer.fit(values, np.ones(6))
    assert_allclose(unit.mean, Standardizer.fit(values).mean, rtol=1e-12)


@pytest.mark.parametrize("Est", LEARNERS)
def test_zero_weighted_run_gives_the_model_without_it(Est, small, fitted):
    """Weight 0 on a run: no window, no gradient, no statistics; the model fitted without it."""
    _, Xb, y = small
    dropped = (Xb["setting"] == SMALL_SETTINGS[0]).to_numpy()
    weight = np.where(dropped, 0.0, 1.0)
    zeroed = tiny_residual(Est).fit(Xb, y, sample_weight=weight)
    without = tiny_residual(Est).fit(Xb[~dropped], y[~dropped], sample_weight=weight[~dropped])
    assert_array_equal(zeroed.predict(Xb), without.predict(Xb))
    assert_array_equal(zeroed.sigma_e_, without.sigma_e_)
    # the weights reach the loss: unlike the unweighted fit
    _, pred = fitted(Est)
    assert np.abs(zeroed.predict(Xb) - pred).max() > 1e-3
    # unit weights are no weights
    ones = tiny_residual(Est).fit(Xb, y, sample_weight=np.ones(len(Xb)))
    assert_array_equal(ones.predict(Xb), pred)


@pytest.mark.parametrize("Est", LEARNERS)
def test_sample_weight_forms_and_errors(Est, small):
    _, Xb, y = small
    weight = np.linspace(0.5, 2.0, len(Xb))
    before = weight.copy()
    expected = tiny_residual(Est, max_epochs=1).fit(Xb, y, sample_weight=weight).predict(Xb)
    assert_array_equal(weight, before)  # not overwritten
    for form in (weight.tolist(), pd.Series(weight, index=Xb.index[::-1])):
        est = tiny_residual(Est, max_epochs=1).fit(Xb, y, sample_weight=form)
        assert_array_equal(est.predict(Xb), expected)  # by position, as numpy arrays
    for bad, match in [(weight[:-1], r"sample_weight.shape"),
                       (-weight, r"Negative values in data passed to `sample_weight`"),
                       (np.zeros(len(Xb)), r"at least one non-zero"),
                       (np.where(_motion(Xb), 0.0, 1.0), r"positive sample_weight")]:
        with pytest.raises(ValueError, match=match):
            tiny_residual(Est, max_epochs=1).fit(Xb, y, sample_weight=bad)


def test_sample_weight_is_routed_through_a_pipeline(small):
    import sklearn

    X, _, y = small
    weight = np.where((X["setting"] == SMALL_SETTINGS[1]).to_numpy(), 0.0, 1.0)
    steps = lambda: [("backbone", PDLBackbone()),  # noqa: E731
                     ("residual", tiny_residual(GRUResidual, max_epochs=1))]
    expected = Pipeline(steps()).fit(X, y, residual__sample_weight=weight).predict(X)
    with sklearn.config_context(enable_metadata_routing=True):
        pipe = Pipeline(steps())
        pipe.named_steps["residual"].set_fit_request(sample_weight=True)
        assert_array_equal(pipe.fit(X, y, sample_weight=weight).predict(X), expected)


# ---------------------------------------------------------------------------
# device, methods a regressor does not offer
# ---------------------------------------------------------------------------
def _unavailable_device():
    """A CUDA device this machine does not have."""
    return f"cuda:{torch.cuda.device_count()}" if torch.cuda.is_available() else "cuda"


@pytest.mark.parametrize("Est", LEARNERS)
def test_unavailable_device_is_refused_up_front(Est, small, fitted, monkeypatch):
    _, Xb, y = small
    device = _unavailable_device()
    prepared = []
    monkeypatch.setattr(_net.Standardizer, "fit",
                        lambda *a, **k: prepared.append(1))  # never reached
    with pytest.raises(ValueError, match=rf"has device='{device}', but torch cannot compute "
                       r"there on this machine; the devices available are \['cpu'"):
        tiny_residual(Est, device=device).fit(Xb, y)
    with pytest.raises(ValueError, match="device="):
        tiny_residual(Est, device=device).partial_fit(Xb, y)
    assert not prepared
    monkeypatch.undo()
    est = copy.deepcopy(fitted(Est)[0]).set_params(device=device)
    with pytest.raises(ValueError, match=r"the devices available are"):
        est.predict(Xb)
    with pytest.raises(ValueError, match="cannot compute there"):
        tiny_residual(Est, device="nowhere").fit(Xb, y)
    assert "cpu" in _estimators.available_devices()


def test_on_cpu_copies_only_when_needed():
    module = _seeded(MODULES[0])
    assert on_cpu(module, torch.float32) is module
    double = on_cpu(module, torch.float64)
    assert double is not module
    assert {p.dtype for p in double.parameters()} == {torch.float64}
    assert {p.dtype for p in module.parameters()} == {torch.float32}


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("Est", LEARNERS)
def test_learner_trained_on_a_gpu(Est, small, fitted):
    _, Xb, y = small
    est = tiny_residual(Est, device="cuda").fit(Xb, y)
    assert next(est.module_.parameters()).device.type == "cuda"
    pred = est.predict(Xb)
    assert np.isfinite(pred).all()
    # the context is encoded on a CPU copy of the encoder, as predict encodes it
    z = est.encode_context(Xb)
    assert next(est.module_.parameters()).device.type == "cuda"
    cpu = copy.deepcopy(est)
    cpu.module_.to("cpu")
    cpu.device = "cpu"
    assert_array_equal(cpu.encode_context(Xb), z)
    # the GPU's kernels may round as TF32 (1e-3 relative)
    assert_allclose(cpu.predict(Xb), pred, rtol=0, atol=1e-2)


@pytest.mark.parametrize("Est", LEARNERS)
def test_methods_a_regressor_does_not_offer(Est, small, fitted):
    _, Xb, _ = small
    est, _ = fitted(Est)
    assert not hasattr(est, "predict_proba")
    assert not hasattr(Est(), "predict_proba")
    with pytest.raises(AttributeError, match="it is a regressor of tip positions. Use predict"):
        est.predict_proba(Xb)
    for method in (est.forward, lambda X: list(est.forward_iter(X)), est.get_dataset):
        with pytest.raises(TypeError, match=r"not DataFrame. Use .*\.predict for tip"):
            method(Xb)
    with pytest.raises(TypeError, match="not ndarray"):
        est.forward(np.zeros((4, 9), dtype=np.float32))


# ---------------------------------------------------------------------------
# NoResidual
# ---------------------------------------------------------------------------
def test_no_residual_returns_the_backbone(small):
    X, Xb, y = small
    est = NoResidual()
    assert est.fit(Xb) is est
    assert_array_equal(est.predict(Xb), Xb[B].to_numpy())
    assert_array_equal(NoResidual().fit(Xb, y).predict(Xb), Xb[B].to_numpy())
    assert est.n_features_in_ == Xb.shape[1]
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())]).fit(X, y)
    assert_array_equal(pipe.predict(X), PDLBackbone().fit(X).predict(X))
    assert est.score(Xb, y) == pytest.approx(-mean_per_run_rmse(y, Xb[B].to_numpy(), Xb))
    with pytest.raises(ValueError, match="rows"):
        NoResidual().fit(Xb, y[:-1])


# ---------------------------------------------------------------------------
# composition
# ---------------------------------------------------------------------------
def test_cross_validate_with_groups(small):
    X, _, y = small
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", tiny_residual(GRUResidual))])
    cv = GroupKFold(2)
    out = cross_validate(pipe, X, y, groups=X["setting"], cv=cv, scoring=run_rmse_scorer)
    assert out["test_score"].shape == (2,)
    # each score is the negated mean per-run RMSE on the held-out settings of a
    # fit on the other settings, as a hand-written fold loop computes it
    for score, (train, test) in zip(out["test_score"], cv.split(X, y, X["setting"])):
        assert not set(X["setting"].iloc[train]) & set(X["setting"].iloc[test])
        fold = clone(pipe).fit(X.iloc[train], y[train])
        expected = mean_per_run_rmse(y[test], fold.predict(X.iloc[test]), X.iloc[test])
        assert score == pytest.approx(-expected, rel=1e-12)
    # better than a constant, the mean tip of the training settings, in every
    # fold and by 30 % on average (measured: 6.7 and 6.9 mm against 8.2 and 14.7)
    constant = cross_validate(
        DummyRegressor(), X, y, groups=X["setting"], cv=cv, scoring=run_rmse_scorer
    )["test_score"]
    assert (out["test_score"] > constant).all()
    assert -out["test_score"].mean() <= 0.7 * -constant.mean()


def test_grid_search_over_backbones_and_residuals(small):
    """The issue's grid: PCC/PDL x none/MLP/GRU, whole settings held out."""
    X, _, y = small
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())])
    grid = {
        "backbone": [PCCBackbone(), PDLBackbone()],
        "residual": [NoResidual(), tiny_residual(MLPResidual), tiny_residual(GRUResidual)],
    }
    search = GridSearchCV(pipe, grid, cv=GroupKFold(2), scoring=run_rmse_scorer)
    search.fit(X, y, groups=X["setting"])
    assert len(search.cv_results_["params"]) == 6
    scores = search.cv_results_["mean_test_score"]
    assert np.isfinite(scores).all() and (scores < 0).all()
    names = [
        (type(p["backbone"]).__name__, type(p["residual"]).__name__)
        for p in search.cv_results_["params"]
    ]
    assert names == [
        (b, r)
        for b in ("PCCBackbone", "PDLBackbone")
        for r in ("NoResidual", "MLPResidual", "GRUResidual")
    ]
    # the baselines in the grid score exactly as the backbones alone
    by_name = dict(zip(names, scores))
    assert by_name[("PCCBackbone", "NoResidual")] != by_name[("PDLBackbone", "NoResidual")]
    assert search.best_estimator_.predict(X).shape == (len(X), 3)


def test_grid_search_over_nested_learner_parameters(small):
    """Ablation switches and module parameters are grid parameters."""
    X, _, y = small
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", tiny_residual(GRUResidual))])
    grid = {"residual__use_context": [True, False], "residual__module__hidden_size": [4, 6]}
    search = GridSearchCV(pipe, grid, cv=GroupKFold(2), scoring=run_rmse_scorer).fit(
        X, y, groups=X["setting"]
    )
    assert len(search.cv_results_["params"]) == 4
    best = search.best_estimator_["residual"]
    assert best.module_.gru.hidden_size == search.best_params_["residual__module__hidden_size"]
    assert best.module_.use_context == search.best_params_["residual__use_context"]


# ---------------------------------------------------------------------------
# the learned residual helps
# ---------------------------------------------------------------------------
def test_gru_beats_its_backbone_on_held_out_settings(bench, transformed):
    # train on 12 bent settings, test on the runs of 4 others (2 low, 2 high)
    X, y = bench.X, bench.y
    setting = X["setting"].astype(str)
    held_out = ["S04", "S08", "S12", "S16"]
    test = setting.isin(held_out).to_numpy()
    train = ~test & (setting != "S00").to_numpy()
    assert setting[train].nunique() == 12
    est = GRUResidual(
        lr=3e-3,
        max_epochs=8,
        batch_size=32,
        window_s=10.0,
        burn_in_s=2.0,
        random_state=0,
        n_threads=1,
    )
    est.fit(transformed[train], y[train])
    backbone = per_run_rmse(y[test], transformed.loc[test, B].to_numpy(), X[test])
    learned = per_run_rmse(y[test], est.predict(transformed[test]), X[test])
    assert len(learned) == 4
    # every held-out run is better (about 0.7-0.8 of the backbone's error)
    assert (learned < 0.95 * backbone).all(), (learned / backbone).to_dict()
    assert learned.mean() < 0.9 * backbone.mean(), (learned.mean(), backbone.mean())


# ---------------------------------------------------------------------------
# one, two and three motors, with and without torques
# ---------------------------------------------------------------------------
def test_feature_names_for_any_number_of_motors():
    assert step_feature_names() == ("q1", "q2", "dq1", "dq2", "tau1", "tau2", *B)
    assert step_feature_names(True, 1) == ("q1", "dq1", "tau1", *B)
    assert step_feature_names(False, 3) == ("q1", "q2", "q3", "dq1", "dq2", "dq3", *B)
    assert len(step_feature_names(True, 3)) == 3 * 3 + 3
    assert sweep_feature_names(True, 3) == ("q1", "q2", "q3", "tau1", "tau2", "tau3")
    assert sweep_feature_names(False, 1) == ("q1",)


@pytest.fixture(scope="module")
def motors():
    """Lazily built (Xb, y) of the settings of ``small`` on the simulated instrument of ``n``
    motors (shortened as ``small``), polynomial backbone."""
    cache = {}

    def get(n_motors, torques=True):
        if (n_motors, torques) not in cache:
            Xn, y = instrument(n_motors, SMALL_SETTINGS, N_MOTION, torques=torques)
            cache[n_motors, torques] = (PolynomialBackbone().fit(Xn).transform(Xn), y)
        return cache[n_motors, torques]

    return get


@pytest.mark.parametrize("Est", LEARNERS)
@pytest.mark.parametrize("n_motors, torques", [(1, True), (3, True), (3, False), (1, False)])
def test_learners_fit_any_number_of_motors(motors, Est, n_motors, torques):
    Xb, y = motors(n_motors, torques)
    est = tiny_residual(Est, use_torque=torques).fit(Xb, y)
    assert est.n_motors_ == n_motors
    width = (3 if torques else 2) * n_motors + 3
    assert est.x_scaler_.mean.shape == (width,)
    assert est.s_scaler_.mean.shape == ((2 if torques else 1) * n_motors,)
    F, _, _ = feature_frame(Xb)
    assert_allclose(est.x_scaler_.mean[n_motors:2 * n_motors],
                    F.loc[_motion(Xb), [f"dq{k}" for k in range(1, n_motors + 1)]].mean(), rtol=1e-9,
                    atol=1e-12)
    pred = est.predict(Xb)
    assert pred.shape == (len(Xb), 3) and np.isfinite(pred).all()
    # sweep rows keep the backbone, motion rows are corrected
    b = Xb[B].to_numpy()
    assert_array_equal(pred[~_motion(Xb)], b[~_motion(Xb)])
    assert np.abs(pred[_motion(Xb)] - b[_motion(Xb)]).max() > 0
    # reproducible, and a clone refits to the same predictions
    assert_array_equal(clone(est).fit(Xb, y).predict(Xb), pred)
    # pickled, the network keeps its input size
    assert_array_equal(pickle.loads(pickle.dumps(est)).predict(Xb), pred)
    if torques:
        assert est.encode_context(Xb).shape == (3, 4)


def test_a_third_motor_changes_the_prediction(motors):
    """The network reads the third motor: changing q3 on motion rows changes the residual."""
    Xb, y = motors(3)
    est = tiny_residual(GRUResidual).fit(Xb, y)
    moved = Xb.copy()
    moved.loc[_motion(Xb), "q3"] += 5.0
    assert np.abs(est.predict_residual(moved) - est.predict_residual(Xb)).max() > 1e-4


def test_partial_fit_and_pretrained_keep_the_number_of_motors(motors):
    Xb3, y = motors(3)
    Xb1, y1 = motors(1)
    est = tiny_residual(MLPResidual).fit(Xb3, y)
    with pytest.raises(ValueError, match=r"fitted on recordings of 3 motor\(s\).*X has 1"):
        est.partial_fit(Xb1, y1)
    with pytest.raises(ValueError, match=r"pretrained was fitted on recordings of 3 motor\(s\) "
                       r"but X has 1"):
        tiny_residual(MLPResidual, pretrained=FrozenEstimator(est)).fit(Xb1, y1)
    tuned = tiny_residual(MLPResidual, pretrained=FrozenEstimator(est)).fit(Xb3, y)
    assert tuned.n_motors_ == 3
