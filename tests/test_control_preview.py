"""Tests of the controllers' path preview (``preview``, ``step(..., upcoming=...)``).

Without preview the controllers command what they did before, whatever
``upcoming`` holds. With it, on one motor behind a play and a rate limit
(no model needed: :func:`plan` and :func:`lead` alone), a reversal is
crossed before the wanted angle turns and the played angle's error there
is smaller; the controllers keep every command within the rate and motor
limits; bad ``upcoming`` raises naming it.
"""

import importlib.util
import warnings

import numpy as np
import pytest
from sklearn.pipeline import Pipeline

from skcath.backbones import PCCBackbone
from skcath.control import FeedbackController, FeedforwardController, UnreachableTargetWarning
from skcath.control._hysteresis import PlayInverse
from skcath.control._preview import lead, plan
from skcath.datasets import SimulatedCatheter, Task, circle_task, run_task, simulate_run
from skcath.online import OnlineEstimator
from skcath.residuals import NoResidual

CHANNELS = ["q1", "q2", "tau1", "tau2"]


def _model_path(hysteresis):
    """A PCC pipeline with ``hysteresis`` fitted on a run (S02), the sweep of another (S05), and model tips along a path."""
    train = simulate_run(setting="S02", random_state=1)
    backbone = PCCBackbone(hysteresis=hysteresis).fit(train.X)
    pipe = Pipeline([("backbone", backbone),
                     ("residual", NoResidual().fit(backbone.transform(train.X), np.asarray(train.y)))])
    test = simulate_run(setting="S05", random_state=2).X
    sweep = test[test["phase"] == "sweep"]
    est = OnlineEstimator(pipe).start(sweep)
    torques = sweep[["tau1", "tau2"]].to_numpy()[-1]
    k = np.arange(90)
    # motor angles that reverse every 15 samples on the first motor, slowly on the second
    q = est.q_neutral_ + np.c_[25.0 * np.sin(2 * np.pi * k / 30), 10.0 * np.sin(2 * np.pi * k / 90)]
    targets = np.array([est.step(*row, *torques).copy() for row in q])
    return pipe, sweep, targets


@pytest.fixture(scope="module")
def setup():
    """The pipeline with the play, its sweep and the model tips along reversing motors."""
    return _model_path("play")


class Plant:
    """The pipeline's own streaming tip at the commanded angles, its record one command late (the rig's timing)."""

    def __init__(self, pipe, sweep):
        self.est = OnlineEstimator(pipe).start(sweep)
        last = sweep[CHANNELS].to_numpy()[-1]
        self.torques = tuple(last[2:])
        self.obs = dict(zip(CHANNELS, last))
        self.pending = self.obs

    def step(self, command):
        tip = self.est.step(*command, *self.torques).copy()
        self.obs, self.pending = self.pending, {**dict(zip(CHANNELS, (*command, *self.torques))),
                                                "x": tip[0], "y": tip[1], "z": tip[2]}
        return tip


def _drive(controller, plant, targets, preview):
    """Tips (mm) and commands (deg), the controller given the next ``preview`` targets when ``preview``."""
    tips, commands = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnreachableTargetWarning)
        for i, target in enumerate(targets):
            upcoming = targets[i + 1:i + 1 + preview] if preview else None
            commands.append(controller.step(target, plant.obs, upcoming=upcoming))
            tips.append(plant.step(commands[-1]))
    return np.array(tips), np.array(commands)


def _one_motor(z_wanted, width, max_step, horizon):
    """Commands and played angles of one motor behind a play, the receding preview of ``horizon`` samples."""
    inverse, project = PlayInverse(width), lambda q: q
    z, q = np.zeros(1), np.array([width])  # at rest, the motor pushing up
    commands, played = [], []
    for t in range(len(z_wanted)):
        u = plan(inverse, z_wanted[t:t + 1 + horizon, None], z, q, project)
        q_new = lead(u, max_step)
        q = q + np.clip(q_new - q, -max_step, max_step)
        z = inverse.follow(z, q)
        commands.append(q[0])
        played.append(z[0])
    return np.array(commands), np.array(played)


def test_a_reversal_is_crossed_before_it_and_its_error_is_smaller():
    """One motor, a play of 2 x 8 deg, 3 deg per sample: the crossing starts before the peak, half made there."""
    k = np.arange(160)
    z_wanted = 30.0 * np.sin(2 * np.pi * k / 80)  # peaks at samples 20, 100, at most 2.4 deg per sample
    width, max_step = 8.0, 3.0
    late, late_z = _one_motor(z_wanted, width, max_step, 0)
    early, early_z = _one_motor(z_wanted, width, max_step, 8)
    peak = 100
    first_down = [90 + int(np.flatnonzero(np.diff(q[90:]) < 0)[0]) + 1 for q in (late, early)]
    # without preview the motor turns back once the wanted angle has; with it, before the peak
    assert first_down[0] == peak + 1 and first_down[1] <= peak - 2
    # the crossing (2 x 8 deg) is about half made at the peak: the motor near the wanted angle there
    assert abs(early[peak] - z_wanted[peak]) <= max_step and late[peak] == pytest.approx(z_wanted[peak] + width)
    near = slice(peak - 5, peak + 8)
    error_late = np.abs(late_z - z_wanted)[near]
    error_early = np.abs(early_z - z_wanted)[near]
    assert error_early.max() < 0.85 * error_late.max()
    # the rate limit holds, and a path the motor can follow is not changed
    assert np.abs(np.diff(early)).max() <= max_step + 1e-12
    slow = 2.0 * np.sin(2 * np.pi * k / 40)
    np.testing.assert_array_equal(_one_motor(slow, 0.0, max_step, 8)[0], _one_motor(slow, 0.0, max_step, 0)[0])


def test_lead_is_the_midpoint_of_the_rate_envelopes():
    """A jump of w = 12 at 4 per sample: started w / R = 3 samples before at half the rate, half made at the jump."""
    u = np.array([[0.0]] * 4 + [[12.0]] * 4)  # the jump between samples 3 and 4
    # 4 samples ahead: max(u - R s) = 12 - 16 < 0, nothing yet; 3 ahead: (12 - 12 + 0) / 2 = 0 still
    assert lead(u, 4.0).tolist() == [0.0] and lead(u[1:], 4.0).tolist() == [0.0]
    # then 2, 4 and at the jump 6 = w / 2; after it, all wanted at 12 (the rate limit brings the rest)
    assert [lead(u[k:], 4.0)[0] for k in (2, 3, 4)] == [2.0, 4.0, 12.0]
    assert lead(u, np.inf).tolist() == [0.0] and lead(u[:1], 4.0).tolist() == [0.0]
    # two motors, opposite jumps; a path the rate allows is left as it is
    both = np.hstack([u[2:], -u[2:]])
    np.testing.assert_allclose(lead(both, 4.0), [2.0, -2.0])
    ramp = np.c_[3.0 * np.arange(6), -4.0 * np.arange(6)]
    assert lead(ramp, 4.0).tolist() == [0.0, 0.0]


@pytest.mark.parametrize("Controller", [FeedforwardController, FeedbackController])
def test_preview_zero_commands_as_without_it(setup, Controller):
    """preview=0 reads no upcoming targets: the same commands, digit for digit, with or without them."""
    pipe, sweep, targets = setup
    got = []
    for upcoming in (0, 5):
        controller = Controller(pipe, rate_limit=60.0, engine="numpy").start(sweep)
        got.append(_drive(controller, Plant(pipe, sweep), targets, upcoming)[1])
    np.testing.assert_array_equal(got[0], got[1])
    assert Controller(pipe).preview == 0


def test_a_held_target_is_commanded_as_without_preview(setup):
    """Reach targets, each held and previewed as held (its successor unknown): the commands of no preview."""
    pipe, sweep, targets = setup
    held = np.repeat(targets[[10, 60, 30]], 12, axis=0)
    got = []
    for preview in (0, 6):
        controller = FeedbackController(pipe, rate_limit=60.0, preview=preview, engine="numpy").start(sweep)
        plant, commands = Plant(pipe, sweep), []
        for i, target in enumerate(held):
            end = (i // 12 + 1) * 12  # the present target's samples only
            commands.append(controller.step(target, plant.obs, upcoming=held[i + 1:min(i + 1 + preview, end)]))
            plant.step(commands[-1])
        got.append(np.array(commands))
    np.testing.assert_array_equal(got[0], got[1])


@pytest.mark.parametrize("Controller", [FeedforwardController, FeedbackController])
def test_preview_keeps_the_limits_and_tracks_the_reversals_better(setup, Controller):
    """On the model's own tips along reversing motors: within the rate and motor limits, and closer at the reversals."""
    pipe, sweep, targets = setup
    rate = 60.0
    errors, all_commands = {}, {}
    for preview in (0, 8):
        controller = Controller(pipe, rate_limit=rate, preview=preview).start(sweep)
        previous = controller.command_.copy()
        tips, commands = _drive(controller, Plant(pipe, sweep), targets, preview)
        steps = np.abs(np.diff(np.vstack([previous, commands]), axis=0))
        assert steps.max() <= rate * controller.dt_ + 1e-9
        assert all(controller.limits_.contains(c) for c in commands)
        errors[preview] = np.linalg.norm(tips[:-1] - targets[1:], axis=1)  # latency 1: command i is sample i + 1
        all_commands[preview] = commands
    assert not np.array_equal(all_commands[0], all_commands[8])
    assert np.sqrt(np.mean(errors[8][20:] ** 2)) < 0.9 * np.sqrt(np.mean(errors[0][20:] ** 2))


def test_bad_upcoming_and_engine_raise_naming_them(setup):
    pipe, sweep, targets = setup
    controller = FeedbackController(pipe, preview=4).start(sweep)
    obs = Plant(pipe, sweep).obs
    with pytest.raises(ValueError, match=r"upcoming must have shape \(k, 3\)"):
        controller.step(targets[0], obs, upcoming=targets[1])
    with pytest.raises(ValueError, match=r"upcoming must have shape \(k, 3\).*\(4, 2\)"):
        controller.step(targets[0], obs, upcoming=targets[1:5, :2])
    bad = targets[1:5].copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="upcoming must be finite.*row 2"):
        controller.step(targets[0], obs, upcoming=bad)
    with pytest.raises(ValueError, match="upcoming must be an array"):
        controller.step(targets[0], obs, upcoming=[[1.0, 2.0, "far"]])
    assert np.isnan(bad[2, 1])  # not modified
    controller.step(targets[0], obs, upcoming=np.empty((0, 3)))  # nothing ahead known: no preview


def test_run_task_passes_the_known_targets_ahead():
    """A path's next targets up to its end; a reach task's up to the present target's end."""

    class Recorder:
        def __init__(self):
            self.seen = []

        def start(self, sweep):
            self.q = sweep[["q1", "q2"]].to_numpy()[-1]

        def step(self, target, obs, upcoming=None):
            self.seen.append((target, upcoming))
            return self.q

    rig = SimulatedCatheter(catheter=1, setting="S05", random_state=0)
    task = circle_task(rig.reset(), speed_mm_s=10.0, n_laps=0.05)
    recorder = Recorder()
    run_task(rig, recorder, task, preview=3)
    n = len(task.target)
    for i, (target, upcoming) in enumerate(recorder.seen):
        np.testing.assert_array_equal(upcoming, task.target[i + 1:min(i + 4, n)])
    reach = Task("reach", np.repeat(task.target[[0, 5, 9]], 4, axis=0), task.rate_hz, changes=(0, 4, 8))
    recorder = Recorder()
    run_task(rig, recorder, reach, preview=3)
    for i, (target, upcoming) in enumerate(recorder.seen):
        np.testing.assert_array_equal(upcoming, reach.target[i + 1:min(i + 4, (i // 4 + 1) * 4)])
    with pytest.raises(ValueError, match="preview must be"):
        run_task(rig, recorder, task, preview=-1)


def test_plan_through_the_pi_leaves_the_stream_alone_and_gives_the_wanted_angles():
    """The PI's plan steps a copy of the forward state: each planned command's forward step is its wanted angle."""
    from skcath.backbones import PrandtlIshlinskii
    from skcath.control._hysteresis import PIInverse

    rng = np.random.default_rng(3)
    model = PrandtlIshlinskii([0.0, 0.5, 1.4, 4.0], [0.4, 0.0, 0.35, 0.25], dead_band=1.2,
                              asymmetry=[0.2, -0.3], creep_gain=0.2, creep_tau_s=2.0)
    q = np.cumsum(rng.normal(0.0, 3.0, (40, 2)), axis=0)
    v, state = model.forward(q, np.arange(40) * 0.1, return_state=True)
    inverse = PIInverse(model, state, np.array([0.1]))
    before = state.copy()
    z_ahead = v[-1] + np.cumsum(rng.normal(0.0, 2.0, (12, 2)), axis=0)  # reversals included
    u = plan(inverse, z_ahead, v[-1], q[-1], lambda x: x)
    assert inverse.state is state and np.array_equal(state, before)  # the stream's state, untouched
    forward, reached = state.copy(), []
    for command in u:
        forward, effective = model.step(forward, command, 0.1)
        reached.append(effective)
    np.testing.assert_allclose(reached, z_ahead, atol=1e-9)


needs_numba = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="the numba engine needs numba")


def _both_engines(make, pipe, sweep, targets, preview, windows=None):
    """Commands, aims and corrections of ``make(engine)`` on both engines, the next targets given as ``windows`` says."""
    got = {}
    for engine in ("numpy", "numba"):
        controller = make(engine).start(sweep)
        assert (controller._compiled is not None) == (engine == "numba")
        plant, record = Plant(pipe, sweep), []
        plant.obs = plant.pending = {**plant.obs, **dict(zip("xyz", sweep[["ref_x", "ref_y", "ref_z"]].iloc[-1]))}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnreachableTargetWarning)
            for i, target in enumerate(targets):
                upcoming = targets[i + 1:i + 1 + preview] if windows is None else windows(i)
                command = controller.step(target, plant.obs, upcoming=upcoming)
                record.append([*command, *controller.aimed_, *getattr(controller, "correction_", ())])
                plant.step(command)
        got[engine] = (np.array(record), controller.n_unreachable_)
    return got


@needs_numba
@pytest.mark.parametrize("case", ["feedforward", "internal-model", "tracker, limits", "resolved-rate"])
def test_compiled_preview_gives_the_numpy_engines_commands(setup, case):
    """With preview on the numba engine, the commands of the numpy engine's preview: each case of the step."""
    pipe, sweep, targets = setup
    # reversing motors, a held target, gaps in what is known ahead (None, nothing), an out-of-reach stretch
    path = np.vstack([targets[:50], np.repeat(targets[[60]], 6, axis=0), np.tile([[90.0, 40.0, 10.0]], (4, 1)),
                      targets[50:]])
    Controller, kwargs = {
        "feedforward": (FeedforwardController, {"rate_limit": 60.0}),
        "internal-model": (FeedbackController, {"rate_limit": 60.0}),
        "tracker, limits": (FeedbackController, {"close_on": "tracker", "rate_limit": 40.0, "dead_band": 0.5,
                                                 "motor_limits": [[-25.0, 25.0], [-40.0, 20.0]]}),
        "resolved-rate": (FeedbackController, {"feedforward": False, "gain": 0.5, "rate_limit": 60.0}),
    }[case]
    preview = 8

    def windows(i):
        if i % 23 == 5:
            return None
        return path[i + 1:i + 1 + (0 if i % 31 == 7 else preview)]

    got = _both_engines(lambda engine: Controller(pipe, preview=preview, engine=engine, **kwargs), pipe, sweep,
                        path, preview, windows)
    np.testing.assert_allclose(got["numba"][0], got["numpy"][0], atol=1e-6)
    assert got["numba"][1] == got["numpy"][1] >= 4  # the out-of-reach targets were met
    without = _both_engines(lambda engine: Controller(pipe, engine=engine, **kwargs), pipe, sweep, path[:40], 0)
    assert not np.allclose(without["numba"][0], got["numba"][0][:40])  # the preview changed the commands


@needs_numba
def test_compiled_preview_through_the_pi_gives_the_numpy_engines_commands():
    """The PI's plan in the compiled step (a copy of its forward state stepped): the numpy engine's commands."""
    pipe, sweep, targets = _model_path("pi")
    for Controller, kwargs in ((FeedforwardController, {"rate_limit": 60.0}),
                               (FeedbackController, {"rate_limit": 60.0, "dead_band": 0.5})):
        got = _both_engines(lambda engine: Controller(pipe, preview=6, engine=engine, **kwargs), pipe, sweep,
                            targets, 6)
        np.testing.assert_allclose(got["numba"][0], got["numpy"][0], atol=1e-6)


@needs_numba
def test_compiled_preview_on_a_task_gives_the_numpy_engines_commands(setup):
    """run_task on the simulated rig along a circle of a few hundred samples: both engines command the same."""
    pipe = setup[0]
    rig = SimulatedCatheter(catheter=1, setting="S05", random_state=0)
    task = circle_task(rig.reset(), speed_mm_s=5.0, n_laps=1.2)
    commands = {}
    for engine in ("numpy", "numba"):
        rig = SimulatedCatheter(catheter=1, setting="S05", random_state=0)
        controller = FeedbackController(pipe, rate_limit=40.0, preview=10, engine=engine)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnreachableTargetWarning)
            result = run_task(rig, controller, task, preview=10)
        commands[engine] = result.command
    assert len(commands["numpy"]) >= 200
    np.testing.assert_allclose(commands["numba"], commands["numpy"], atol=1e-6)
