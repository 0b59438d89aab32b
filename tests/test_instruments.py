"""Tests of the simulated instruments of one, two and three motors.

``simulate_run(n_motors=...)`` and ``make_benchmark(n_motors=...)``: the
tendon layouts, the protocol of each instrument, its columns, determinism,
the physics that differs (one bending plane; three tendons, each with its
own torque), and that the two-motor benchmark is unchanged.
"""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from skcath import motor_columns
from skcath._validation import check_recordings
from skcath.datasets import (
    SIMULATOR_VERSION,
    benchmark_catheter,
    make_benchmark,
    setting_parameters,
    shaft_settings,
    simulate_run,
)
from skcath.datasets._catheter import TENDON_AZIMUTHS
from skcath.datasets._tendons import RELEASE_RATIO, tendon_layout

AMPLITUDE = 60.0
#: Sums over the samples of ``simulate_run(setting="S09", random_state=3)`` of
#: the noise-free tip (mm) and of the torques (N mm), as simulated before the
#: simulator had instruments of other numbers of motors (version 6).
REFERENCE_TIP_SUMS = [-19921.362849945705, -180551.79330797, 303144.1192913061]
REFERENCE_TORQUE_SUMS = [-26229.0, -28168.0]


@pytest.fixture(autouse=True)
def _isolated_data_home(tmp_path, monkeypatch):
    """Keep every cache this module may write out of the user's home."""
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "default_home"))


@pytest.fixture(scope="module")
def runs():
    """``runs(n)``: one run of ``n`` motors in a high-bend setting, seed 3 (built once)."""
    cache = {}

    def get(n_motors):
        if n_motors not in cache:
            cache[n_motors] = simulate_run(setting="S09", random_state=3, n_motors=n_motors)
        return cache[n_motors]

    return get


def _sweep(run):
    """The motor angles (n_sweep, N) of a run's sweep."""
    X = run.X
    motors, _ = motor_columns(X)
    return X.loc[X["phase"] == "sweep", list(motors)].to_numpy()


def _ray_ends(q):
    """The motor angles at the far end of each ray of a sweep: the peaks of |q| between rests."""
    moving = np.any(q != 0.0, axis=1).astype(int)
    edges = np.flatnonzero(np.diff(np.r_[0, moving, 0]))
    ends = []
    for start, stop in zip(edges[::2], edges[1::2]):
        ray = q[start:stop]
        ends.append(ray[np.argmax(np.linalg.norm(ray, axis=1))])
    return np.array(ends)


# ---------------------------------------------------------------------------
# tendon layouts
# ---------------------------------------------------------------------------
def test_two_motor_layout_is_the_identity():
    layout = tendon_layout(2)
    assert_array_equal(layout.bend_map, np.eye(2))
    assert_array_equal(layout.command_map, np.eye(2))
    assert_array_equal(layout.azimuths, TENDON_AZIMUTHS)
    assert not layout.single_tendons and not layout.planar and layout.sweep_rays == 8
    x = np.random.default_rng(0).normal(size=(5, 2))
    assert_array_equal(layout.motor_angles(x), x)
    assert_array_equal(layout.bending_inputs(x), x)


def test_three_tendons_bend_the_section_by_the_commanded_vector():
    """Tendons displaced by ``c cos(psi - a_i)`` bend the section by ``c`` towards ``psi``."""
    layout = tendon_layout(3)
    assert_allclose(np.rad2deg(layout.azimuths[:, 0]), [0.0, 120.0, 240.0])
    assert_allclose(layout.bend_map @ layout.command_map, np.eye(2), atol=1e-15)
    assert layout.single_tendons and layout.sweep_rays == 6
    # pulled along the command, released by RELEASE_RATIO of the geometry
    q = layout.motor_angles(np.array([[AMPLITUDE, 0.0]]))[0]
    assert_allclose(q, [AMPLITUDE, -RELEASE_RATIO * AMPLITUDE / 2, -RELEASE_RATIO * AMPLITUDE / 2])
    assert layout.per_motor([1.0, 0.0]) == pytest.approx([1.0, -0.5, -0.5])


def test_one_motor_layout_is_one_axis():
    layout = tendon_layout(1)
    assert layout.planar and layout.n_commands == 1 and layout.sweep_rays == 2
    assert_array_equal(layout.bending_inputs(np.array([[2.0], [-3.0]])), [[2.0, 0.0], [-3.0, 0.0]])


@pytest.mark.parametrize("n_motors", [0, 4, True])
def test_tendon_layout_refuses_other_numbers_of_motors(n_motors):
    with pytest.raises(ValueError, match=r"n_motors must be one of \(1, 2, 3\)"):
        tendon_layout(n_motors)


# ---------------------------------------------------------------------------
# catheter units
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [1, 3])
def test_unit_of_other_motors_is_the_two_motor_unit_with_its_tendons(n_motors):
    two = benchmark_catheter(2)
    unit = benchmark_catheter(2, n_motors=n_motors)
    assert unit.n_motors == n_motors
    assert unit.gains.shape == (n_motors, 2) and unit.offsets.shape == (n_motors,)
    shared = min(n_motors, 2)
    assert_array_equal(unit.offsets[:shared], two.offsets[:shared])
    # the same section, drive and mount
    for name in ("length", "tip_length", "max_bend", "mu", "play_w0", "stiffness", "mount_rotvec"):
        assert_array_equal(getattr(unit, name), getattr(two, name))
    # the differences between the first motor's tendons are kept
    assert unit.gains[0, 0] - unit.gains[0, 1] == pytest.approx(two.gains[0, 0] - two.gains[0, 1])


def test_one_motor_section_stays_in_its_plane():
    """setting_parameters of a one-motor unit: nothing turns the bend out of the plane."""
    unit = benchmark_catheter(1, n_motors=1)
    for setting in shaft_settings()[::5]:
        cfg = setting_parameters(unit, setting)
        assert cfg["twist"] == 0.0 and cfg["windup"] == 0.0
        assert_array_equal(cfg["coupling"], [0.0, 0.0])
        assert cfg["rest_bend"][1] == 0.0
        assert cfg["routing"][0] == 0.0 and cfg["routing"][2] == 0.0
        assert cfg["gains"].shape == (1, 2) and cfg["w0"].shape == (1,)


# ---------------------------------------------------------------------------
# runs
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [1, 2, 3])
def test_columns_and_format_of_each_instrument(runs, n_motors):
    run = runs(n_motors)
    X = run.X
    motors = [f"q{k}" for k in range(1, n_motors + 1)]
    torques = [f"tau{k}" for k in range(1, n_motors + 1)]
    assert list(X.columns) == ["catheter", "setting", "run", "t", "phase", *motors, *torques,
                               "ref_x", "ref_y", "ref_z"]
    assert motor_columns(X) == (tuple(motors), tuple(torques))
    check_recordings(X, run.y, columns="auto")
    assert run.y.shape == run.y_true.shape == (len(X), 3)
    assert np.isfinite(run.y_true).all() and np.isfinite(X[motors + torques].to_numpy()).all()
    drift = [f"offset_drift{k}_deg" for k in range(1, n_motors + 1)]
    drift += [f"gain_drift{k}" for k in range(1, n_motors + 1)]
    assert [c for c in run.runs.columns if "drift" in c] == drift
    # the walk is the two-motor run's length; the sweep has the instrument's rays
    n_sweep = int(run.runs["n_sweep"].iloc[0])
    assert 1650 <= len(X) - n_sweep <= 2200
    assert len(_ray_ends(_sweep(run))) == tendon_layout(n_motors).sweep_rays


@pytest.mark.parametrize("n_motors", [1, 3])
def test_same_seed_same_run(runs, n_motors):
    a = runs(n_motors)
    b = simulate_run(setting="S09", random_state=3, n_motors=n_motors)
    pd.testing.assert_frame_equal(a.X, b.X, check_exact=True)
    assert_array_equal(a.y, b.y)
    c = simulate_run(setting="S09", random_state=4, n_motors=n_motors)
    assert not np.array_equal(a.y_true[:100], c.y_true[:100])


def test_one_motor_sweeps_out_and_back_to_both_signs_and_walks_in_an_interval(runs):
    run = runs(1)
    ends = _ray_ends(_sweep(run))
    assert_allclose(ends[:, 0], [AMPLITUDE, -AMPLITUDE], atol=1e-9)
    q = run.X["q1"].to_numpy()
    assert np.abs(q).max() <= AMPLITUDE + 1e-9
    motion = (run.X["phase"] == "motion").to_numpy()
    assert q[motion].min() < -20.0 and q[motion].max() > 20.0


def test_one_motor_tip_moves_in_one_plane(runs):
    """The noise-free tips of a one-motor instrument lie in a plane; those of two motors do not."""
    def flatness(y):
        s = np.linalg.svd(y - y.mean(axis=0), compute_uv=False)
        return s[-1] / s[0]

    assert flatness(runs(1).y_true) < 1e-9
    assert flatness(runs(2).y_true) > 0.05


def test_three_motor_sweep_rays_pull_each_tendon_and_each_pair(runs):
    """Six rays at 60 degrees: towards each tendon (pull one, pay out two) and between two."""
    layout = tendon_layout(3)
    psi = np.deg2rad(60.0 * np.arange(6))
    expected = layout.motor_angles(AMPLITUDE * np.column_stack([np.cos(psi), np.sin(psi)]))
    assert_allclose(_ray_ends(_sweep(runs(3))), expected, atol=1e-9)
    # every ray is straight in the space of the three motors
    q = _sweep(runs(3))
    moving = np.linalg.norm(q, axis=1) > 1.0
    direction = q[moving] / np.linalg.norm(q[moving], axis=1, keepdims=True)
    ends = expected / np.linalg.norm(expected, axis=1, keepdims=True)
    assert np.max(direction @ ends.T, axis=1) == pytest.approx(1.0, abs=1e-9)


def test_three_motor_torque_is_the_load_of_each_motors_tendon(runs):
    """Each motor's torque rises when its own tendon is pulled, not when the others are."""
    X = runs(3).X
    sweep = (X["phase"] == "sweep").to_numpy()
    q = X.loc[sweep, ["q1", "q2", "q3"]].to_numpy()
    tau = X.loc[sweep, ["tau1", "tau2", "tau3"]].to_numpy()
    for i in range(3):
        pulled = q[:, i] > 40.0
        paid_out = q[:, i] < -15.0
        assert tau[pulled, i].mean() > tau[paid_out, i].mean() + 20.0
        assert np.corrcoef(q[:, i], tau[:, i])[0, 1] > 0.7


def test_a_unit_of_three_motors_runs_in_a_run_of_its_own():
    unit = benchmark_catheter(1, n_motors=3)
    run = simulate_run(unit, "S00", random_state=1, n_motors=3)
    assert run.X["catheter"].iloc[0] == "C1"
    changed = simulate_run(unit, "S00", random_state=1, n_motors=3, setting_after="S09")
    k = int(np.argmax(changed.X["t"].to_numpy() >= changed.runs["change_time_s"].iloc[0]))
    assert_array_equal(changed.y_true[:k], run.y_true[:k])
    assert not np.allclose(changed.y_true[k + 50:], run.y_true[k + 50:])


# ---------------------------------------------------------------------------
# benchmarks
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [1, 3])
def test_benchmark_of_other_motors_is_cached_under_its_own_key(tmp_path, n_motors):
    bench = make_benchmark(n_catheters=1, n_runs=1, n_motors=n_motors, data_home=tmp_path)
    assert bench.key == {"version": SIMULATOR_VERSION, "n_catheters": 1, "n_runs": 1,
                         "mechanism": "play", "random_state": 0, "n_motors": n_motors}
    assert bench.X["run"].nunique() == 17 == len(bench.runs)
    assert motor_columns(bench.X)[0] == tuple(f"q{k}" for k in range(1, n_motors + 1))
    assert f"{tendon_layout(n_motors).sweep_rays}-ray" in bench.DESCR
    assert len(bench.catheters["C1"]["offsets"]) == n_motors
    again = make_benchmark(n_catheters=1, n_runs=1, n_motors=n_motors, data_home=tmp_path)
    pd.testing.assert_frame_equal(again.X, bench.X, check_exact=True)
    assert_array_equal(again.y, bench.y)
    assert len(list(tmp_path.glob("benchmark-*"))) == 1


def test_two_motors_are_the_default_benchmark_with_its_key(tmp_path):
    """n_motors=2 is the default: same key as before the parameter existed, same data."""
    default = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path)
    assert default.key == {"version": SIMULATOR_VERSION, "n_catheters": 1, "n_runs": 1,
                           "mechanism": "play", "random_state": 0}
    two = make_benchmark(n_catheters=1, n_runs=1, n_motors=2, cache=False)
    pd.testing.assert_frame_equal(two.X, default.X, check_exact=True)
    assert_array_equal(two.y, default.y)
    assert "Instrument" not in default.DESCR and "8-ray" in default.DESCR


def test_two_motor_run_is_unchanged():
    """A run of the two-motor simulator keeps its values (simulator version 6)."""
    run = simulate_run(setting="S09", random_state=3)
    assert len(run.X) == 6047 and int(run.runs["n_sweep"].iloc[0]) == 4326
    assert run.y_true.sum(axis=0) == pytest.approx(REFERENCE_TIP_SUMS, rel=1e-9)
    assert run.X[["tau1", "tau2"]].to_numpy().sum(axis=0) == pytest.approx(
        REFERENCE_TORQUE_SUMS, rel=1e-9
    )
