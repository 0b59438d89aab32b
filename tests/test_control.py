"""Tests of the controllers of ``skcath.control``.

Open loop: the feedforward command for the model's own predicted tips
recovers the motor path that produced them (for a backbone with and without
the play in front). Closed loop: a plant made of a fitted model (another
calibration than the controller's, so that the controller's model is wrong)
is driven to reachable targets by the feedback controllers, on the tracker
and, where the plant is the controller's own model, on the estimate. Then
the limits (motor and rate limits never exceeded, unreachable targets
clipped with a warning) and the bad inputs.
"""

import importlib.util
import warnings

import numpy as np
import pandas as pd
import pytest
from sklearn.exceptions import NotFittedError
from sklearn.pipeline import Pipeline
from sklearn.utils._param_validation import InvalidParameterError

from skcath.backbones import PCCBackbone, PDLBackbone, play_kernel
from skcath.control import FeedbackController, FeedforwardController, UnreachableTargetWarning
from skcath.control._hysteresis import IdentityInverse, PlayInverse
from skcath.datasets import simulate_run
from skcath.online import OnlineEstimator
from skcath.residuals import NoResidual

CHANNELS = ["q1", "q2", "tau1", "tau2"]
N_MOTION = 150


@pytest.fixture(scope="module")
def runs():
    """A training run (setting S02) and a test run (S05), the latter's motion cut short."""
    train = simulate_run(setting="S02", random_state=1)
    test = simulate_run(setting="S05", random_state=2).X
    sweep = test[test["phase"] == "sweep"]
    motion = test[test["phase"] == "motion"].iloc[:N_MOTION]
    return train.X, np.asarray(train.y), sweep, motion


@pytest.fixture(scope="module")
def pipes(runs):
    """Fitted pipelines of a backbone and NoResidual, keyed by (backbone class, hysteresis)."""
    X, y, _, _ = runs
    cache = {}

    def get(Backbone, hysteresis=None):
        if (Backbone, hysteresis) not in cache:
            backbone = Backbone(hysteresis=hysteresis).fit(X)
            residual = NoResidual().fit(backbone.transform(X), y)
            cache[Backbone, hysteresis] = Pipeline([("backbone", backbone), ("residual", residual)])
        return cache[Backbone, hysteresis]

    return get


class ModelPlant:
    """A plant whose tip is a fitted model's streaming estimate at the commanded angles.

    Its motors follow the command exactly; the torques are the last sweep
    sample's. ``offset`` (mm) is added to the tip it reports and stores.
    """

    def __init__(self, pipe, sweep, offset=(0.0, 0.0, 0.0)):
        self.est = OnlineEstimator(pipe).start(sweep)
        last = sweep[CHANNELS].to_numpy()[-1]
        self.torques = tuple(last[2:])
        self.offset = np.asarray(offset, dtype=float)
        x, y, z = sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()[-1]
        self.obs = {"q1": last[0], "q2": last[1], "tau1": last[2], "tau2": last[3], "x": x, "y": y, "z": z}
        self.tip = None

    def step(self, command):
        self.tip = self.est.step(*command, *self.torques) + self.offset
        self.obs = {"q1": command[0], "q2": command[1], "tau1": self.torques[0],
                    "tau2": self.torques[1], "x": self.tip[0], "y": self.tip[1], "z": self.tip[2]}
        return self.obs


def _drive(controller, plant, targets):
    """Tips (mm) and commands (deg) of the plant under ``controller``, one target per sample."""
    tips, commands = [], []
    for target in targets:
        command = controller.step(target, plant.obs)
        commands.append(command)
        plant.step(command)
        tips.append(plant.tip.copy())
    return np.array(tips), np.array(commands)


def _model_tips(pipe, sweep, motion):
    est = OnlineEstimator(pipe).start(sweep)
    return np.array([est.step(*s).copy() for s in motion[CHANNELS].to_numpy()])


@pytest.mark.parametrize("Backbone", [PCCBackbone, PDLBackbone])
@pytest.mark.parametrize("hysteresis", [None, "play"])
def test_feedforward_recovers_the_motor_path_of_the_model_tips(runs, pipes, Backbone, hysteresis):
    _, _, sweep, motion = runs
    pipe = pipes(Backbone, hysteresis)
    targets = _model_tips(pipe, sweep, motion)
    controller = FeedforwardController(pipe, latency=0).start(sweep)
    plant = ModelPlant(pipe, sweep)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnreachableTargetWarning)
        tips, commands = _drive(controller, plant, targets)
    error = np.linalg.norm(tips - targets, axis=1)
    # the tip of the next sample is the model's own: the inverse puts it on the target
    assert np.median(error) < 1e-3
    # the PDL backbone has flat regions (its dead zone) where the inverse stops a little short
    assert np.quantile(error, 0.95) < (0.05 if Backbone is PCCBackbone else 0.5)
    if Backbone is PCCBackbone and hysteresis is None:  # a one-to-one map: the path itself
        assert np.max(np.abs(commands - motion[["q1", "q2"]].to_numpy())) < 0.05


def test_play_inverse_commands_the_wanted_played_angle():
    rng = np.random.default_rng(0)
    inverse, width = PlayInverse(4.0), 4.0
    z, q = np.zeros(2), np.zeros(2)
    for wanted in rng.uniform(-30, 30, size=(50, 2)):
        q = inverse.command(wanted, z, q)
        z = np.array([play_kernel(zi, qi, width) for zi, qi in zip(z, q)])
        np.testing.assert_allclose(z, wanted, atol=1e-12)
    # a played angle already where it is wanted keeps the command within the play
    q_before = q.copy()
    assert np.array_equal(inverse.command(z, z, q_before), q_before)
    assert np.array_equal(IdentityInverse().command(z, None, None), z)


def test_play_inverse_beats_the_backbone_inverse_on_a_played_plant(runs, pipes):
    """Against a plant with a play, the inverse with the play tracks better than without."""
    _, _, sweep, motion = runs
    plant_pipe = pipes(PCCBackbone, "play")
    targets = _model_tips(plant_pipe, sweep, motion)
    errors = {}
    for hysteresis in (None, "play"):
        controller = FeedforwardController(pipes(PCCBackbone, hysteresis), latency=0).start(sweep)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnreachableTargetWarning)
            tips, _ = _drive(controller, ModelPlant(plant_pipe, sweep), targets)
        errors[hysteresis] = np.sqrt(np.mean(np.sum((tips - targets) ** 2, axis=1)))
    assert errors["play"] < 0.5 * errors[None]


@pytest.mark.parametrize("close_on", ["estimate", "tracker"])
@pytest.mark.parametrize("feedforward", [True, False])
def test_feedback_reaches_a_held_target(runs, pipes, close_on, feedforward):
    """Closed on the tracker, the loop removes an error of the model; on the estimate, it reaches the model's target."""
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone)
    target = _model_tips(pipe, sweep, motion)[80]
    offset = (1.5, -1.0, 0.0) if close_on == "tracker" else (0.0, 0.0, 0.0)
    # a plant whose tip is off the model's by an offset mostly across the tip's surface
    plant = ModelPlant(pipe, sweep, offset=offset)
    controller = FeedbackController(pipe, close_on=close_on, feedforward=feedforward, gain=0.5,
                                    latency=0).start(sweep)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnreachableTargetWarning)
        tips, _ = _drive(controller, plant, [target] * 60)
    feedforward_only = FeedforwardController(pipe, latency=0).start(sweep)
    ff_tips, _ = _drive(feedforward_only, ModelPlant(pipe, sweep, offset=offset), [target] * 60)
    final = np.linalg.norm(tips[-5:] - target, axis=1).max()
    if close_on == "tracker":
        # the offset's part across the surface is removed; the feedforward keeps it
        assert final < 0.5 * np.linalg.norm(ff_tips[-1] - target)
    else:
        assert final < 0.05


@pytest.mark.parametrize("Controller", [FeedforwardController, FeedbackController])
def test_rate_limit_is_never_exceeded(runs, pipes, Controller):
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone, "play")
    far = _model_tips(pipe, sweep, motion)[[20, 140]]
    targets = np.repeat(far, 15, axis=0)[np.r_[0:15, 15:30, 0:15]]
    rate = 20.0
    controller = Controller(pipe, rate_limit=rate, latency=0).start(sweep)
    previous = controller.command_.copy()
    _, commands = _drive(controller, ModelPlant(pipe, sweep), targets)
    steps = np.abs(np.diff(np.vstack([previous, commands]), axis=0))
    assert controller.dt_ == pytest.approx(0.1)
    assert steps.max() <= rate * controller.dt_ + 1e-9
    assert steps.max() > 0.9 * rate * controller.dt_  # the targets are far apart: the limit binds


@pytest.mark.parametrize("Controller", [FeedforwardController, FeedbackController])
def test_unreachable_target_is_clipped_with_a_warning(runs, pipes, Controller):
    _, _, sweep, _ = runs
    pipe = pipes(PCCBackbone)
    limits = [[-20.0, 20.0], [-30.0, 10.0]]
    controller = Controller(pipe, motor_limits=limits, latency=0).start(sweep)
    plant = ModelPlant(pipe, sweep)
    target = np.array([80.0, 80.0, 0.0])
    given = target.copy()
    with pytest.warns(UnreachableTargetWarning, match="reach_tol_mm"):
        command = controller.step(target, plant.obs)
    assert np.array_equal(target, given)
    assert np.all(command >= [-20.0, -30.0]) and np.all(command <= [20.0, 10.0])
    assert controller.n_unreachable_ == 1
    # the aimed tip is the model's tip nearest the target over the limit box
    est = OnlineEstimator(pipe).start(sweep)
    grid = np.stack(np.meshgrid(np.linspace(-20, 20, 41), np.linspace(-30, 10, 41)), -1).reshape(-1, 2)
    nearest = min(np.linalg.norm(np.array(est._backbone(*g)) - target) for g in grid)
    assert np.linalg.norm(controller.aimed_ - target) <= nearest + 1e-6
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnreachableTargetWarning)
        for _ in range(30):
            command = controller.step(target, plant.step(command))
            assert np.all(command >= [-20.0, -30.0]) and np.all(command <= [20.0, 10.0])


@pytest.mark.parametrize("engine", ["numpy", pytest.param("numba", marks=pytest.mark.skipif(
    importlib.util.find_spec("numba") is None, reason="the numba engine needs numba"))])
@pytest.mark.parametrize("Controller", [FeedforwardController, FeedbackController])
def test_unreachable_warning_as_error_leaves_the_step_complete(runs, pipes, Controller, engine):
    """With the warning an error, the step raises once complete: its command is ``command_``, as without the error."""
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone, "play")
    tips = _model_tips(pipe, sweep, motion)
    targets = np.vstack([tips[:10], np.tile([[80.0, 80.0, 0.0]], (3, 1)), tips[10:20]])
    records = {}
    for action in ("ignore", "error"):
        controller = Controller(pipe, engine=engine, motor_limits=[[-20.0, 20.0], [-30.0, 10.0]]).start(sweep)
        plant, record, raised = ModelPlant(pipe, sweep), [], 0
        with warnings.catch_warnings():
            warnings.simplefilter(action, UnreachableTargetWarning)
            for target in targets:
                try:
                    command = controller.step(target, plant.obs)
                except UnreachableTargetWarning:
                    raised += 1
                    command = controller.command_.copy()  # the step's command, issued
                record.append([*command, *controller.aimed_, *controller.estimate_])
                plant.step(command)
        records[action] = (np.array(record), controller.n_unreachable_, raised)
    assert records["error"][2] == records["error"][1] == records["ignore"][1] == 3
    # the commands, aims and estimates go on as if the warning had not been an error
    assert np.array_equal(records["error"][0], records["ignore"][0])


def test_steps_accept_series_dicts_and_sequences_alike(runs, pipes):
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone)
    target = _model_tips(pipe, sweep, motion)[30]
    rows = motion[CHANNELS + ["t"]].iloc[:5]
    outs = []
    for form in ("series", "dict", "tuple"):
        controller = FeedbackController(pipe).start(sweep)
        got = []
        for _, row in rows.iterrows():
            obs = {"series": row, "dict": row.to_dict(), "tuple": tuple(row[CHANNELS])}[form]
            got.append(controller.step(target, obs))
        outs.append(np.array(got))
    np.testing.assert_allclose(outs[0], outs[1])
    np.testing.assert_allclose(outs[0], outs[2])


def test_bad_inputs_raise_naming_them(runs, pipes):
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone)
    controller = FeedbackController(pipe, close_on="tracker")
    with pytest.raises(NotFittedError, match="start"):
        controller.step([0, 0, 50], {})
    controller.start(sweep)
    obs = {"q1": 1.0, "q2": 2.0, "tau1": 0.0, "tau2": 0.0, "t": 100.0, "x": 1.0, "y": 2.0, "z": 50.0}
    with pytest.raises(ValueError, match="target must be finite"):
        controller.step([0.0, np.nan, 50.0], obs)
    with pytest.raises(ValueError, match=r"target must have shape \(3,\)"):
        controller.step([0.0, 50.0], obs)
    with pytest.raises(ValueError, match="non-finite value.*q2"):
        controller.step([0.0, 0.0, 50.0], {**obs, "q2": np.nan})
    with pytest.raises(ValueError, match="non-finite value.*y"):
        controller.step([0.0, 0.0, 50.0], {**obs, "y": np.nan})
    with pytest.raises(ValueError, match="tracker.*x, y, z"):
        controller.step([0.0, 0.0, 50.0], {k: v for k, v in obs.items() if k not in "xyz"})
    with pytest.raises(ValueError, match="lacks the channel.*tau2"):
        controller.step([0.0, 0.0, 50.0], {k: v for k, v in obs.items() if k != "tau2"})
    with pytest.raises(ValueError, match="motor_limits"):
        FeedforwardController(pipe, motor_limits=[10.0, -10.0]).start(sweep)
    with pytest.raises(InvalidParameterError, match="rate_limit"):
        FeedforwardController(pipe, rate_limit=-1.0).start(sweep)
    with pytest.raises(InvalidParameterError, match="close_on"):
        FeedbackController(pipe, close_on="camera").start(sweep)
    with pytest.raises(ValueError, match="exactly one run|phase"):
        FeedforwardController(pipe).start(pd.concat([sweep, motion]))


class DelayedPlant(ModelPlant):
    """A :class:`ModelPlant` whose record of a sample comes one command later, as the simulated rig's."""

    def __init__(self, pipe, sweep):
        super().__init__(pipe, sweep)
        self.pending = (self.obs, None)

    def step(self, command):
        obs, tip = self.pending
        super().step(command)
        self.pending = (self.obs, self.tip.copy())
        self.obs, self.tip = obs, tip
        return obs


def test_latency_counts_the_commands_not_yet_observed(runs, pipes):
    """On a plant that shows a sample one command late, latency=1 puts the commanded tip on the target."""
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone, "play")
    targets = _model_tips(pipe, sweep, motion)
    controller = FeedforwardController(pipe, latency=1).start(sweep)
    plant = DelayedPlant(pipe, sweep)
    commands = []
    for target in targets:
        commands.append(controller.step(target, plant.obs))
        plant.step(commands[-1])
    # the tips of the commanded samples, each after the one commanded before it
    est = OnlineEstimator(pipe).start(sweep)
    torques = sweep[["tau1", "tau2"]].to_numpy()[-1]
    tips = np.array([est.step(*c, *torques).copy() for c in commands])
    assert np.quantile(np.linalg.norm(tips - targets, axis=1), 0.95) < 0.05


@pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="the numba engine needs numba")
def test_compiled_inverse_gives_the_commands_of_the_numpy_one(runs, pipes):
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone, "play")  # one command per tip: no dead zone to pick among equal commands
    targets = _model_tips(pipe, sweep, motion)
    commands = {}
    for engine in ("numpy", "numba"):
        controller = FeedbackController(pipe, engine=engine, latency=0).start(sweep)
        assert (controller._compiled is not None) == (engine == "numba")
        commands[engine] = _drive(controller, ModelPlant(pipe, sweep), targets)[1]
    np.testing.assert_allclose(commands["numba"], commands["numpy"], atol=1e-6)


def test_play_inverse_dead_band_holds_small_reversals_only():
    """Under jitter within the dead band the motor stays within the play; a larger reversal is made."""
    width, band = 4.0, 1.0
    inverse = PlayInverse(width, dead_band=band)
    z, q = np.zeros(1), np.zeros(1)
    q = inverse.command(np.array([10.0]), z, q)  # a move up: the motor pushes from below
    z = np.array([play_kernel(z[0], q[0], width)])
    np.testing.assert_allclose(z, [10.0])
    rng = np.random.default_rng(0)
    commands = []
    for jitter in rng.uniform(-0.4, 0.4, size=40):
        q = inverse.command(np.array([10.0 + jitter]), z, q)
        z = np.array([play_kernel(z[0], q[0], width)])
        commands.append(q[0])
    # motion up (the side the motor pushes) is followed, reversals within the band are not made
    assert np.ptp(commands) < 2.0 * width - 1.0
    assert abs(z[0] - 10.0) <= 0.4
    q = inverse.command(z - 3.0, z, q)  # a reversal larger than the band crosses the play
    np.testing.assert_allclose(play_kernel(z[0], q[0], width), z[0] - 3.0)
    jittery = PlayInverse(width)  # without a dead band the same jitter swings the motor across the play
    z, q, commands = np.array([10.0]), np.array([14.0]), []
    for jitter in rng.uniform(-0.4, 0.4, size=40):
        q = jittery.command(np.array([10.0 + jitter]), z, q)
        z = np.array([play_kernel(z[0], q[0], width)])
        commands.append(q[0])
    assert np.ptp(commands) > 2.0 * width


class NoisyDelayedPlant(DelayedPlant):
    """A :class:`DelayedPlant` whose tip is off the model's by ``offset`` and whose tracker is noisy."""

    def __init__(self, pipe, sweep, offset, noise_mm, seed):
        super().__init__(pipe, sweep)
        self.offset = np.asarray(offset, dtype=float)
        self.noise, self.rng = noise_mm, np.random.default_rng(seed)

    def step(self, command):
        obs = dict(super().step(command))
        for k in ("x", "y", "z"):
            obs[k] += self.noise * self.rng.normal()
        self.obs = obs
        return obs


def test_tracker_loop_holds_a_target_through_a_play_and_a_delay(runs, pipes):
    """Closed on a noisy tracker, with a play and a sample of delay, the tip holds the target near the noise."""
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone, "play")
    target = _model_tips(pipe, sweep, motion)[80]
    offset, noise = (1.5, -1.0, 0.0), 0.2
    finals = {}
    for name, controller in (
        ("feedback", FeedbackController(pipe, close_on="tracker", latency=1, rate_limit=60.0)),
        ("feedforward", FeedforwardController(pipe, latency=1, rate_limit=60.0)),
    ):
        controller.start(sweep)
        plant = NoisyDelayedPlant(pipe, sweep, offset, noise, seed=3)
        tips, commands = [], []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnreachableTargetWarning)
            for _ in range(80):
                commands.append(controller.step(target, plant.obs))
                plant.step(commands[-1])
                if plant.tip is not None:
                    tips.append(plant.tip.copy())
        tips, commands = np.array(tips), np.array(commands)
        # the error across the tip's surface: what the two motors can remove
        finals[name] = np.linalg.norm(tips[-30:] - target, axis=1)
        if name == "feedback":
            # no swing across the play (half-width plant.est.play_width_) at the hold
            assert np.abs(np.diff(commands[-30:], axis=0)).max() < plant.est.play_width_
            assert np.all(np.abs(np.diff(commands, axis=0)) <= 60.0 * controller.dt_ + 1e-9)
    assert np.median(finals["feedback"]) < 0.5 * np.median(finals["feedforward"])
    assert np.median(finals["feedback"]) < np.linalg.norm(offset) * 0.4


needs_numba = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="the numba engine needs numba")


def _compare_engines(make, pipe, sweep, targets, offset=(0.0, 0.0, 0.0)):
    """Commands, aims, corrections and unreachable counts of ``make(engine)`` on both engines."""
    got = {}
    for engine in ("numpy", "numba"):
        controller = make(engine).start(sweep)
        plant, record = DelayedPlant(pipe, sweep), []
        plant.offset = np.asarray(offset, dtype=float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnreachableTargetWarning)
            for target in targets:
                command = controller.step(target, plant.obs)
                record.append([*command, *controller.aimed_, *getattr(controller, "correction_", ())])
                plant.step(command)
        got[engine] = (np.array(record), controller.n_unreachable_, controller._limited)
    return got


@needs_numba
@pytest.mark.parametrize("case", ["feedforward", "internal-model", "resolved-rate", "tracker, limits"])
def test_compiled_step_gives_the_numpy_steps_commands(runs, pipes, case):
    """Over a task with far targets, rate and motor limits and a delay, both engines command the same."""
    _, _, sweep, motion = runs
    hysteresis = None if case == "resolved-rate" else "play"
    pipe = pipes(PDLBackbone if case == "tracker, limits" else PCCBackbone, hysteresis)
    tips = _model_tips(pipe, sweep, motion)
    # model tips, then jumps between far ones (the rate limit binds), then out of reach (the seed grid restarts)
    targets = np.vstack([tips[:40], np.repeat(tips[[20, 140, 60]], 8, axis=0),
                         np.tile([[90.0, 40.0, 10.0]], (6, 1)), tips[100:110]])
    params = {
        "feedforward": (FeedforwardController, {"rate_limit": 60.0}),
        "internal-model": (FeedbackController, {"rate_limit": 60.0}),
        "resolved-rate": (FeedbackController, {"feedforward": False, "gain": 0.5, "latency": 0}),
        "tracker, limits": (FeedbackController, {"close_on": "tracker", "motor_limits": [[-25.0, 25.0], [-40.0, 20.0]],
                                                 "dead_band": 0.5}),
    }[case]
    Controller, kwargs = params
    got = _compare_engines(lambda engine: Controller(pipe, engine=engine, **kwargs), pipe, sweep, targets,
                           offset=(1.0, -0.5, 0.0))
    np.testing.assert_allclose(got["numba"][0], got["numpy"][0], atol=1e-6)
    assert got["numba"][1:] == got["numpy"][1:]
    assert got["numpy"][1] >= 6  # the out-of-reach targets were met


@needs_numba
def test_compiled_play_inverse_is_the_python_one():
    """The compiled play inverse makes :class:`PlayInverse`'s command to the last bit, dead band and ties included."""
    from skcath.control import _jit

    _jit.control_kernel()
    rng = np.random.default_rng(4)
    for width, band in ((0.0, 0.0), (3.0, 0.0), (3.0, 1.0), (0.5, 2.0)):
        inverse = PlayInverse(width, dead_band=band)
        for _ in range(200):
            z_state, q_prev = rng.uniform(-20, 20, 3), rng.uniform(-20, 20, 3)
            # near the played angle (within the tolerance and the band), at it, and far from it
            z_wanted = z_state + rng.choice([0.0, 1e-7, -1e-7, 0.3, -0.3, 1.5, -1.5, 8.0], size=3)
            q = np.empty(3)
            _jit._play_command(z_wanted, z_state, q_prev, width, band, q)
            assert np.array_equal(q, inverse.command(z_wanted, z_state, q_prev))


@pytest.mark.parametrize("engine", ["numpy", pytest.param("numba", marks=needs_numba)])
def test_model_view_looks_ahead_without_moving_the_stream(runs, pipes, engine):
    """The view's tip is the backbone's at the effective angles; the stream steps on as if never looked at."""
    _, _, sweep, motion = runs
    pipe = pipes(PCCBackbone, "play")
    samples = [tuple(row) for row in motion[CHANNELS].to_numpy()[:12]]
    est, twin = (OnlineEstimator(pipe, engine=engine).start(sweep) for _ in range(2))
    view = est._model_view()
    width = view.play_width
    assert width == est.play_width_ > 0
    for sample in samples[:6]:
        est.step(*sample)
        twin.step(*sample)
    played = np.array(est.play_state_)
    commanded = samples[6]
    view.advance([commanded])
    # the state advanced by the commanded sample, its play included
    expected = [play_kernel(p, q, width) for p, q in zip(played, commanded[:2])]
    np.testing.assert_allclose(view.effective, expected, rtol=0, atol=1e-12)
    z, torques = np.array([12.0, -7.0]), commanded[2:]
    # the hysteresis skipped: the tip at the effective angles themselves (no residual)
    np.testing.assert_allclose(view.tip(z, torques, np.empty(3)), est._backbone(*z), atol=1e-9)
    np.testing.assert_allclose(view.tip(z, torques, np.empty(3)), est._backbone(*z), atol=1e-9)
    np.testing.assert_allclose(view.effective, expected, rtol=0, atol=1e-12)  # restored after each look
    if engine == "numba":
        arrays, advance, restore, tip = view.compiled()
        out = np.empty(3)
        tip(*arrays, z, np.asarray(torques), np.empty(4), out)
        np.testing.assert_allclose(out, est._backbone(*z), atol=1e-9)
    view.restore()
    for sample in samples[6:]:
        np.testing.assert_array_equal(est.step(*sample), twin.step(*sample))
    np.testing.assert_array_equal(est.play_state_, twin.play_state_)


def test_one_term_pi_inverse_is_the_play_inverse_without_its_dead_band():
    """The play as a one-term PI: its inverse commands as PlayInverse does, until a reversal dead band holds."""
    from skcath.backbones import PrandtlIshlinskii
    from skcath.backbones._pi import pi_inverse_step

    width = 3.0
    theta, up, down = PrandtlIshlinskii.play(width, n_motors=1).pack_inverse()
    rng = np.random.default_rng(0)
    differ = {}
    for band in (0.0, 1.0):
        inverse, z_state, q = PlayInverse(width, dead_band=band), 0.0, 0.0
        differ[band] = 0
        for _ in range(1000):
            z = z_state + (rng.normal(0.0, 0.4) if rng.random() < 0.5 else rng.normal(0.0, 5.0))
            q_play = inverse.command(np.array([z]), np.array([z_state]), np.array([q]))[0]
            # the PI inverse's state: its creep, its one play and its dead band at the played angle, the last command
            q_pi = pi_inverse_step(theta, np.array([z_state, z_state, z_state, q]), 0, z, 0.1, up[0], down[0])
            differ[band] += abs(q_pi - q_play) > 1e-9
            q = q_play
            z_state = play_kernel(z_state, q, width)
    assert differ[0.0] == 0
    assert differ[1.0] > 100  # the dead band holds small reversals that the PI inverse makes


def _random_pi(rng, n_motors=2):
    """A Prandtl-Ishlinskii model with dead band, asymmetry, creep and some plays without weight."""
    from skcath.backbones import PrandtlIshlinskii

    weights = rng.uniform(0.1, 1.0, 4) * (rng.random(4) > 0.3)
    weights = weights / weights.sum() if weights.sum() > 0 else np.eye(1, 4).ravel()
    return PrandtlIshlinskii([0.0, 0.5, 1.4, 4.0], weights, dead_band=rng.uniform(0.0, 2.0),
                             asymmetry=rng.uniform(-0.5, 0.5, n_motors), creep_gain=rng.uniform(0.0, 0.4),
                             creep_tau_s=rng.uniform(0.5, 5.0))


def _pi_after_motion(model, rng, n=40, dt=0.1):
    """The forward state and effective angles of ``model`` after a random walk of the motors, and the last angles."""
    q = np.cumsum(rng.normal(0.0, 3.0, (n, model.n_motors)), axis=0)
    v, state = model.forward(q, np.arange(n) * dt, return_state=True)
    return state, v[-1], q[-1]


def test_pi_inverse_commands_the_wanted_effective_angle_from_the_streams_state():
    """From any state the forward PI reached, the forward step of the inverse's command is the wanted angle."""
    from skcath.control._hysteresis import PIInverse

    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(40):
        model = _random_pi(rng)
        state, v, q = _pi_after_motion(model, rng)
        inverse = PIInverse(model, state, np.array([0.1]))
        for _ in range(30):  # small and large moves, reversals included
            wanted = v + rng.normal(0.0, rng.choice([0.05, 1.0, 5.0]), 2)
            q = inverse.command(wanted, v, q)
            new_state, v = model.step(state, q, 0.1)
            state[:] = new_state  # the inverse reads the stream's state in place
            worst = max(worst, float(np.abs(v - wanted).max()))
    assert worst < 1e-9


def test_pi_inverse_dead_band_holds_small_reversals_only():
    """A reversal of the wanted angle smaller than the dead band keeps the command; a larger one is made."""
    from skcath.control._hysteresis import PIInverse

    rng = np.random.default_rng(6)
    model = _random_pi(rng, n_motors=1)
    state, v, q = _pi_after_motion(model, rng)
    inverse = PIInverse(model, state, np.array([0.1]), dead_band=1.0)
    q = inverse.command(v + 5.0, v, q)  # a move up: the motor pushes from above the effective angle
    state[:], v = model.step(state, q, 0.1)
    assert q[0] > v[0]
    np.testing.assert_array_equal(inverse.command(v - 0.5, v, q), q)  # held
    up = inverse.command(v + 0.5, v, q)  # the side the motor pushes: followed
    np.testing.assert_allclose(model.step(state, up, 0.1)[1], v + 0.5, atol=1e-9)
    down = inverse.command(v - 3.0, v, q)  # a reversal larger than the band: made
    np.testing.assert_allclose(model.step(state, down, 0.1)[1], v - 3.0, atol=1e-9)


@needs_numba
def test_compiled_pi_inverse_is_the_python_one():
    """The compiled PI inverse makes :class:`PIInverse`'s command to the last bit, dead band included."""
    from skcath.control import _jit
    from skcath.control._compiled import _pi_arrays
    from skcath.control._hysteresis import PIInverse

    _jit.control_kernel()
    rng = np.random.default_rng(7)
    for band in (0.0, 1.0):
        for _ in range(20):
            model = _random_pi(rng, n_motors=3)
            state, v, q = _pi_after_motion(model, rng)
            inverse = PIInverse(model, state, np.array([0.1]), dead_band=band)
            wanted = v + rng.choice([0.0, 0.3, -0.3, 1.5, -1.5, 8.0], size=3)
            got = np.empty(3)
            _jit._pi_commands(_pi_arrays(inverse), wanted, v, q, band, got)
            assert np.array_equal(got, inverse.command(wanted, v, q))


@pytest.fixture(scope="module")
def pi_pipe(runs):
    """A PCC backbone with hysteresis="pi" and no residual, fitted on the training run."""
    X, y, _, _ = runs
    backbone = PCCBackbone(hysteresis="pi").fit(X)
    return Pipeline([("backbone", backbone), ("residual", NoResidual().fit(backbone.transform(X), y))])


def _rig_circle(pi_pipe, inverse_on, rate_limit=None, check=None):
    """A feedforward controller of the PI model on the simulated rig, along a slow circle of model tips.

    Returns the RMS distance (mm) of the rig's noise-free tip from the target
    the controller was given for it, after the first turn, and the commands.
    """
    from skcath.datasets import SimulatedCatheter

    rig = SimulatedCatheter(catheter=1, setting="S02", random_state=0)
    controller = FeedforwardController(pi_pipe, engine="numpy", rate_limit=rate_limit).start(rig.reset())
    assert controller.inverse_.kind == "pi"
    if not inverse_on:
        controller.inverse_ = IdentityInverse()
    elif check is not None:
        command = controller.inverse_.command
        controller.inverse_.command = lambda *args: check(controller, args, command(*args))
    k = np.arange(120)
    z = controller.limits_.neutral + 15.0 * np.c_[np.cos(2 * np.pi * k / 60) - 1.0, np.sin(2 * np.pi * k / 60)]
    targets = np.array([controller._view.backbone(*row) for row in z])
    obs, tips, commands = rig.step(controller.command_), [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnreachableTargetWarning)
        for target in targets:
            commands.append(controller.step(target, obs))
            obs = rig.step(commands[-1])
            tips.append(rig.tip_.copy())
    error = np.linalg.norm(np.array(tips)[2:] - targets[:-2], axis=1)[60:]
    return float(np.sqrt(np.mean(error ** 2))), np.array(commands), controller


def test_pi_feedforward_solves_through_the_hysteresis_and_tracks_better(pi_pipe):
    """On the rig: every command's forward PI step gives the solved effective angles; the circle is tracked better."""
    worst, n_checked = [0.0], [0]

    def check(controller, args, q):
        z_wanted, _, _ = args
        est = controller.estimator_
        effective = est.hysteresis_.step(est.hysteresis_state_, q, float(est._dt[0]))[1]
        worst[0] = max(worst[0], float(np.abs(effective - z_wanted).max()))
        n_checked[0] += 1
        return q

    with_inverse, _, controller = _rig_circle(pi_pipe, True, check=check)
    assert controller.estimator_.hysteresis_.dead_band > 0.0  # a hysteresis worth inverting
    assert n_checked[0] == 120 and worst[0] < 1e-6
    without, _, _ = _rig_circle(pi_pipe, False)
    assert with_inverse < 0.95 * without
    _, commands, controller = _rig_circle(pi_pipe, True, rate_limit=20.0)
    steps = np.abs(np.diff(commands, axis=0)).max(axis=1)
    assert steps.max() <= 20.0 * controller.dt_ + 1e-9
    assert np.all([controller.limits_.contains(c) for c in commands])


@needs_numba
def test_compiled_step_gives_the_numpy_steps_commands_with_the_pi(runs, pi_pipe):
    """With the PI's inverse in the compiled step, both engines command the same over a task with limits."""
    _, _, sweep, motion = runs
    tips = _model_tips(pi_pipe, sweep, motion)
    targets = np.vstack([tips[:40], np.repeat(tips[[20, 140, 60]], 8, axis=0), tips[100:110]])
    for Controller, kwargs in ((FeedforwardController, {"rate_limit": 60.0}),
                               (FeedbackController, {"rate_limit": 60.0, "dead_band": 0.5})):
        got = _compare_engines(lambda engine: Controller(pi_pipe, engine=engine, **kwargs), pi_pipe, sweep,
                               targets, offset=(1.0, -0.5, 0.0))
        np.testing.assert_allclose(got["numba"][0], got["numpy"][0], atol=1e-6)
        assert got["numba"][1:] == got["numpy"][1:]
