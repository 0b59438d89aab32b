"""Tests of the closed-loop tasks, their runner and their scores (skcath.datasets._tasks)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from skcath.datasets import (
    SimulatedCatheter,
    Task,
    circle_task,
    figure_eight_task,
    reach_task,
    run_task,
    standard_tasks,
    task_scores,
)


@pytest.fixture(scope="module")
def rig():
    return SimulatedCatheter(3, "S04", mechanism="bouc_wen", rate_hz=5.0, tracker=True)


@pytest.fixture(scope="module")
def sweep(rig):
    return rig.reset()


class ReplayController:
    """Replays a fixed motor path, whatever the target; records what it is given."""

    def __init__(self, path):
        self.path = np.asarray(path, dtype=float)

    def start(self, sweep):
        self.sweeps = getattr(self, "sweeps", []) + [sweep]
        self.targets, self.observations, self.k = [], [], 0

    def step(self, target, obs):
        self.targets.append(target)
        self.observations.append(dict(obs))
        command = self.path[self.k]
        self.k += 1
        self.estimate_ = np.full(3, float(self.k))
        return command


def test_run_task_calls_the_controller_once_per_target_and_scores_where_commands_act(rig, sweep):
    n = 12
    task = Task("demo", sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()[-n:], 5.0, (), np.ones(n, dtype=bool))
    path = np.column_stack([np.linspace(0.0, 30.0, n), np.linspace(0.0, -20.0, n)])
    controller = ReplayController(path)
    result = run_task(rig, controller, task)
    assert len(controller.sweeps) == 1
    assert_array_equal(controller.sweeps[0], sweep)
    assert_array_equal(np.array(controller.targets), task.target)
    assert_array_equal(result.command, path)
    assert_array_equal(result.estimate, np.arange(1, n + 1)[:, None] * np.ones(3))
    # the records follow each other from the first motion sample on, tracked
    t_obs = np.array([o["t"] for o in controller.observations])
    assert_allclose(t_obs, (len(sweep) + np.arange(n)) / 5.0)
    assert all({"x", "y", "z"} <= set(o) for o in controller.observations)
    # the first record is the run's first motion sample (the protocol's angle, near
    # neutral), the second holds the last sweep angles; a command is the angle two records on
    assert abs(controller.observations[0]["q1"]) < 0.5
    assert controller.observations[1]["q1"] == sweep["q1"].iloc[-1]
    for i in range(n - 2):
        assert controller.observations[i + 2]["q1"] == path[i, 0]
    # scored at the sample each command takes effect: its time and its true tip
    assert_allclose(result.t, (len(sweep) + 2 + np.arange(n)) / 5.0)
    replay = SimulatedCatheter(**rig.get_params())
    replay.reset()
    replay.step(sweep[["q1", "q2"]].to_numpy()[-1])
    tips = []
    for command in [*path, path[-1]]:
        replay.step(command)
        tips.append(replay.tip_)
    assert_array_equal(result.tip, np.array(tips[1:]))
    assert_allclose(result.error, np.linalg.norm(result.tip - task.target, axis=1))


def test_a_controller_without_an_estimate_returns_none(rig, sweep):
    class Hold:
        def start(self, sweep):
            pass

        def step(self, target, obs):
            return [0.0, 0.0]

    task = Task("demo", np.zeros((3, 3)), 5.0, (), np.ones(3, dtype=bool))
    assert run_task(rig, Hold(), task).estimate is None


def test_run_task_refuses_a_task_at_another_rate(rig, sweep):
    task = Task("demo", np.zeros((3, 3)), 10.0, (), np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match="rate_hz"):
        run_task(rig, ReplayController(np.zeros((3, 2))), task)


def _result(error, changes=(), scored=None, rate_hz=10.0):
    error = np.asarray(error, dtype=float)
    scored = np.ones(len(error), dtype=bool) if scored is None else scored
    task = Task("reach" if changes else "path", np.zeros((len(error), 3)), rate_hz, changes, scored)
    return type("R", (), {"task": task, "error": error})()


def test_scores_rms_p95_and_settling_time():
    # target 1 held from its 4th sample on, target 2 from its 10th (last), target 3 never
    error = [5, 5, 3, 1, 1, 1, 1, 1, 1, 1] + [5] * 9 + [1] + [1] * 9 + [4]
    scores = task_scores(_result(error, changes=(0, 10, 20)))
    assert scores["settling_s"] == pytest.approx(0.9)  # median of 0.3, 0.9, inf
    assert scores["settled"] == pytest.approx(2 / 3)
    assert scores["rms_mm"] == pytest.approx(np.sqrt(np.mean(np.square(error))))
    flat = task_scores(_result(np.full(40, 3.0)))
    assert flat["rms_mm"] == pytest.approx(3.0) and flat["p95_mm"] == pytest.approx(3.0)
    assert np.isnan(flat["settling_s"])
    # samples not scored (a lead-in) do not count
    scored = np.arange(40) >= 10
    lead = task_scores(_result(np.where(scored, 2.0, 50.0), scored=scored))
    assert lead["rms_mm"] == pytest.approx(2.0)
    assert task_scores(_result([3.0, 1.0, 1.0], changes=(0,)), settle_mm=0.5)["settled"] == 0.0


def test_reach_targets_are_tips_the_sweep_reached_within_the_shrunk_motor_range(sweep):
    task = reach_task(sweep, n_targets=4, hold_s=2.0, shrink=0.5, random_state=0)
    assert task.target.shape == (4 * 10, 3) and task.changes == (0, 10, 20, 30)
    assert task.rate_hz == 5.0 and task.duration_s == pytest.approx(8.0)
    tips = sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()
    magnitude = np.linalg.norm(sweep[["q1", "q2"]].to_numpy(), axis=1)
    for k in task.changes:
        row = np.flatnonzero(np.all(tips == task.target[k], axis=1))
        assert row.size and magnitude[row].min() <= 0.5 * magnitude.max()
        assert np.all(task.target[k : k + 10] == task.target[k])
    again = reach_task(sweep, n_targets=4, hold_s=2.0, shrink=0.5, random_state=0)
    assert_array_equal(again.target, task.target)
    other = reach_task(sweep, n_targets=4, hold_s=2.0, shrink=0.5, random_state=1)
    assert not np.array_equal(other.target, task.target)


@pytest.mark.parametrize("make", [circle_task, figure_eight_task])
@pytest.mark.parametrize("speed", [2.0, 8.0])
def test_paths_move_at_the_tip_speed_inside_the_swept_workspace(sweep, make, speed):
    task = make(sweep, speed_mm_s=speed)
    path = task.target[task.scored]
    step = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert_allclose(step, speed / 5.0, rtol=0.02)
    # the lead-in starts at the neutral tip; the path closes on itself
    rest = np.all(sweep[["q1", "q2"]].abs().to_numpy() <= 0.5, axis=1)
    neutral = np.median(sweep.loc[rest, ["ref_x", "ref_y", "ref_z"]].to_numpy(), axis=0)
    assert np.linalg.norm(task.target[0] - neutral) < 1e-9
    assert np.linalg.norm(path[-1] - path[0]) < 2.0 * speed / 5.0
    tips = sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()
    assert np.all(path >= tips.min(axis=0)) and np.all(path <= tips.max(axis=0))
    # on the reachable surface: within a few mm of a tip the sweep reached
    nearest = np.min(np.linalg.norm(path[:, None, :] - tips[None, ::5, :], axis=2), axis=1)
    assert nearest.max() < 15.0


def test_a_one_motor_sweep_gets_the_reach_task_only():
    sweep = SimulatedCatheter(1, "S00", n_motors=1, rate_hz=2.0).reset()
    with pytest.raises(ValueError, match="two or three motors"):
        circle_task(sweep)
    tasks = standard_tasks(sweep, random_state=0)
    assert [t.name for t in tasks] == ["reach"]


def test_a_sweep_without_the_tracked_tip_is_refused(sweep):
    with pytest.raises(ValueError, match="ref_x"):
        reach_task(sweep.drop(columns=["ref_x"]))
    with pytest.raises(ValueError, match="at least 10"):
        reach_task(sweep.head(5))
