"""Tests of the simulated catheter driven one sample at a time (skcath.datasets.SimulatedCatheter)."""

import copy
import dataclasses
import warnings

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from sklearn.exceptions import NotFittedError

from skcath.datasets import SimulatedCatheter, benchmark_catheter, shaft_settings
from skcath.datasets._benchmark import _benchmark_field, benchmark_specs
from skcath.datasets._simulator import simulate_runs
from skcath.exceptions import MotorLimitWarning


def _benchmark_run(number, setting, repeat, *, mechanism, n_motors, rate_hz=10.0, random_state=0):
    """The run ``C<number>-<setting>-R<repeat>`` as make_benchmark simulates it (one run of its specs)."""
    cat = benchmark_catheter(number, random_state, n_motors=n_motors)
    spec = next(
        s for s in benchmark_specs([cat], repeat, random_state)
        if s.setting.name == setting and s.repeat == repeat
    )
    return simulate_runs(
        [spec], mechanism=mechanism, field=_benchmark_field(random_state), rate_hz=rate_hz
    )


def _columns(n_motors):
    return [f"q{j + 1}" for j in range(n_motors)] + [f"tau{j + 1}" for j in range(n_motors)]


@pytest.mark.parametrize(
    "mechanism, n_motors, rate_hz, n_steps",
    [
        ("play", 2, 10.0, None),  # the whole motion phase
        ("bouc_wen", 1, 10.0, 400),
        ("dahl_creep", 3, 10.0, 400),
        ("play", 2, 25.0, 400),
    ],
)
def test_replaying_the_benchmark_motor_path_records_the_benchmark_run(mechanism, n_motors, rate_hz, n_steps):
    bench = _benchmark_run(2, "S05", 1, mechanism=mechanism, n_motors=n_motors, rate_hz=rate_hz)
    X = bench.X
    rig = SimulatedCatheter(
        2, "S05", mechanism=mechanism, n_motors=n_motors, rate_hz=rate_hz, tracker=True
    )
    sweep = rig.reset()
    n_sweep = len(sweep)
    assert n_sweep == bench.runs["n_sweep"].iloc[0]
    # the sweep rows, every column
    assert list(sweep.columns) == list(X.columns)
    for col in X.columns:
        assert_array_equal(sweep[col].to_numpy(), X[col].to_numpy()[:n_sweep], err_msg=col)
    assert (sweep["phase"] == "sweep").all()
    # the motion: the command of each step is the angle of the sample after the record
    cols = _columns(n_motors)
    q = X[cols[:n_motors]].to_numpy()
    stop = len(X) if n_steps is None else n_sweep + 1 + n_steps
    records, tips = [], []
    for command in q[n_sweep + 1 : stop]:
        obs = rig.step(command)
        records.append([obs[c] for c in ["t", *cols, "x", "y", "z"]])
        tips.append(rig.tip_)
    m = len(records)
    expected = np.column_stack([X[["t", *cols]].to_numpy()[n_sweep : n_sweep + m], bench.y[n_sweep : n_sweep + m]])
    assert_array_equal(np.array(records), expected)
    assert_array_equal(np.array(tips), bench.y_true[n_sweep : n_sweep + m])
    assert rig.n_steps_ == m and rig.n_clipped_ == 0


def test_the_record_holds_the_tracked_tip_only_with_the_tracker_on():
    on = SimulatedCatheter(3, "S00", tracker=True)
    off = SimulatedCatheter(3, "S00", tracker=False)
    on.reset(), off.reset()
    for command in ([0.0, 0.0], [5.0, -3.0], [10.0, -6.0]):
        a, b = on.step(command), off.step(command)
    assert list(a) == ["t", "q1", "q2", "tau1", "tau2", "x", "y", "z"]
    assert list(b) == ["t", "q1", "q2", "tau1", "tau2"]
    assert all(a[k] == b[k] for k in b)
    assert_array_equal(on.tip_, off.tip_)
    # the tracked tip is the noise-free one plus sensor noise of a fraction of a mm
    assert 0.0 < np.linalg.norm([a["x"] - on.tip_[0], a["y"] - on.tip_[1], a["z"] - on.tip_[2]]) < 3.0


def _drive(rig, commands):
    rig.reset()
    return np.array([[rig.step(c)[k] for k in ("q1", "tau1", "x")] + list(rig.tip_) for c in commands])


def test_same_parameters_same_run_and_random_state_changes_it():
    commands = np.linspace([0.0, 0.0], [30.0, -20.0], 40)
    first = _drive(SimulatedCatheter(4, "S09", tracker=True, mechanism="bouc_wen"), commands)
    rig = SimulatedCatheter(4, "S09", tracker=True, mechanism="bouc_wen")
    assert_array_equal(_drive(rig, commands), first)
    assert_array_equal(_drive(rig, commands), first)  # reset starts the same run again
    other = _drive(SimulatedCatheter(4, "S09", tracker=True, mechanism="bouc_wen", random_state=1), commands)
    assert not np.allclose(other[:, 3:], first[:, 3:])
    again = _drive(SimulatedCatheter(4, "S09", tracker=True, mechanism="bouc_wen", repeat=2), commands)
    assert not np.array_equal(again[:, 2], first[:, 2])


def test_a_catheter_object_named_like_a_unit_is_that_unit():
    commands = np.linspace([0.0, 0.0], [20.0, 10.0], 10)
    by_number = _drive(SimulatedCatheter(2, "S03", tracker=True), commands)
    by_unit = _drive(SimulatedCatheter(benchmark_catheter(2), "S03", tracker=True), commands)
    assert_array_equal(by_unit, by_number)
    stiffer = dataclasses.replace(benchmark_catheter(2), max_bend=0.5 * benchmark_catheter(2).max_bend)
    changed = _drive(SimulatedCatheter(stiffer, "S03", tracker=True), commands)
    assert not np.allclose(changed[:, 3:], by_number[:, 3:])


def test_stepping_past_the_benchmark_run_goes_on_with_drifts_of_its_own():
    rig = SimulatedCatheter(1, "S02", rate_hz=2.0, tracker=True)
    sweep = rig.reset()
    n_motion = rig.run_length_ - len(sweep)
    t, tips = [], []
    for _ in range(n_motion + 250):  # past the run's end, into two extra blocks of 60 s
        obs = rig.step([20.0, 20.0])
        t.append(obs["t"])
        tips.append(rig.tip_)
    assert_array_equal(np.diff(t), 0.5)
    tips = np.array(tips)
    assert np.all(np.isfinite(tips))
    # held motors, once settled: the tip moves only with the slow drifts, with
    # no jump where the run's own draws end and the extra blocks start
    assert np.abs(np.diff(tips[50:], axis=0)).max() < 0.1
    assert np.ptp(tips[-250:], axis=0).max() > 1e-3


def test_bad_commands_raise_naming_the_command():
    rig = SimulatedCatheter(1, "S00", n_motors=2)
    with pytest.raises(NotFittedError, match="reset"):
        rig.step([0.0, 0.0])
    rig.reset()
    with pytest.raises(ValueError, match="finite"):
        rig.step([np.nan, 0.0])
    with pytest.raises(ValueError, match="finite"):
        rig.step([np.inf, 0.0])
    with pytest.raises(ValueError, match=r"n_motors=2"):
        rig.step([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"n_motors=2"):
        rig.step([[1.0, 2.0]])
    with pytest.raises(ValueError, match="command"):
        rig.step(["a", "b"])
    assert rig.n_steps_ == 0  # a refused command does not advance the rig
    command = np.array([1.0, 2.0])
    rig.step(command)
    assert_array_equal(command, [1.0, 2.0])


def test_commands_beyond_the_motor_range_are_clipped_with_a_warning():
    rig = SimulatedCatheter(1, "S00", n_motors=1, motor_limit_deg=45.0)
    rig.reset()
    with pytest.warns(MotorLimitWarning, match="motor_limit_deg"):
        rig.step([80.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once per run
        obs = rig.step([-100.0])
        assert obs["q1"] == 45.0
        obs = rig.step([0.0])
    assert obs["q1"] == -45.0
    assert rig.n_clipped_ == 2
    rig.reset()
    assert rig.n_clipped_ == 0


@pytest.mark.parametrize(
    "params, match",
    [
        ({"mechanism": "backlash"}, "mechanism"),
        ({"setting": "S99"}, "setting"),
        ({"catheter": 0}, "catheter"),
        ({"n_motors": 4}, "n_motors"),
        ({"catheter": benchmark_catheter(1, n_motors=2), "n_motors": 1}, "n_motors"),
        ({"motor_limit_deg": 0.0}, "motor_limit_deg"),
        ({"run_variation": {"bogus": 1.0}}, "run_variation"),
    ],
)
def test_bad_parameters_raise_at_reset(params, match):
    rig = SimulatedCatheter(**params)  # __init__ only stores
    with pytest.raises(ValueError, match=match):
        rig.reset()


def test_a_unit_must_be_named_like_a_benchmark_unit_and_a_setting_like_a_benchmark_setting():
    cat = dataclasses.replace(benchmark_catheter(1), name="mine")
    with pytest.raises(ValueError, match="'C1', 'C2'"):
        SimulatedCatheter(cat).reset()
    setting = dataclasses.replace(shaft_settings()[3], name="bent")
    with pytest.raises(ValueError, match="'bent' is not one of the benchmark's settings"):
        SimulatedCatheter(1, setting).reset()


def test_a_lost_tip_sensor_gives_a_nan_tip_in_the_record_only():
    rig = SimulatedCatheter(2, "S07", tracker=True, dropout_rate=0.3, rate_hz=2.0)
    sweep = rig.reset()
    lost_sweep = sweep["ref_x"].isna().mean()
    assert 0.2 < lost_sweep < 0.4
    records, tips = [], []
    for k in range(200):
        records.append(rig.step([0.1 * k, -0.05 * k])["x"])
        tips.append(rig.tip_)
    assert 0.15 < np.isnan(records).mean() < 0.45
    assert np.all(np.isfinite(tips))


@pytest.mark.parametrize("mechanism, n_motors", [("play", 2), ("bouc_wen", 1), ("dahl_creep", 3)])
def test_tips_ahead_are_the_tips_the_steps_along_each_path_show(mechanism, n_motors):
    rig = SimulatedCatheter(catheter=2, setting="S05", mechanism=mechanism, n_motors=n_motors)
    rig.reset()
    rng = np.random.default_rng(0)
    for command in rng.uniform(-20, 20, size=(5, n_motors)):
        rig.step(command)
    start = rig.sweep_[[f"q{j + 1}" for j in range(n_motors)]].to_numpy()[-1]
    # three candidates: two smooth moves and one that crosses the motor limit (clipped as step clips)
    ends = np.array([np.full(n_motors, 25.0), np.full(n_motors, -30.0), np.full(n_motors, 90.0)])
    paths = start + (ends - start) * np.linspace(0.1, 1.0, 8)[:, None, None]
    state, before = copy.deepcopy(rig), copy.deepcopy(rig)
    tips = rig.tips_ahead(paths)
    assert tips.shape == (8, 3, 3)
    # the rig did not move
    assert rig.n_steps_ == before.n_steps_
    assert rig.step(np.zeros(n_motors)) == before.step(np.zeros(n_motors))
    assert_array_equal(rig.step(np.ones(n_motors))["q1"], before.step(np.ones(n_motors))["q1"])
    assert_array_equal(rig.tip_, before.tip_)
    for c in range(3):
        walked = copy.deepcopy(state)
        seen = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MotorLimitWarning)
            for command in [*paths[:, c], paths[-1, c]]:
                walked.step(command)
                seen.append(walked.tip_)
        np.testing.assert_allclose(tips[:, c], np.array(seen[1:]), atol=1e-9)
    # different paths reach different tips
    assert np.linalg.norm(tips[-1, 0] - tips[-1, 1]) > 1.0


def test_tips_ahead_and_play_crossing_check_their_input():
    rig = SimulatedCatheter(catheter=2, setting="S05")
    with pytest.raises(NotFittedError, match="reset"):
        rig.tips_ahead(np.zeros((1, 1, 2)))
    rig.reset()
    with pytest.raises(ValueError, match=r"paths must have shape \(n_ahead, n_candidates, 2\)"):
        rig.tips_ahead(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="paths must be finite"):
        rig.tips_ahead(np.full((1, 1, 2), np.nan))
    with pytest.raises(ValueError, match="command must hold one angle per motor"):
        rig.play_crossing([1.0, 2.0, 3.0])


def test_play_crossing_grows_with_the_load_and_is_nan_without_a_play():
    rig = SimulatedCatheter(catheter=2, setting="S12")
    rig.reset()
    rest, loaded = rig.play_crossing([0.0, 0.0]), rig.play_crossing([40.0, 0.0])
    assert np.all(rest > 0)
    assert loaded[0] > rest[0] and loaded[1] > rest[1]  # its own load, and the other motor's (cross load)
    other = SimulatedCatheter(catheter=2, setting="S12", mechanism="bouc_wen")
    other.reset()
    assert np.all(np.isnan(other.play_crossing([0.0, 0.0])))
