"""The width grids' PDL calibrations solved in one batch equal those solved one by one, bit for bit.

``_calibrate_pdl_batch`` against ``calibrate_pdl`` on each played sweep
(rays of different lengths, rows lost); the play's and the PI's width
searches of a backbone with the grid batched against the same searches
with every grid width calibrated in turn; the grid callable of
``identify_play_width`` is asked for the grid and its answer checked.
"""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from skcath.backbones import PDLBackbone, identify_play_width, play_operator
from skcath.backbones._pdl import calibrate_pdl
from skcath.backbones._pdl_batch import _calibrate_pdl_batch
from skcath.datasets import simulate_run
from skcath.sweep import find_rays


def _assert_identical(a, b):
    params_a, info_a = a
    params_b, info_b = b
    for name in ("coef", "p0", "basis", "q_neutral", "directions"):
        assert_array_equal(getattr(params_a, name), getattr(params_b, name), strict=True)
    assert params_a.rho0 == params_b.rho0
    assert info_a.keys() == info_b.keys()
    for key in info_a:
        assert_array_equal(info_a[key], info_b[key], strict=True)


@pytest.fixture(scope="module")
def recording():
    """A simulated hysteretic run (all its rows)."""
    return simulate_run(random_state=3).X


@pytest.mark.parametrize("max_iter", [8, 100])
def test_batch_equals_each_calibration_alone(recording, max_iter):
    X = recording[recording["phase"] == "sweep"]
    q, p = X[["q1", "q2"]].to_numpy(), X[["ref_x", "ref_y", "ref_z"]].to_numpy().copy()
    rays = find_rays(q, n_rays=8)
    p[np.random.default_rng(0).random(len(p)) < 0.3] = np.nan  # rays of different lengths
    qs = [play_operator(q, width) for width in (0.0, 2.0, 7.5, 14.0, 20.0)]
    args = (p, rays.labels, rays.directions, rays.neutral)
    batch = _calibrate_pdl_batch(qs, *args, q_neutral=rays.q_neutral, max_iter=max_iter)
    alone = [calibrate_pdl(z, *args, q_neutral=rays.q_neutral, max_iter=max_iter, return_info=True)
             for z in qs]
    assert len(batch) == len(qs)
    for a, b in zip(batch, alone):
        _assert_identical(a, b)
    # the widths' own rho0 (half their largest rho) differ, so each ray kept its calibration's
    assert len({params.rho0 for params, _ in batch}) == len(qs)
    assert _calibrate_pdl_batch([], *args) == []


def _one_by_one(self, qs, ref, rays, q_raw):
    return [self._calibrate(q, ref, rays, q_raw) for q in qs]


@pytest.mark.parametrize("hysteresis", ["play", "pi"])
def test_batched_grid_equals_the_sequential_grid(recording, hysteresis, monkeypatch):
    batched = PDLBackbone(hysteresis=hysteresis).fit(recording).calibrate(recording)
    monkeypatch.setattr(PDLBackbone, "_calibrate_many", _one_by_one)
    sequential = PDLBackbone(hysteresis=hysteresis).fit(recording).calibrate(recording)
    assert batched.table.equals(sequential.table)
    assert_array_equal(batched.nominal, sequential.nominal, strict=True)
    assert batched.play_widths == sequential.play_widths
    (run,) = batched.params
    for name in ("coef", "p0", "basis", "q_neutral", "directions"):
        assert_array_equal(getattr(batched.params[run], name), getattr(sequential.params[run], name),
                           strict=True)


def test_grid_callable_is_asked_for_the_grid():
    asked = []

    def cost(w):
        return (w - 7.3) ** 2

    def grid(widths):
        asked.append(list(widths))
        return [cost(w) for w in widths]

    assert identify_play_width(cost, 20.0, grid) == identify_play_width(cost, 20.0)
    assert asked == [[2.0 * k for k in range(11)]]
    with pytest.raises(ValueError, match="grid_rmse must return one RMSE"):
        identify_play_width(cost, 20.0, lambda widths: [0.0])
