"""Tests of skcath.datasets: recording protocol, simulated runs, the benchmark.

The default benchmark (204 runs, about 1.25 million samples) is generated once
per test session into a temporary cache folder and shared by the tests that
need it; everything else uses single runs or one-catheter benchmarks.
"""

import dataclasses
import logging

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation
from sklearn.utils import Bunch

from skcath._validation import check_recordings
from skcath.datasets import (
    SIMULATOR_VERSION,
    Catheter,
    benchmark_catheter,
    clear_data_home,
    get_data_home,
    make_benchmark,
    sample_catheter,
    setting_parameters,
    shaft_settings,
    simulate_run,
)
from skcath.datasets import _benchmark, _cache
from skcath.datasets._protocol import (
    constant_speed,
    min_jerk,
    random_walk_trajectory,
    run_protocol,
    sweep_trajectory,
)
from skcath.datasets._simulator import _transmission_params

ID_COLUMNS = ["catheter", "setting", "run"]
REF_COLUMNS = ["ref_x", "ref_y", "ref_z"]
AMPLITUDE = 60.0
REST = 30  # samples at neutral before the first ray
DWELL_IN = 25  # samples at neutral after each ray's return
RAMP_FRACTION = 0.1  # share of each sweep move spent accelerating (and decelerating)


@pytest.fixture(autouse=True)
def _isolated_data_home(tmp_path, monkeypatch):
    """Keep every cache this module may write out of the user's home."""
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "default_home"))


def _assert_same_data(a, b):
    """Assert that two simulated bunches hold identical recordings.

    Parameters
    ----------
    a, b : sklearn.utils.Bunch
        Outputs of :func:`simulate_run` or :func:`make_benchmark`.
    """
    pd.testing.assert_frame_equal(a.X, b.X, check_exact=True)
    assert_array_equal(a.y, b.y)
    assert_array_equal(a.y_true, b.y_true)
    pd.testing.assert_frame_equal(a.sensors, b.sensors, check_exact=True)
    pd.testing.assert_frame_equal(a.runs, b.runs, check_exact=True)
    assert a.noise_floor == b.noise_floor


def _plain_ids(X):
    """``X`` with id and phase columns as strings and a fresh index."""
    cols = [*ID_COLUMNS, "phase"]
    return X.astype({c: str for c in cols}).reset_index(drop=True)


# ---------------------------------------------------------------------------
# protocol
# ---------------------------------------------------------------------------
def _rays(q):
    """Split a sweep into its excursions from neutral.

    Parameters
    ----------
    q : ndarray of shape (n, 2)
        Sweep motor angles (deg).

    Returns
    -------
    rays : list of ndarray of int
        Sample indices of each maximal run of non-neutral samples.
    """
    moving = np.any(q != 0.0, axis=1).astype(int)
    edges = np.flatnonzero(np.diff(np.r_[0, moving, 0]))
    return [np.arange(start, stop) for start, stop in zip(edges[::2], edges[1::2])]


def _check_sweep(q, amplitude=AMPLITUDE):
    """Assert the structure of an 8-ray outward-and-return sweep from neutral.

    Each ray leaves neutral, runs out to ``amplitude`` at constant speed
    (trapezoidal profile), turns back at once and returns along the same
    motor angles; ``DWELL_IN`` samples at exactly neutral follow each return,
    after ``REST`` samples at neutral before the first ray.

    Returns
    -------
    n_move : int
        Number of samples of each outward (and each return) move.
    """
    assert_array_equal(q[:REST], 0.0)
    assert_array_equal(q[-1], [0.0, 0.0])
    rays = _rays(q)
    assert len(rays) == 8
    assert rays[0][0] == REST
    n_moves = set()
    for k, idx in enumerate(rays):
        # exactly neutral before and after each ray: the return's last sample,
        # then the dwell
        assert_array_equal(q[idx[0] - 1], [0.0, 0.0])
        assert_array_equal(q[idx[-1] + 1], [0.0, 0.0])
        next_start = rays[k + 1][0] if k < 7 else len(q)
        assert next_start - idx[-1] - 1 == DWELL_IN + 1
        rho = np.hypot(q[idx, 0], q[idx, 1])
        psi = np.deg2rad(45.0 * k)
        # every sample lies on the ray at 45 k degrees
        assert np.allclose(q[idx], rho[:, None] * [np.cos(psi), np.sin(psi)], atol=1e-9)
        assert rho.max() == pytest.approx(amplitude, abs=1e-9)
        peak = np.flatnonzero(np.isclose(rho, amplitude, atol=1e-9))
        # out, and straight back: no dwell at the end of the ray
        assert len(peak) == 1
        out, back = np.r_[0.0, rho[: peak[0] + 1]], np.r_[rho[peak[0] :], 0.0]
        assert np.all(np.diff(out) > 0)
        assert np.all(np.diff(back) < 0)
        # the return visits the outward motor angles in reverse
        assert len(out) == len(back)
        assert np.allclose(back[::-1], out, atol=1e-9)
        # constant speed between short linear ramps: the cruise speed is the
        # mean speed / (1 - ramp fraction), held over 80 % of the move
        n_move = len(out) - 1
        n_moves.add(n_move)
        step = np.diff(out)
        cruise = amplitude / (n_move * (1.0 - RAMP_FRACTION))
        assert step.max() == pytest.approx(cruise, rel=1e-9)
        at_cruise = np.isclose(step, cruise, rtol=1e-9, atol=0)
        assert abs(at_cruise.mean() - (1 - 2 * RAMP_FRACTION)) <= 2.0 / n_move
    assert len(n_moves) == 1
    return n_moves.pop()


def test_constant_speed_profile():
    for n in (1, 2, 7, 250):
        s = constant_speed(n)
        assert s.shape == (n,)
        assert s[-1] == 1.0
        assert np.all(np.diff(np.r_[0.0, s]) > 0)
    n = 250
    s = constant_speed(n)
    # symmetric about the midpoint
    assert np.allclose(s[:-1] + s[::-1][1:], 1.0, atol=1e-12)
    step = np.diff(np.r_[0.0, s])
    cruise = 1.0 / (n * (1.0 - RAMP_FRACTION))
    assert step.max() == pytest.approx(cruise, rel=1e-12)
    assert np.isclose(step, cruise, rtol=1e-9, atol=0).sum() == pytest.approx(0.8 * n, abs=2)
    # constant acceleration over the first 10 % of the move, from rest
    n_ramp = int(RAMP_FRACTION * n) - 1
    assert_allclose(np.diff(step[:n_ramp]), cruise / (RAMP_FRACTION * n), rtol=1e-9)
    assert step[0] == pytest.approx(0.5 * cruise / (RAMP_FRACTION * n), rel=1e-9)
    assert_allclose(step[::-1][:n_ramp], step[:n_ramp], rtol=1e-9)


def test_min_jerk_profile():
    for n in (1, 2, 7, 250):
        s = min_jerk(n)
        assert s.shape == (n,)
        assert s[-1] == 1.0
        assert np.all(s > 0)
        assert np.all(np.diff(s) > 0)
    s = min_jerk(200)
    tau = np.arange(1, 201) / 200
    # symmetric about the midpoint, with zero slope at both ends
    assert np.allclose(s[:-1] + s[::-1][1:], 1.0, atol=1e-12)
    assert s[0] < 1e-5 and 1 - s[-2] < 1e-5
    assert s[99] == pytest.approx(0.5)
    assert np.all(np.abs(np.diff(s)) <= 1.875 / 200 + 1e-12)  # peak speed 15/8
    assert np.allclose(s, 10 * tau**3 - 15 * tau**4 + 6 * tau**5)


def test_sweep_trajectory_rays():
    q = sweep_trajectory()
    assert _check_sweep(q) == 250
    # 30 rest samples, then 8 x (250 out + 250 back + 25 dwell) at 2.4 deg/s
    assert len(q) == REST + 8 * (250 + 250 + DWELL_IN)
    # the first ray is the constant-speed profile along +q1
    first_ray = AMPLITUDE * constant_speed(250)[:, None] * [1.0, 0.0]
    assert_allclose(q[REST : REST + 250], first_ray, rtol=0, atol=1e-12)
    q = sweep_trajectory(amplitude_deg=40.0, n_rays=8)
    assert _check_sweep(q, amplitude=40.0) == 167
    # a dwell at the ray's end is still available
    q = sweep_trajectory(dwell_out_s=1.5)
    rho = np.hypot(q[:, 0], q[:, 1])
    assert np.isclose(rho, AMPLITUDE, atol=1e-9).sum() == 8 * 16


@pytest.mark.parametrize("seed", range(6))
def test_run_protocol_sweep_then_random_walk(seed):
    q, n_sweep = run_protocol(np.random.default_rng(seed))
    assert 6000 <= len(q) <= 6300
    assert q.shape == (len(q), 2)
    n_move = _check_sweep(q[:n_sweep])
    assert n_sweep == REST + 8 * (2 * n_move + DWELL_IN)
    # the sweep speed varies by at most 3 % around 2.4 deg/s
    assert round(600 / (2.4 * 1.03)) <= n_move <= round(600 / (2.4 * 0.97))
    motion = q[n_sweep:]
    rho = np.hypot(motion[:, 0], motion[:, 1])
    assert rho.max() <= AMPLITUDE + 1e-9
    assert rho.max() > 0.8 * AMPLITUDE  # the walk explores the workspace
    # the walk starts from neutral and moves continuously
    assert np.hypot(*motion[0]) < 1.0
    assert np.abs(np.diff(q, axis=0)).max() < 20.0


def test_run_protocol_sweep_speed_varies():
    protocols = (run_protocol(np.random.default_rng(seed)) for seed in range(12))
    n_moves = {_check_sweep(q[:n_sweep]) for q, n_sweep in protocols}
    assert len(n_moves) > 3


def test_run_protocol_lengths_cover_range():
    lengths = [len(run_protocol(np.random.default_rng(s))[0]) for s in range(40)]
    assert min(lengths) >= 6000 and max(lengths) <= 6300
    assert len(set(lengths)) > 20


def test_run_protocol_rejects_short_runs():
    with pytest.raises(ValueError, match="n_samples_range"):
        run_protocol(np.random.default_rng(0), n_samples_range=(4500, 4600))


@pytest.mark.parametrize("n_samples", [100, 101, 137, 1000, 1777, 2100])
def test_random_walk_length_exact_and_inside_disk(n_samples):
    rng = np.random.default_rng(n_samples)
    q = random_walk_trajectory(rng, n_samples, radius_deg=AMPLITUDE, start=(10.0, -5.0))
    assert q.shape == (n_samples, 2)
    assert np.hypot(q[:, 0], q[:, 1]).max() <= AMPLITUDE + 1e-9
    assert np.all(np.isfinite(q))


def test_random_walk_moves_with_minimum_jerk():
    # A one-step walk is a single minimum-jerk move to its (reflected) target.
    start = np.array([10.0, -5.0])
    for seed in range(5):
        q = random_walk_trajectory(np.random.default_rng(seed), 137, n_steps=1, start=start)
        target = q[-1]
        assert np.hypot(*target) <= AMPLITUDE + 1e-9
        assert np.hypot(*(target - start)) > 1.0
        assert_allclose(q, start + (target - start) * min_jerk(137)[:, None], rtol=0, atol=1e-9)


def test_random_walk_rejects_too_few_samples():
    with pytest.raises(ValueError, match="n_samples"):
        random_walk_trajectory(np.random.default_rng(0), 99)


# ---------------------------------------------------------------------------
# one simulated run
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run0():
    """One run with the default catheter draw, setting and mechanism, seed 0."""
    return simulate_run(random_state=0)


def test_simulate_run_is_deterministic(run0):
    _assert_same_data(run0, simulate_run(random_state=0))
    _assert_same_data(
        simulate_run(random_state=np.random.default_rng(5)),
        simulate_run(random_state=np.random.default_rng(5)),
    )


def test_simulate_run_seeds_differ(run0):
    other = simulate_run(random_state=1)
    n = min(len(run0.y), len(other.y))
    assert not np.allclose(run0.y_true[:n], other.y_true[:n])
    assert not np.array_equal(run0.X["tau1"].to_numpy()[:n], other.X["tau1"].to_numpy()[:n])


def test_simulate_run_passes_format_checks(run0):
    X, y = check_recordings(run0.X, run0.y)
    assert len(X) == len(y) == run0.runs.loc[0, "n_samples"]
    assert 6000 <= len(X) <= 6300
    assert y.shape == run0.y_true.shape == (len(X), 3)
    assert len(run0.sensors) == len(X)
    assert set(X["run"]) == {"run-0"}
    assert np.all(np.isfinite(run0.y)) and np.all(np.isfinite(run0.y_true))
    # torques are quantised to the drive's 0.5 N mm step
    tau = X[["tau1", "tau2"]].to_numpy()
    assert_array_equal(tau / 0.5, np.round(tau / 0.5))


def test_reference_columns_are_the_sweep_targets(run0):
    X = run0.X
    sweep = (X["phase"] == "sweep").to_numpy()
    assert sweep.sum() == run0.runs.loc[0, "n_sweep"]
    assert np.all(sweep[: sweep.sum()]) and not np.any(sweep[sweep.sum() :])
    ref = X[REF_COLUMNS].to_numpy()
    assert_array_equal(ref[sweep], run0.y[sweep])
    assert np.all(np.isnan(ref[~sweep]))


def test_simulate_run_accepts_setting_objects_and_catheters():
    cat = sample_catheter(3, "C7")
    setting = shaft_settings()[12]
    a = simulate_run(cat, setting, random_state=2, run="r")
    b = simulate_run(cat, setting.name, random_state=2, run="r")
    _assert_same_data(a, b)
    assert a.runs.loc[0, "catheter"] == "C7"
    assert a.runs.loc[0, "setting"] == setting.name
    assert a.runs.loc[0, "bend_level"] == setting.level == "high"


def test_noise_free_tip_stays_within_reach():
    # Back in the kinematic frame, the tip is never farther than section + tip.
    cat = sample_catheter(11, "C1")
    data = simulate_run(cat, "S09", random_state=4, field=False)
    p_k = Rotation.from_rotvec(cat.mount_rotvec).inv().apply(data.y_true) + cat.mount_position
    reach = np.linalg.norm(p_k, axis=1)
    assert reach.max() <= cat.length + cat.tip_length + 1e-9
    assert reach.min() > 0.5 * (cat.length + cat.tip_length)


@pytest.mark.parametrize("dropout_rate", [0.05, 0.3])
def test_dropouts_give_nan_targets(run0, dropout_rate):
    data = simulate_run(random_state=0, dropout_rate=dropout_rate)
    lost = np.isnan(data.y).any(axis=1)
    assert np.all(np.isnan(data.y[lost]))
    assert abs(lost.mean() - dropout_rate) < 0.03
    tip_cols = ["tip_px", "tip_py", "tip_pz", "tip_qw", "tip_qx", "tip_qy", "tip_qz"]
    assert_array_equal(data.sensors[tip_cols].isna().all(axis=1).to_numpy(), lost)
    sweep = (data.X["phase"] == "sweep").to_numpy()
    ref = data.X[REF_COLUMNS].to_numpy()
    assert np.all(np.isnan(ref[lost & sweep]))
    assert_array_equal(ref[sweep & ~lost], data.y[sweep & ~lost])
    check_recordings(data.X, data.y)
    # a dropout only hides samples: the same seed gives the same motion and tip
    assert_array_equal(data.y_true, run0.y_true)
    pd.testing.assert_frame_equal(
        data.X.drop(columns=REF_COLUMNS), run0.X.drop(columns=REF_COLUMNS), check_exact=True
    )
    assert_array_equal(data.y[~lost], run0.y[~lost])
    assert np.isfinite(data.noise_floor)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"setting": "S17"}, "setting"),
        ({"setting": "straight"}, "setting"),
        ({"random_state": -1}, "random_state"),
        ({"random_state": 1.5}, "random_state"),
        ({"random_state": "0"}, "random_state"),
        ({"mechanism": "x"}, "mechanism"),
        ({"dropout_rate": 1.0}, "dropout_rate"),
        ({"dropout_rate": -0.1}, "dropout_rate"),
    ],
)
def test_simulate_run_rejects_bad_arguments(kwargs, name):
    with pytest.raises(ValueError, match=name):
        simulate_run(**kwargs)


def test_sample_catheter_transmission_parameters():
    cats = [sample_catheter(seed, f"C{seed}") for seed in range(100)]
    fields = {f.name for f in dataclasses.fields(Catheter)}
    params = cats[0].to_dict()
    assert set(params) == fields
    assert isinstance(params["route_phases"], list) and len(params["route_phases"]) == 3
    assert sample_catheter(5, "C5").to_dict() == cats[5].to_dict()

    def drawn(name):
        values = np.array([getattr(c, name) for c in cats], dtype=float)
        assert np.all(np.isfinite(values))
        assert values.std(axis=0).min() > 0, name  # varies from unit to unit
        return values

    # shares and gains that keep the transmission physical
    assert np.all((drawn("cross_load") > 0) & (drawn("cross_load") < 1))
    # the per-pair wraps Theta (1 +- wrap_routing) stay positive
    assert np.all((drawn("wrap_routing") >= 0) & (drawn("wrap_routing") < 1))
    assert np.all((drawn("slow_creep_gain") > 0) & (drawn("slow_creep_gain") < 0.5))
    assert np.all(drawn("slow_creep_tau") > 1.0)  # slow: seconds, not samples
    assert np.all((drawn("tip_lag") > 0) & (drawn("tip_lag") < 1.0))
    assert np.all((drawn("windup") > 0) & (drawn("windup") < np.deg2rad(10.0)))
    assert np.all(drawn("play_growth_base") > 0)
    assert np.all(drawn("route_a1") >= 0) and np.all(drawn("route_shift") > 0)
    drawn("route_a3")  # finite, and varies from unit to unit
    assert np.all(np.abs(drawn("route_phases")) <= np.pi)
    assert np.all(np.abs(drawn("route_b3")) < 1)  # the routing never flips the bend


def test_no_load_play_width_follows_each_pair_wrap():
    # Simulator version 5: the pretension presses each tendon on its sheath
    # along the whole wrap, so the no-load play of a pair grows with its own
    # wrap; play_w0 is the width at one radian of wrap.
    settings = {s.name: s for s in shaft_settings()}
    for seed in range(5):
        cat = sample_catheter(seed)
        w0 = {name: np.asarray(setting_parameters(cat, s)["w0"], dtype=float) for name, s in settings.items()}
        assert all(w.shape == (2,) for w in w0.values())
        assert np.all(np.concatenate(list(w0.values())) > 0)
        # straight: both pairs alike, below the width at one radian (30 deg of wrap)
        assert w0["S00"][0] == w0["S00"][1]
        assert 0 < w0["S00"][0] < cat.play_w0
        # the pair whose plane holds the shaft bend (S01/S09 along +x, pair 1;
        # S03/S11 along +y, pair 2) has the wider play; at 45 deg both alike
        for name, bent_axis in (("S01", 0), ("S03", 1), ("S09", 0), ("S11", 1)):
            assert w0[name][bent_axis] > w0[name][1 - bent_axis] > w0["S00"][0], name
        for name in ("S02", "S10"):
            assert w0[name][0] == pytest.approx(w0[name][1], rel=1e-12)
        # a high bend widens both pairs beyond the same direction at low bend
        for low in range(1, 9):
            assert np.all(w0[f"S{low + 8:02d}"] > w0[f"S{low:02d}"])
        # linear in the wrap: the width grows by the same amount per radian
        # for both pairs of a setting, and play_w0 is the width at 1 rad
        for name in ("S01", "S09", "S11"):
            beta = np.deg2rad(settings[name].direction_deg)
            wrap = settings[name].wrap * (1 + cat.wrap_routing * np.cos(2 * (beta - np.array([0.0, np.pi / 2]))))
            slope = np.diff(w0[name])[0] / np.diff(wrap)[0]
            assert w0[name] - slope * (wrap - 1.0) == pytest.approx(np.full(2, cat.play_w0), rel=1e-9)


def test_transmission_receives_the_per_pair_play_width():
    specs = _benchmark.benchmark_specs([benchmark_catheter(1)], 1, 0, False)
    configs = [setting_parameters(spec.catheter, spec.setting) for spec in specs]
    params = _transmission_params(specs, configs)
    assert params["w0"].shape == (len(specs), 2)
    assert_array_equal(params["w0"], np.array([c["w0"] for c in configs]))
    # the two pairs differ whenever the shaft is bent along a motor axis
    along_axis = np.array([s.setting.bend_deg > 0 and s.setting.direction_deg % 90 == 0 for s in specs])
    assert along_axis.sum() == 8
    assert np.all(params["w0"][along_axis, 0] != params["w0"][along_axis, 1])
    assert_allclose(params["w0"][~along_axis, 0], params["w0"][~along_axis, 1], rtol=1e-12)


# ---------------------------------------------------------------------------
# noise floor
# ---------------------------------------------------------------------------
def test_noise_floor_is_motion_rms_error(run0):
    motion = (run0.X["phase"] == "motion").to_numpy()
    err = np.linalg.norm(run0.y[motion] - run0.y_true[motion], axis=1)
    rms = np.sqrt(np.mean(err**2))
    assert run0.noise_floor == pytest.approx(rms, rel=1e-12)
    assert run0.runs.loc[0, "noise_floor_mm"] == pytest.approx(rms, rel=1e-12)
    assert 0.1 < run0.noise_floor < 1.5  # measured: 0.60 mm
    # the tracker makes the measured tip differ from the true one, by < a few mm
    all_err = np.linalg.norm(run0.y - run0.y_true, axis=1)
    assert np.all(all_err > 0)
    assert all_err.max() < 4.0


@pytest.mark.parametrize("seed", [0, 3])
def test_undistorted_noise_floor_matches_sensor_jitter(seed):
    # Without field distortion the floor follows from the sensor figures:
    # 0.15 mm per coordinate on both sensors, and the base orientation jitter
    # (0.2 deg per axis) swinging the tip vector: E|w x p|^2 = 2 sigma^2 |p|^2.
    data = simulate_run(random_state=seed, field=False)
    motion = (data.X["phase"] == "motion").to_numpy()
    mean_sq_reach = np.mean(np.sum(data.y_true[motion] ** 2, axis=1))
    predicted = np.sqrt(2 * 3 * 0.15**2 + 2 * np.deg2rad(0.2) ** 2 * mean_sq_reach)
    assert data.noise_floor == pytest.approx(predicted, rel=0.1)


# ---------------------------------------------------------------------------
# the default benchmark, generated once per session
# ---------------------------------------------------------------------------
@pytest.fixture(scope="session")
def benchmark_home(tmp_path_factory):
    """Cache folder that holds the session's default benchmark."""
    return tmp_path_factory.mktemp("skcath_benchmark_cache")


@pytest.fixture(scope="session")
def default_benchmark(benchmark_home):
    """The default benchmark (4 catheters x 17 settings x 3 runs), cached."""
    return make_benchmark(cache=True, data_home=benchmark_home)


@pytest.fixture(scope="module")
def small_benchmark():
    """One catheter in all 17 settings, one run each, seed 0, not cached."""
    return make_benchmark(n_catheters=1, n_runs=1, cache=False)


def test_default_benchmark_layout(default_benchmark):
    data = default_benchmark
    X, runs = data.X, data.runs
    assert len(runs) == 204
    assert runs["run"].is_unique
    assert sorted(X["catheter"].unique()) == ["C1", "C2", "C3", "C4"]
    assert sorted(X["setting"].unique()) == [f"S{k:02d}" for k in range(17)]
    assert X["run"].nunique() == 204
    per_cell = runs.groupby(["catheter", "setting"]).size()
    assert len(per_cell) == 4 * 17 and (per_cell == 3).all()
    assert sorted(runs["repeat"].unique()) == [1, 2, 3]
    assert runs["bend_level"].value_counts().to_dict() == {"low": 96, "high": 96, "straight": 12}
    sizes = X.groupby("run", observed=True).size()
    assert sizes.between(6000, 6300).all()
    assert set(data.catheters) == {"C1", "C2", "C3", "C4"}
    fields = {f.name for f in dataclasses.fields(Catheter)}
    assert all(set(params) == fields for params in data.catheters.values())
    assert data.mechanism == "play"
    assert "204 runs" in data.DESCR


def test_runs_table_matches_recordings(default_benchmark):
    X, runs = default_benchmark.X, default_benchmark.runs
    grouped = X.groupby("run", observed=True, sort=False)
    first = grouped[["catheter", "setting"]].first().astype(str)
    table = runs.set_index("run")
    assert list(first.index) == list(runs["run"])  # same run order
    assert_array_equal(first["catheter"], table["catheter"])
    assert_array_equal(first["setting"], table["setting"])
    assert_array_equal(grouped.size(), table["n_samples"])
    n_sweep = (X["phase"] == "sweep").groupby(X["run"], observed=True, sort=False).sum()
    assert_array_equal(n_sweep, table["n_sweep"])
    assert len(X) == runs["n_samples"].sum() == len(default_benchmark.y)
    settings = {s.name: s for s in shaft_settings()}
    for _, row in runs.iterrows():
        assert row["run"] == f"{row['catheter']}-{row['setting']}-R{row['repeat']}"
        assert row["bend_level"] == settings[row["setting"]].level
        assert row["shaft_wrap_deg"] == settings[row["setting"]].bend_deg
    assert default_benchmark.noise_floor == pytest.approx(runs["noise_floor_mm"].mean())
    assert runs["noise_floor_mm"].between(0.1, 1.5).all()  # measured: 0.46-0.60 mm


def test_default_benchmark_passes_format_checks(default_benchmark):
    X, y = check_recordings(default_benchmark.X, default_benchmark.y)
    assert len(X) == len(y) > 1_200_000


def test_default_benchmark_ranges(default_benchmark):
    X, y = default_benchmark.X, default_benchmark.y
    run = X["run"].to_numpy()
    tip = pd.DataFrame(y, columns=["x", "y", "z"]).groupby(run)
    spans = tip.max() - tip.min()
    typical = spans.median()
    # measured median spans (mm): x 48.8, y 48.5, z 27.4 (simulator version 5)
    assert typical.between(25.0, 60.0).all(), typical.to_dict()
    # every run reaches the amplitude on its sweep, and never goes beyond
    rho = pd.Series(np.hypot(X["q1"], X["q2"]).to_numpy()).groupby(run).max()
    assert_allclose(rho, AMPLITUDE, rtol=0, atol=1e-9)
    assert np.isfinite(X[["tau1", "tau2"]].to_numpy()).all()
    assert np.isfinite(default_benchmark.y_true).all()


def test_cache_reload_does_not_resimulate(default_benchmark, benchmark_home, monkeypatch):
    files = list(benchmark_home.glob("benchmark-play-*.npz"))
    assert len(files) == 1

    def _no_simulation(*args, **kwargs):
        raise AssertionError("make_benchmark re-simulated a cached benchmark")

    monkeypatch.setattr(_benchmark, "simulate_runs", _no_simulation)
    again = make_benchmark(cache=True, data_home=benchmark_home)
    _assert_same_data(again, default_benchmark)
    assert again.catheters == default_benchmark.catheters


def test_small_benchmark_is_subset_of_default(default_benchmark, small_benchmark):
    small, full = small_benchmark, default_benchmark
    ids = list(small.runs["run"])
    assert ids == [f"C1-S{k:02d}-R1" for k in range(17)]
    rows = full.X["run"].isin(ids).to_numpy()
    pd.testing.assert_frame_equal(_plain_ids(full.X[rows]), _plain_ids(small.X), check_exact=True)
    assert_array_equal(full.y[rows], small.y)
    assert_array_equal(full.y_true[rows], small.y_true)
    pd.testing.assert_frame_equal(
        full.sensors[rows].reset_index(drop=True), small.sensors, check_exact=True
    )
    sub_runs = full.runs[full.runs["run"].isin(ids)].reset_index(drop=True)
    pd.testing.assert_frame_equal(sub_runs, small.runs, check_exact=True)
    assert small.catheters["C1"] == full.catheters["C1"]


def test_random_state_changes_benchmark(small_benchmark):
    other = make_benchmark(n_catheters=1, n_runs=1, random_state=1, cache=False)
    assert list(other.runs["run"]) == list(small_benchmark.runs["run"])
    assert other.catheters["C1"] != small_benchmark.catheters["C1"]
    n = min(len(other.y), len(small_benchmark.y))
    assert not np.allclose(other.y_true[:n], small_benchmark.y_true[:n])
    same = make_benchmark(n_catheters=1, n_runs=1, random_state=0, cache=False)
    _assert_same_data(same, small_benchmark)


def _count_simulations(monkeypatch):
    """Wrap ``simulate_runs`` in the benchmark module and count its calls."""
    calls = []
    original = _benchmark.simulate_runs

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(_benchmark, "simulate_runs", counting)
    return calls


def test_small_benchmark_cache_round_trip(small_benchmark, tmp_path, monkeypatch):
    calls = _count_simulations(monkeypatch)
    first = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    second = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert len(calls) == 1
    _assert_same_data(first, small_benchmark)
    _assert_same_data(second, small_benchmark)
    # other arguments are cached separately
    make_benchmark(n_catheters=1, n_runs=1, mechanism="bouc_wen", data_home=tmp_path)
    assert len(calls) == 2
    assert len(list(tmp_path.glob("benchmark-*.npz"))) == 2


def test_simulator_version_keys_the_cache(small_benchmark, tmp_path, monkeypatch):
    # A cache written by another simulator version is never reused.
    version = _benchmark.SIMULATOR_VERSION
    assert SIMULATOR_VERSION == version
    calls = []

    def fake_simulation(*args, **kwargs):
        calls.append(1)
        keys = ("X", "y", "y_true", "sensors", "runs", "noise_floor", "mechanism")
        return Bunch(**{k: small_benchmark[k] for k in keys})

    monkeypatch.setattr(_benchmark, "simulate_runs", fake_simulation)
    current = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert current.key["version"] == version
    monkeypatch.setattr(_benchmark, "SIMULATOR_VERSION", version + "-older")
    older = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert older.key["version"] == version + "-older"
    assert len(calls) == 2
    assert len(list(tmp_path.glob("benchmark-play-*.npz"))) == 2
    monkeypatch.setattr(_benchmark, "SIMULATOR_VERSION", version)
    again = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert len(calls) == 2
    assert again.key == current.key
    _assert_same_data(again, small_benchmark)


@pytest.mark.parametrize("content", ["garbage", "foreign"])
def test_corrupt_cache_is_regenerated(small_benchmark, tmp_path, monkeypatch, caplog, content):
    make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    (path,) = tmp_path.glob("benchmark-play-*.npz")
    if content == "garbage":
        path.write_bytes(b"not a cache file")
    else:  # a readable file written for other arguments
        with open(path, "wb") as file:
            _cache.write_bunch(file, Bunch(key={"version": "0"}, X=None), {"version": "0"})
    calls = _count_simulations(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="skcath"):
        data = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert len(calls) == 1
    _assert_same_data(data, small_benchmark)
    if content == "garbage":
        assert any(path.name in rec.getMessage() for rec in caplog.records)
    # the cache file was rewritten and now loads without simulating
    _assert_same_data(_cache.read_bunch(path), small_benchmark)
    make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert len(calls) == 1


def _assert_identical_bunches(a, b):
    """Same fields in the same order; frames with the same dtypes, categories and index."""
    assert list(a) == list(b)
    for name, value in a.items():
        other = b[name]
        assert type(other) is type(value), name
        if isinstance(value, pd.DataFrame):
            pd.testing.assert_frame_equal(value, other, check_exact=True)
            pd.testing.assert_index_equal(value.index, other.index, exact=True)
            pd.testing.assert_index_equal(value.columns, other.columns, exact=True)
            for column in value:
                assert other[column].dtype == value[column].dtype, (name, column)
                if isinstance(value[column].dtype, pd.CategoricalDtype):
                    pd.testing.assert_index_equal(
                        other[column].cat.categories, value[column].cat.categories, exact=True
                    )
        elif isinstance(value, np.ndarray):
            assert other.dtype == value.dtype and other.shape == value.shape, name
            assert_array_equal(other, value)
        else:  # JSON values: repr tells a float from a numpy float, a list from a tuple
            assert repr(other) == repr(value), name


@pytest.mark.parametrize("shaft_change", [False, True])
def test_cached_benchmark_is_the_generated_one_without_pickle(
    small_benchmark, changed_benchmark, tmp_path, monkeypatch, shaft_change
):
    fresh = changed_benchmark if shaft_change else small_benchmark
    make_benchmark(n_catheters=1, n_runs=1, shaft_change=shaft_change, data_home=tmp_path)
    (path,) = tmp_path.glob("benchmark-play-*.npz")
    with np.load(path, allow_pickle=False) as npz:  # no member needs pickle
        assert all(npz[name].dtype != object for name in npz.files)
    calls = _count_simulations(monkeypatch)
    cached = make_benchmark(n_catheters=1, n_runs=1, shaft_change=shaft_change, data_home=tmp_path)
    assert calls == []
    _assert_identical_bunches(cached, fresh)
    assert set(cached) == {"X", "y", "y_true", "sensors", "runs", "noise_floor", "mechanism",
                           "catheters", "key", "DESCR"}


def test_cached_benchmark_of_given_catheters_is_found_again(tmp_path, monkeypatch):
    # the key holds the units' parameters: it must compare equal once read back
    units = [dataclasses.replace(benchmark_catheter(1), length=55.0)]
    first = make_benchmark(n_runs=1, catheters=units, data_home=tmp_path)
    calls = _count_simulations(monkeypatch)
    again = make_benchmark(n_runs=1, catheters=units, data_home=tmp_path)
    assert calls == []
    _assert_identical_bunches(again, first)


def test_no_cache_writes_nothing(tmp_path):
    make_benchmark(n_catheters=1, n_runs=1, cache=False, data_home=tmp_path / "unused")
    assert not (tmp_path / "unused").exists()


def test_data_home_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "env_home"))
    home = get_data_home()
    assert home == tmp_path / "env_home" and home.is_dir()
    assert get_data_home(tmp_path / "explicit") == tmp_path / "explicit"
    (home / "file").write_text("x")
    clear_data_home()
    assert not home.exists()


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"n_catheters": 0}, "n_catheters"),
        ({"n_catheters": 1.5}, "n_catheters"),
        ({"n_catheters": True}, "n_catheters"),
        ({"n_runs": 0}, "n_runs"),
        ({"mechanism": "x"}, "mechanism"),
        ({"random_state": -1}, "random_state"),
        ({"random_state": None}, "random_state"),
    ],
)
def test_make_benchmark_rejects_bad_arguments(kwargs, name, tmp_path):
    with pytest.raises(ValueError, match=name):
        make_benchmark(**{"n_catheters": 1, "n_runs": 1, **kwargs}, data_home=tmp_path)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------
# shaft repositioned during motion
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def changed_run(run0):
    """The run of ``run0`` (seed 0, setting S01) with the shaft moved to S13 after 45 s of motion."""
    return simulate_run(random_state=0, setting_after="S13", change_after_s=45.0)


def test_shaft_change_happens_where_runs_says(run0, changed_run):
    runs = changed_run.runs
    assert runs.loc[0, "setting"] == "S01" and runs.loc[0, "setting_after"] == "S13"
    n_sweep = runs.loc[0, "n_sweep"]
    t_change = runs.loc[0, "change_time_s"]
    assert t_change == pytest.approx(n_sweep / 10.0 + 45.0)
    # the unchanged run has no change columns
    assert "change_time_s" not in run0.runs and "setting_after" not in run0.runs
    X, X0 = changed_run.X, run0.X
    before = (X["t"] < t_change).to_numpy()
    # up to the change: the same run, sample for sample
    pd.testing.assert_frame_equal(X[before], X0[before], check_exact=True)
    assert_array_equal(changed_run.y_true[before], run0.y_true[before])
    assert_array_equal(changed_run.sensors[before].to_numpy(), run0.sensors[before].to_numpy())
    # from the change on: same motors, other torques and tip
    assert_array_equal(X[["q1", "q2"]].to_numpy(), X0[["q1", "q2"]].to_numpy())
    k = int(np.flatnonzero(~before)[0])
    tau, tau0 = X[["tau1", "tau2"]].to_numpy(), X0[["tau1", "tau2"]].to_numpy()
    assert np.abs(tau[k:] - tau0[k:]).mean() > 2.0  # measured: 6.1 N mm
    tip_shift = np.linalg.norm(changed_run.y_true[k:] - run0.y_true[k:], axis=1)
    assert tip_shift.mean() > 1.0
    # the base of the bending section moves with the shaft
    base = changed_run.sensors[["base_px", "base_py", "base_pz"]].to_numpy()
    jump = np.linalg.norm(base[k:].mean(axis=0) - base[:k].mean(axis=0))
    assert jump > 1.0
    check_recordings(X, changed_run.y)


def test_later_shaft_change_keeps_a_longer_identical_stretch(changed_run):
    # The change time is the first sample in the new setting: a change later
    # in the same run leaves a longer stretch identical to the unchanged run.
    later = simulate_run(random_state=0, setting_after="S13", change_after_s=90.0)
    k_early = int(np.searchsorted(changed_run.X["t"], changed_run.runs.loc[0, "change_time_s"]))
    k_late = int(np.searchsorted(later.X["t"], later.runs.loc[0, "change_time_s"]))
    assert k_late - k_early == 450
    assert_array_equal(later.y_true[:k_early], changed_run.y_true[:k_early])
    assert not np.array_equal(later.y_true[k_early:k_late], changed_run.y_true[k_early:k_late])


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"setting_after": "S99"}, "setting_after"),
        ({"setting_after": "S01"}, "setting_after"),
        ({"setting": "S00", "setting_after": "S00"}, "setting_after"),
        ({"setting_after": "S05", "change_after_s": -1.0}, "change_after_s"),
        ({"setting_after": "S05", "change_after_s": np.nan}, "change_after_s"),
        ({"setting_after": "S05", "change_after_s": "10"}, "change_after_s"),
        ({"setting_after": "S05", "change_after_s": 1000.0}, "change_after_s"),
    ],
)
def test_simulate_run_rejects_bad_shaft_changes(kwargs, name):
    with pytest.raises(ValueError, match=name):
        simulate_run(random_state=0, **kwargs)


@pytest.fixture(scope="module")
def changed_benchmark():
    """One catheter in all 17 settings, one run each, every shaft repositioned."""
    return make_benchmark(n_catheters=1, n_runs=1, shaft_change=True, cache=False)


def test_shaft_change_benchmark(small_benchmark, changed_benchmark):
    runs = changed_benchmark.runs
    assert list(runs["run"]) == list(small_benchmark.runs["run"])
    assert (runs["setting_after"] != runs["setting"]).all()
    assert runs["setting_after"].nunique() > 5  # drawn among the other settings
    after_motion = runs["change_time_s"] - runs["n_sweep"] / 10.0
    assert after_motion.between(30.0, 90.0).all()
    assert after_motion.std() > 5.0
    pd.testing.assert_frame_equal(
        runs.drop(columns=["setting_after", "change_time_s", "noise_floor_mm"]),
        small_benchmark.runs.drop(columns="noise_floor_mm"),
        check_exact=True,
    )
    assert "repositioned" in changed_benchmark.DESCR
    assert changed_benchmark.key["shaft_change"] is True
    X, X0 = changed_benchmark.X, small_benchmark.X
    t_change = X["run"].map(runs.set_index("run")["change_time_s"]).astype(float)
    before = (X["t"] < t_change).to_numpy()
    pd.testing.assert_frame_equal(X[before], X0[before], check_exact=True)
    assert_array_equal(changed_benchmark.y[before], small_benchmark.y[before])
    assert not np.array_equal(X.loc[~before, "tau1"], X0.loc[~before, "tau1"])
    check_recordings(X, changed_benchmark.y)


def test_shaft_change_keeps_the_default_benchmark_and_its_cache(small_benchmark, tmp_path, monkeypatch):
    calls = _count_simulations(monkeypatch)
    default = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    explicit = make_benchmark(n_catheters=1, n_runs=1, shaft_change=False, data_home=tmp_path)
    assert len(calls) == 1  # shaft_change=False is the default benchmark, from its cache
    _assert_same_data(explicit, small_benchmark)
    assert explicit.key == default.key and "shaft_change" not in default.key
    changed = make_benchmark(n_catheters=1, n_runs=1, shaft_change=True, data_home=tmp_path)
    again = make_benchmark(n_catheters=1, n_runs=1, shaft_change=True, data_home=tmp_path)
    assert len(calls) == 2  # cached separately, then loaded
    assert len(list(tmp_path.glob("benchmark-*.npz"))) == 2
    _assert_same_data(changed, again)
    pd.testing.assert_frame_equal(changed.runs, again.runs, check_exact=True)


def test_make_benchmark_rejects_bad_shaft_change(tmp_path):
    with pytest.raises(ValueError, match="shaft_change"):
        make_benchmark(n_catheters=1, n_runs=1, shaft_change="yes", data_home=tmp_path)


# ---------------------------------------------------------------------------
# a re-sweep after the shaft change
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def reswept_run():
    """The run of ``changed_run`` sweeping again at its change: two recorded runs."""
    return simulate_run(random_state=0, setting_after="S13", change_after_s=45.0, resweep=True)


def _rows_of(bunch, run):
    """Rows of one run in ``bunch``: its frame (ids as strings), y, y_true and sensor poses."""
    rows = (bunch.X["run"] == run).to_numpy()
    return _plain_ids(bunch.X[rows]), bunch.y[rows], bunch.y_true[rows], bunch.sensors[rows].to_numpy()


def test_resweep_keeps_the_changed_run_up_to_the_change(changed_run, reswept_run):
    runs = reswept_run.runs
    assert list(runs["run"]) == ["run-0", "run-0/after"]
    assert list(runs["setting"]) == ["S01", "S13"]
    assert pd.isna(runs.loc[0, "before_run"]) and runs.loc[1, "before_run"] == "run-0"
    assert runs.loc[0, "setting_after"] == "S13" and pd.isna(runs.loc[1, "setting_after"])
    t_change = changed_run.runs.loc[0, "change_time_s"]
    assert runs.loc[0, "change_time_s"] == t_change and np.isnan(runs.loc[1, "change_time_s"])
    # the part before the change: the shaft_change run up to its change, sample for sample
    X, y, y_true, sensors = _rows_of(reswept_run, "run-0")
    k = int(np.sum(changed_run.X["t"] < t_change))
    assert len(X) == k == runs.loc[0, "n_samples"]
    pd.testing.assert_frame_equal(X, _plain_ids(changed_run.X.iloc[:k]), check_exact=True)
    assert_array_equal(y, changed_run.y[:k])
    assert_array_equal(y_true, changed_run.y_true[:k])
    assert_array_equal(sensors, changed_run.sensors.to_numpy()[:k])
    check_recordings(reswept_run.X, reswept_run.y)


def test_resweep_is_a_run_of_its_own_in_the_new_setting(changed_run, reswept_run):
    from skcath.backbones import PDLBackbone
    from skcath.sweep import find_rays

    X, y, _, _ = _rows_of(reswept_run, "run-0/after")
    first = changed_run.X
    n_sweep = int(changed_run.runs.loc[0, "n_sweep"])
    k = int(np.sum(first["t"] < changed_run.runs.loc[0, "change_time_s"]))
    sweep = (X["phase"] == "sweep").to_numpy()
    assert sweep[:n_sweep].all() and not sweep[n_sweep:].any()
    assert (X["setting"] == "S13").all() and (X["catheter"] == "C1").all()
    # the same 8 rays as the first sweep, with the tracked reference on them
    q = X[["q1", "q2"]].to_numpy()
    assert_array_equal(q[:n_sweep], first[["q1", "q2"]].to_numpy()[:n_sweep])
    rays = find_rays(q[:n_sweep])
    assert rays.n_rays == 8 and rays.amplitude == pytest.approx(60.0)
    assert_array_equal(X.loc[sweep, REF_COLUMNS].to_numpy(), y[sweep])
    assert X.loc[~sweep, REF_COLUMNS].isna().all().all()
    # then back to where the motors stood at the change, and the rest of the walk
    q_stop = first[["q1", "q2"]].to_numpy()[k - 1]
    assert_array_equal(q[n_sweep + 19], q_stop)
    assert_array_equal(q[n_sweep + 20:], first[["q1", "q2"]].to_numpy()[k:])
    # on the run's clock: after the change and the return to neutral (not recorded)
    t = X["t"].to_numpy()
    assert t[0] > changed_run.runs.loc[0, "change_time_s"]
    assert_allclose(np.diff(t), 0.1)
    # its own torques and tips: the new setting's, not the first sweep's
    tau = X[["tau1", "tau2"]].to_numpy()[:n_sweep]
    assert np.abs(tau - first[["tau1", "tau2"]].to_numpy()[:n_sweep]).mean() > 2.0
    calibration = PDLBackbone().fit(reswept_run.X).calibrate(reswept_run.X)
    assert calibration.table["converged"].all()
    assert calibration.table["rmse_mm"].max() < 10.0


def test_resweep_benchmark(changed_benchmark, tmp_path):
    data = make_benchmark(
        n_catheters=1, n_runs=1, shaft_change=True, resweep=True, data_home=tmp_path
    )
    runs, changed = data.runs, changed_benchmark.runs
    assert len(runs) == 2 * len(changed)
    before = runs[runs["before_run"].isna()].reset_index(drop=True)
    after = runs[runs["before_run"].notna()].reset_index(drop=True)
    assert list(before["run"]) == list(changed["run"])
    assert list(after["run"]) == [f"{run}/after" for run in changed["run"]]
    assert list(after["before_run"]) == list(changed["run"])
    assert list(after["setting"]) == list(changed["setting_after"])
    pd.testing.assert_series_equal(before["change_time_s"], changed["change_time_s"])
    # every run before its change is the shaft_change run, sample for sample
    t_change = changed_benchmark.X["run"].map(changed.set_index("run")["change_time_s"]).astype(float)
    kept = (changed_benchmark.X["t"] < t_change).to_numpy()
    first = ~data.X["run"].astype(str).str.endswith("/after").to_numpy()
    pd.testing.assert_frame_equal(
        _plain_ids(data.X[first]), _plain_ids(changed_benchmark.X[kept]), check_exact=True
    )
    assert_array_equal(data.y[first], changed_benchmark.y[kept])
    check_recordings(data.X, data.y)
    assert data.key["resweep"] is True and "resweep" not in changed_benchmark.key
    assert "sweeps again" in data.DESCR
    # cached under its own key, beside the shaft_change variant's
    make_benchmark(n_catheters=1, n_runs=1, shaft_change=True, data_home=tmp_path)
    assert len(list(tmp_path.glob("benchmark-*.npz"))) == 2
    again = make_benchmark(n_catheters=1, n_runs=1, shaft_change=True, resweep=True, data_home=tmp_path)
    _assert_same_data(again, data)


def test_resweep_needs_a_shaft_change(tmp_path):
    with pytest.raises(ValueError, match="resweep=True .* needs shaft_change=True"):
        make_benchmark(n_catheters=1, n_runs=1, resweep=True, data_home=tmp_path)
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="resweep=True .* needs setting_after"):
        simulate_run(random_state=0, resweep=True)
    with pytest.raises(ValueError, match="resweep"):
        simulate_run(random_state=0, setting_after="S05", resweep="yes")


def test_unit_spread_narrows_the_unit_parameters_but_not_the_set_up():
    # Simulator version 6: a unit's parameters are draws pulled towards the
    # middle of the family's range by UNIT_SPREAD; the direction-dependent
    # routing terms, the tendon-to-tendon gain differences and the set-up
    # (motor offsets, base-sensor mount) are drawn over the whole range.
    from skcath.datasets._catheter import UNIT_SPREAD

    assert 0 < UNIT_SPREAD < 1
    cats = [sample_catheter(seed) for seed in range(300)]
    mu = np.array([c.mu for c in cats])  # family range U(0.10, 0.20)
    half = 0.5 * UNIT_SPREAD * 0.10
    assert np.all(np.abs(mu - 0.15) <= half + 1e-12)
    assert mu.max() - mu.min() > 1.8 * half  # the narrowed range is used, not a constant
    length = np.array([c.length for c in cats])  # U(38, 46)
    assert np.all(np.abs(length - 42.0) <= 0.5 * UNIT_SPREAD * 8.0 + 1e-12)
    # gains: the unit's mean is narrowed (sd 0.2 / 2 -> 0.35 of it), the
    # differences between its four tendons keep sd 0.2 sqrt(3/4)
    relative = np.array([c.gains / np.deg2rad(3.2) for c in cats]).reshape(len(cats), 4)
    unit_mean = relative.mean(axis=1)
    assert 0.5 * UNIT_SPREAD * 0.1 < unit_mean.std() < 1.5 * UNIT_SPREAD * 0.1
    within = (relative - unit_mean[:, None]).std()
    assert 0.8 * 0.2 * np.sqrt(0.75) < within < 1.2 * 0.2 * np.sqrt(0.75)
    # kept whole: routing phases over the circle, motor offsets N(0, 1.5^2)
    phases = np.concatenate([c.route_phases for c in cats])
    assert phases.max() - phases.min() > 0.9 * 2 * np.pi
    offsets = np.concatenate([c.offsets for c in cats])
    assert 1.2 < offsets.std() < 1.8


def test_unit_spread_pulls_every_narrowed_parameter_towards_the_middle():
    # the same random numbers at every spread: 1 keeps the whole family
    # range (simulator version 5), 0 puts the unit at the middle
    whole = sample_catheter(4, unit_spread=1.0)
    default = sample_catheter(4)
    middle = sample_catheter(4, unit_spread=0.0)
    assert middle.length == pytest.approx(42.0) and middle.mu == pytest.approx(0.15)
    assert default.length == pytest.approx(42.0 + 0.35 * (whole.length - 42.0))
    assert default.play_w0 == pytest.approx(4.0 + 0.35 * (whole.play_w0 - 4.0))
    # kept whole at every spread: offsets, routing phases, mount
    for cat in (default, middle):
        assert_array_equal(cat.offsets, whole.offsets)
        assert_array_equal(cat.route_phases, whole.route_phases)
        assert_array_equal(cat.mount_rotvec, whole.mount_rotvec)
    # the differences between the four tendon gains are kept, their mean narrowed
    assert_allclose(default.gains - default.gains.mean(), whole.gains - whole.gains.mean())
    assert abs(middle.gains.mean() - np.deg2rad(3.2)) < 1e-12
    with pytest.raises(ValueError, match="unit_spread"):
        sample_catheter(4, unit_spread=1.5)


def test_benchmark_catheter_is_the_benchmarks_unit(small_benchmark):
    unit = benchmark_catheter(1)
    assert unit.name == "C1"
    assert unit.to_dict() == small_benchmark.catheters["C1"]
    assert benchmark_catheter(2).to_dict() != unit.to_dict()
    wide = benchmark_catheter(1, unit_spread=1.0)
    assert wide.length != unit.length
    for bad in (0, True, 1.5):
        with pytest.raises(ValueError, match="number"):
            benchmark_catheter(bad)


def test_given_catheters_run_the_benchmarks_runs_of_their_names(small_benchmark):
    unit = benchmark_catheter(1)
    again = make_benchmark(n_runs=1, catheters=[unit], cache=False)
    _assert_same_data(again, small_benchmark)
    assert "catheters" in again.key
    # a changed copy of the unit: same runs (motor angles, torque noise
    # draws, sweeps), other tip positions
    longer = make_benchmark(
        n_runs=1, catheters=[dataclasses.replace(unit, length=unit.length + 4.0)], cache=False
    )
    assert_array_equal(longer.X[["t", "q1", "q2"]], small_benchmark.X[["t", "q1", "q2"]])
    assert not np.allclose(longer.y_true, small_benchmark.y_true)
    # the unit named C2 gets the runs of the benchmark's second unit
    renamed = make_benchmark(
        n_runs=1, catheters=[dataclasses.replace(unit, name="C2")], cache=False
    )
    assert not np.array_equal(renamed.X["q1"].to_numpy()[:500], small_benchmark.X["q1"].to_numpy()[:500])


@pytest.mark.parametrize(
    "catheters, error, match",
    [
        ([], ValueError, "at least one"),
        (["C1"], TypeError, "Catheter"),
        ([dataclasses.replace(sample_catheter(0), name="unit-a")], ValueError, "'C1', 'C2'"),
        ([sample_catheter(0, "C3"), sample_catheter(1, "C3")], ValueError, "own name"),
    ],
)
def test_make_benchmark_rejects_bad_catheters(catheters, error, match, tmp_path):
    with pytest.raises(error, match=match):
        make_benchmark(n_runs=1, catheters=catheters, data_home=tmp_path)
    assert not list(tmp_path.iterdir())


def test_run_variation_changes_only_the_given_variation(small_benchmark, tmp_path):
    calm = make_benchmark(
        n_catheters=1, n_runs=1, run_variation={"gain_drift": 0.0, "offset_drift_deg": 0.0},
        data_home=tmp_path,
    )
    # the runs keep their random numbers: same protocols, other tips
    assert_array_equal(calm.X[["t", "q1", "q2"]], small_benchmark.X[["t", "q1", "q2"]])
    assert not np.allclose(calm.y_true, small_benchmark.y_true)
    assert calm.key["run_variation"] == {"gain_drift": 0.0, "offset_drift_deg": 0.0}
    # a different cache file from the default benchmark's
    default = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert "run_variation" not in default.key
    assert len(list(tmp_path.glob("benchmark-*.npz"))) == 2
    # giving the default values is the default benchmark
    same = make_benchmark(n_catheters=1, n_runs=1, run_variation={"gain_drift": 0.03}, cache=False)
    _assert_same_data(same, small_benchmark)


DRIFT_COLUMNS = ["offset_drift1_deg", "offset_drift2_deg", "gain_drift1", "gain_drift2"]


def test_runs_give_each_runs_own_drift_at_motion_start(small_benchmark):
    drift = small_benchmark.runs[DRIFT_COLUMNS]
    assert drift.notna().all().all() and (drift != 0).all().all()
    # jitter 0.4 deg plus drift 1.2 deg; gains 1.5 % plus 3 %
    assert drift[DRIFT_COLUMNS[:2]].abs().max().max() < 6.0
    assert drift[DRIFT_COLUMNS[2:]].abs().max().max() < 0.25
    # the same random numbers scaled: twice the standard deviations, twice the values
    double = {"offset_jitter_deg": 0.8, "offset_drift_deg": 2.4, "gain_jitter": 0.03,
              "gain_drift": 0.06}
    wider = make_benchmark(n_catheters=1, n_runs=1, run_variation=double, cache=False)
    assert_allclose(wider.runs[DRIFT_COLUMNS], 2.0 * drift, rtol=1e-9)
    # without jitter and drift the run is its setting
    still = {key: 0.0 for key in double}
    calm = make_benchmark(n_catheters=1, n_runs=1, run_variation=still, cache=False)
    assert_array_equal(calm.runs[DRIFT_COLUMNS], 0.0)


def test_cache_of_an_earlier_layout_is_regenerated(small_benchmark, tmp_path, monkeypatch):
    # a file written before the runs had their drift columns is not read back
    old_runs = small_benchmark.runs.drop(columns=DRIFT_COLUMNS)
    monkeypatch.setattr(_cache, "CACHE_FORMAT", _cache.CACHE_FORMAT - 1)
    monkeypatch.setattr(
        _benchmark, "simulate_runs", lambda *a, **k: Bunch(**{**small_benchmark, "runs": old_runs})
    )
    make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    monkeypatch.undo()
    calls = _count_simulations(monkeypatch)
    data = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert len(calls) == 1
    assert set(DRIFT_COLUMNS) <= set(data.runs.columns)


@pytest.mark.parametrize(
    "run_variation, match",
    [
        ({"gain_drfit": 0.0}, "unknown key"),
        ({"gain_drift": -0.1}, r"run_variation\['gain_drift'\]"),
        ({"gain_drift_tau_s": 0.0}, "time constant"),
        ({"offset_jitter_deg": "1"}, "offset_jitter_deg"),
        ({"base_position_mm": np.inf}, "base_position_mm"),
    ],
)
def test_make_benchmark_rejects_bad_run_variation(run_variation, match, tmp_path):
    with pytest.raises(ValueError, match=match):
        make_benchmark(n_catheters=1, n_runs=1, run_variation=run_variation, data_home=tmp_path)
    assert not list(tmp_path.iterdir())


def test_unit_spread_keys_the_cache(tmp_path, monkeypatch):
    calls = _count_simulations(monkeypatch)
    wide = make_benchmark(n_catheters=1, n_runs=1, unit_spread=1.0, data_home=tmp_path)
    assert wide.key["unit_spread"] == 1.0
    assert wide.catheters["C1"] == benchmark_catheter(1, unit_spread=1.0).to_dict()
    make_benchmark(n_catheters=1, n_runs=1, unit_spread=1.0, data_home=tmp_path)
    assert len(calls) == 1
    default = make_benchmark(n_catheters=1, n_runs=1, unit_spread=0.35, data_home=tmp_path)
    assert "unit_spread" not in default.key and len(calls) == 2


def test_setting_parameters_of_a_unit():
    settings = {s.name: s for s in shaft_settings()}
    cat = benchmark_catheter(1)
    straight, bent = setting_parameters(cat, settings["S00"]), setting_parameters(cat, settings["S09"])
    assert set(straight) == set(bent)
    # a bent shaft wraps the tendons more: wider dead zone and play
    assert (bent["dead_zone"] > straight["dead_zone"]).all()
    assert (bent["w0"] > straight["w0"]).all()
    with pytest.raises(ValueError, match="setting"):
        setting_parameters(cat, "S09")
