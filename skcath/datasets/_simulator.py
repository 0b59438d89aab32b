"""Simulation of recordings: protocol -> transmission -> kinematics -> sensors.

The per-sample time loop (hysteresis state) runs once for all runs at once;
everything stateless is vectorised over samples.
"""

from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
import pandas as pd
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation
from sklearn.utils import Bunch
from sklearn.utils._param_validation import Interval, StrOptions, validate_params

from .. import _format as fmt
from ..frames import tip_in_base_frame
from ._catheter import Catheter, ShaftSetting, sample_catheter, setting_parameters, shaft_settings
from ._hysteresis import MECHANISMS, simulate_transmission, torsional_windup
from ._kinematics import bend_from_inputs, tip_position, tip_rotvec
from ._protocol import protocol_trajectory
from ._sensors import DistortionField, measure_pose

__all__ = [
    "MAX_RATE_HZ",
    "RATE_HZ",
    "RUN_VARIATION",
    "RunSpec",
    "ShaftChange",
    "check_run_variation",
    "simulate_runs",
    "simulate_run",
]

#: Rate of the protocol (Hz): the durations of its moves, the run lengths and
#: the per-run draws are counted in samples at this rate, whatever the rate
#: the runs are sampled at (``rate_hz``).
RATE_HZ = 10.0

#: Per-run variation (standard deviations): gain jitter (relative), offset
#: jitter (deg), slow drift of offsets (deg, time constant s) and of gains
#: (relative, time constant s), re-installation of the base (mm, deg).
RUN_VARIATION = {
    "gain_jitter": 0.015,
    "offset_jitter_deg": 0.4,
    "offset_drift_deg": 1.2,
    "offset_drift_tau_s": 150.0,
    "gain_drift": 0.03,
    "gain_drift_tau_s": 300.0,
    "base_position_mm": 2.0,
    "base_rotation_deg": 2.0,
}
#: Keys of :data:`RUN_VARIATION` that are time constants (s), which must be positive.
_TIME_CONSTANTS = ("offset_drift_tau_s", "gain_drift_tau_s")

#: Highest sample rate the simulator accepts (Hz).
MAX_RATE_HZ = 1000.0


def check_run_variation(run_variation=None):
    """The per-run variation with some values replaced, checked.

    Parameters
    ----------
    run_variation : dict or None
        Values replacing those of :data:`RUN_VARIATION`, by key (e.g.
        ``{"gain_drift": 0.0}`` switches the gain drift off); None keeps them.

    Returns
    -------
    variation : dict
        All keys of :data:`RUN_VARIATION`, as floats.

    Raises
    ------
    ValueError
        For an unknown key, or a value that is not a finite number ``>= 0``
        (``> 0`` for the time constants).
    """
    changes = {} if run_variation is None else dict(run_variation)
    unknown = sorted(set(changes) - set(RUN_VARIATION), key=str)
    if unknown:
        raise ValueError(
            f"run_variation has unknown key(s) {unknown}; the keys are {sorted(RUN_VARIATION)}."
        )
    for key, value in changes.items():
        is_number = isinstance(value, Real) and not isinstance(value, bool)
        positive = key in _TIME_CONSTANTS
        if not (is_number and np.isfinite(value) and (value > 0 if positive else value >= 0)):
            bound = "> 0 (a time constant, s)" if key in _TIME_CONSTANTS else ">= 0"
            raise ValueError(
                f"run_variation[{key!r}] must be a finite number {bound}; got {value!r}."
            )
    return {key: float(changes.get(key, default)) for key, default in RUN_VARIATION.items()}


@dataclass(frozen=True)
class ShaftChange:
    """A repositioning of the shaft during the motion phase of a run.

    Attributes
    ----------
    setting : ShaftSetting
        Shaft setting from the change on.
    after_s : float
        Time of the change after the first motion sample (s).
    seed : numpy.random.SeedSequence
        Seed of the base pose after the change (the base of the bending
        section moves with the shaft).
    """

    setting: ShaftSetting
    after_s: float
    seed: np.random.SeedSequence


@dataclass(frozen=True)
class RunSpec:
    """What to simulate for one run: a catheter in a setting, and a seed.

    ``change`` (None: the shaft stays in ``setting`` for the whole run)
    repositions the shaft during the motion phase.
    """

    run: str
    catheter: Catheter
    setting: ShaftSetting
    repeat: int
    seed: np.random.SeedSequence
    change: ShaftChange | None = None


def _ou(rng, n, std, tau_s, t, size=2):
    """Stationary Ornstein-Uhlenbeck series of ``n`` samples at RATE_HZ, at the times ``t`` (s).

    Drawn at the protocol's rate, so that a run has the same drift at every
    sample rate, and interpolated linearly to ``t`` (its time constants are
    minutes).
    """
    phi = np.exp(-1.0 / (RATE_HZ * tau_s))
    white = rng.normal(0.0, std * np.sqrt(1.0 - phi**2), size=(n, size))
    white[0] = rng.normal(0.0, std, size=size)
    drift = lfilter([1.0], [1.0, -phi], white, axis=0)
    knots = np.arange(n) / RATE_HZ
    return np.column_stack([np.interp(t, knots, drift[:, j]) for j in range(size)])


def _lag(v, tau_s, rate_hz):
    """First-order lag (time constant ``tau_s``) along the time axis, starting at rest."""
    alpha = 1.0 - np.exp(-1.0 / (rate_hz * tau_s))
    out, _ = lfilter([alpha], [1.0, alpha - 1.0], v, axis=0, zi=(1.0 - alpha) * v[:1])
    return out


def _soft_dead_zone(v, width):
    """``v - d tanh(v / d)``: zero slope at neutral, ``v - d sign(v)`` far from it."""
    return v - width * np.tanh(v / width)


def _route(theta, routing):
    """Direction-dependent turn and scaling of the bend vector (tendon routing)."""
    a1, z1, a3, z3, b3, x3 = routing
    delta = np.arctan2(theta[:, 1], theta[:, 0])
    turned = delta + a1 * np.cos(delta - z1) + a3 * np.cos(3.0 * delta - z3)
    scale = np.hypot(theta[:, 0], theta[:, 1]) * (1.0 + b3 * np.cos(3.0 * delta - x3))
    return scale[:, None] * np.column_stack([np.cos(turned), np.sin(turned)])


def _axis_gains(e, gains):
    """Bend (rad) per axis with sign-dependent gains blended over about 1 deg."""
    s = 0.5 * (1.0 + np.tanh(e / 1.0))
    return e * (s * gains[:, 0] + (1.0 - s) * gains[:, 1])


def _base_pose(rng, setting, variation):
    """Pose of the bending-section base in the tracker frame for one run (mm)."""
    bvec = setting.bend_vector()
    visible = 0.5 * (setting.bend_deg - 30.0)
    shaft = Rotation.from_rotvec(np.deg2rad(visible) * np.array([-bvec[1], bvec[0], 0.0]))
    jitter = Rotation.from_rotvec(rng.normal(0.0, np.deg2rad(variation["base_rotation_deg"]), 3))
    position = np.array([0.0, 0.0, 250.0]) + 0.3 * visible * np.r_[bvec, 0.0]
    position = position + rng.normal(0.0, variation["base_position_mm"], 3)
    return shaft * jitter, position


def _draw_run(spec, variation, rate_hz=RATE_HZ):
    """Per-run random quantities that do not need the time loop, sampled at ``rate_hz``.

    Everything is drawn in samples at the protocol's rate (:data:`RATE_HZ`),
    so a run is the same motion with the same drifts at every ``rate_hz``.
    """
    rng = np.random.default_rng(spec.seed)
    trajectory = protocol_trajectory(rng, rate_hz=RATE_HZ)
    q, n_sweep = trajectory.sample(rate_hz)
    n, n_protocol = len(q), trajectory.n_samples
    t = np.arange(n) / rate_hz
    cfg = setting_parameters(spec.catheter, spec.setting)
    v = variation
    offsets = cfg["offsets"] + rng.normal(0.0, v["offset_jitter_deg"], 2)
    offsets = offsets + _ou(rng, n_protocol, v["offset_drift_deg"], v["offset_drift_tau_s"], t)
    gain_scale = 1.0 + rng.normal(0.0, v["gain_jitter"], 2) + _ou(
        rng, n_protocol, v["gain_drift"], v["gain_drift_tau_s"], t
    )
    draw = {"rng": rng, "q": q, "n_sweep": n_sweep, "cfg": cfg, "u": q - offsets,
            "gain_scale": gain_scale, "rate_hz": rate_hz, "n_protocol": n_protocol}
    if spec.change is not None:
        # same per-run jitter and drift; only the setting's offsets move
        k = n_sweep + int(round(spec.change.after_s * rate_hz))
        if not n_sweep <= k < n:
            raise ValueError(
                f"change_after_s={spec.change.after_s!r} s is outside the motion phase of run "
                f"{spec.run!r}, which lasts {(n - n_sweep) / rate_hz:.1f} s."
            )
        cfg_after = setting_parameters(spec.catheter, spec.change.setting)
        draw["cfg_after"] = cfg_after
        draw["u_after"] = draw["u"] + (cfg["offsets"] - cfg_after["offsets"])
        draw["change_index"] = k
    return draw


def _transmission_params(specs, configs):
    """Hysteresis parameters of shape (n_runs, 2) for simulate_transmission."""
    def col(values):
        return np.repeat(np.asarray(values, dtype=float)[:, None], 2, axis=1)

    cats = [s.catheter for s in specs]
    return {
        "w0": np.array([np.broadcast_to(c["w0"], 2) for c in configs], dtype=float),
        "growth": np.array([c["growth"] for c in configs], dtype=float),
        "asym": col([c.play_asym for c in cats]),
        "cross_load": col([c.cross_load for c in cats]),
        "kappa": col([c.bw_kappa for c in cats]),
        "rate_gain": col([c.rate_gain for c in cats]),
        "rate_speed": col([c.rate_speed for c in cats]),
        "creep_gain": col([c.creep_gain for c in cats]),
        "creep_tau": col([c.creep_tau for c in cats]),
    }


def _mechanics(cat, cfg, lagged, phi, windup, gain_scale):
    """Bend, tip position in the kinematic frame and tendon torque of one setting.

    Stateless (vectorised over samples) once the hysteresis output ``phi``,
    the lagged effective input ``lagged`` and the wind-up are known.
    """
    e = _soft_dead_zone(lagged, cfg["dead_zone"])
    theta = _axis_gains(e, cfg["gains"]) * gain_scale
    c12, c21 = cfg["coupling"]
    theta = _route(theta @ np.array([[1.0, c21], [c12, 1.0]]), cfg["routing"])
    cw, sw = np.cos(windup), np.sin(windup)
    theta = np.column_stack([cw * theta[:, 0] - sw * theta[:, 1], sw * theta[:, 0] + cw * theta[:, 1]])
    a, delta = bend_from_inputs(theta, rest=cfg["rest_bend"], max_bend=cat.max_bend, twist=cfg["twist"])
    share = np.clip(cat.split_fraction + cat.split_bias + cat.split_slope * (a - 1.0), 0.1, 0.9)
    p_k = tip_position(
        a, delta, length=cat.length, tip_length=cat.tip_length,
        split_fraction=cat.split_fraction, split_share=share,
    )

    # drive torque: antagonistic tendon pair through the capstan of the shaft
    exponent = (cfg["capstan_exponent"] + cat.mu * a[:, None]) * phi
    pos = (cat.pretension + cat.stiffness * np.maximum(e, 0.0)) * np.exp(exponent)
    neg = (cat.pretension + cat.stiffness * np.maximum(-e, 0.0)) * np.exp(-exponent)
    return a, delta, p_k, cat.pulley_radius * (pos - neg)


def _noise_stream(spec, draw, size):
    """Where the per-sample noise of a run (torque, sensors, dropouts) is drawn from.

    At the protocol's rate, the run's own stream, as always. At another rate
    the run's stream first draws the torque noise it draws at the protocol's
    rate (``size``, discarded), so that the base pose drawn next is that of
    the run at the protocol's rate; the noise itself comes from a stream of
    its own, derived from the run's seed.
    """
    rng = draw["rng"]
    if draw["rate_hz"] == RATE_HZ:
        return rng
    rng.normal(size=size)
    key = (*spec.seed.spawn_key, 2)
    return np.random.default_rng(np.random.SeedSequence(spec.seed.entropy, spawn_key=key))


def _finish_run(spec, draw, v, phi, windup, field, dropout_rate, variation):
    """Kinematics, torque and EM sensors of one run, vectorised over samples.

    For a run whose shaft is repositioned at sample ``draw["change_index"]``,
    ``v``, ``phi`` and ``windup`` are already spliced at the change (see
    :func:`_splice_changes`); the stateless mechanics of the new setting take
    over from that sample on, and the base of the bending section moves to a
    pose of the new setting.
    """
    cat, cfg, rng, rate_hz = spec.catheter, draw["cfg"], draw["rng"], draw["rate_hz"]
    q, n = draw["q"], len(draw["q"])
    v = v - cat.slow_creep_gain * _lag(v, cat.slow_creep_tau, rate_hz)  # tendon creep under load
    lagged = _lag(v, cat.tip_lag, rate_hz)
    a, delta, p_k, drive = _mechanics(cat, cfg, lagged, phi, windup, draw["gain_scale"])
    k = draw.get("change_index")
    if k is not None:  # the new setting's mechanics from the change on
        a[k:], delta[k:], p_k[k:], drive[k:] = _mechanics(
            cat, draw["cfg_after"], lagged[k:], phi[k:], windup[k:], draw["gain_scale"][k:]
        )
    omega = np.gradient(q, 1.0 / rate_hz, axis=0)
    tau = drive + cat.motor_friction * np.tanh(omega) + cat.motor_viscous * omega
    noise = _noise_stream(spec, draw, (draw["n_protocol"], 2))
    tau = tau + noise.normal(0.0, cat.torque_noise, size=tau.shape)
    tau = np.round(tau / cat.torque_step) * cat.torque_step

    # base frame and sensors
    mount = Rotation.from_rotvec(cat.mount_rotvec)  # kinematic frame K -> base-sensor frame B
    y_true = mount.apply(p_k - cat.mount_position)
    r_wk, p_wk = _base_pose(rng, spec.setting, variation)
    tip_pos = p_wk + r_wk.apply(p_k)
    tip_rot = r_wk * Rotation.from_rotvec(tip_rotvec(a, delta))
    base_pos = np.repeat((p_wk + r_wk.apply(cat.mount_position))[None], n, axis=0)
    base_rot = Rotation.from_quat(np.repeat((r_wk * mount.inv()).as_quat()[None], n, axis=0))
    if k is not None:  # the base of the bending section moves with the shaft
        r_b, p_b = _base_pose(
            np.random.default_rng(spec.change.seed), spec.change.setting, variation
        )
        tip_pos[k:] = p_b + r_b.apply(p_k[k:])
        bend_after = Rotation.from_rotvec(tip_rotvec(a[k:], delta[k:]))
        tip_rot = Rotation.concatenate([tip_rot[:k], r_b * bend_after])
        base_pos[k:] = p_b + r_b.apply(cat.mount_position)
        base_rot = Rotation.concatenate(
            [base_rot[:k], Rotation.from_quat(np.repeat((r_b * mount.inv()).as_quat()[None], n - k, axis=0))]
        )
    tip_meas, tip_quat = measure_pose(noise, tip_pos, tip_rot, field)
    base_meas, base_quat = measure_pose(noise, base_pos, base_rot, field)
    if dropout_rate > 0:
        lost = noise.random(n) < dropout_rate
        tip_meas[lost] = np.nan
        tip_quat[lost] = np.nan
    y = tip_in_base_frame(tip_meas, base_meas, base_quat, quat_order="wxyz")
    sensors = np.column_stack([tip_meas, tip_quat, base_meas, base_quat])
    return tau, y, y_true, sensors


def _splice_changes(u, v_all, phi_all, windup_all, changed, specs, draws, lengths, mechanism):
    """Switch the transmission of repositioned runs to their new setting, in place.

    The transmission of each changed run is simulated a second time over the
    whole run with the new setting's friction, offsets and wind-up, and its
    output replaces the first one from the change on: at the change, the
    tendons re-seat in the new shaft path, and their friction state is the
    one the new path has after the same motor history.
    """
    u_after = u[:, changed].copy()
    for i, j in enumerate(changed):
        u_after[: lengths[j], i] = draws[j]["u_after"]
        u_after[lengths[j]:, i] = draws[j]["u_after"][-1]
    sub_specs = [specs[j] for j in changed]
    configs = [draws[j]["cfg_after"] for j in changed]
    v_after, phi_after = simulate_transmission(
        u_after, 1.0 / draws[changed[0]]["rate_hz"], _transmission_params(sub_specs, configs),
        mechanism,
    )
    windup_after = torsional_windup(u_after, np.array([c["windup"] for c in configs]))
    for i, j in enumerate(changed):
        k = draws[j]["change_index"]
        v_all[k:, j] = v_after[k:, i]
        phi_all[k:, j] = phi_after[k:, i]
        windup_all[k:, j] = windup_after[k:, i]


def _run_frame(spec, draw, tau, y):
    """The long-format rows of one simulated run (reference tip on sweep rows only)."""
    q, n = draw["q"], len(draw["q"])
    sweep = np.arange(n) < draw["n_sweep"]
    ref = np.where(sweep[:, None], y, np.nan)
    return pd.DataFrame(
        {
            fmt.CATHETER: spec.catheter.name,
            fmt.SETTING: spec.setting.name,
            fmt.RUN: spec.run,
            fmt.TIME: np.arange(n) / draw["rate_hz"],
            fmt.PHASE: np.where(sweep, fmt.SWEEP, fmt.MOTION),
            "q1": q[:, 0], "q2": q[:, 1],
            "tau1": tau[:, 0], "tau2": tau[:, 1],
            "ref_x": ref[:, 0], "ref_y": ref[:, 1], "ref_z": ref[:, 2],
        }
    )


def _run_row(spec, draw, y, y_true, *, with_change):
    """The row of one simulated run in the ``runs`` table (noise floor over motion rows, mm)."""
    n = len(draw["q"])
    motion = np.arange(n) >= draw["n_sweep"]
    err = np.linalg.norm(y[motion] - y_true[motion], axis=1)
    row = {
        "run": spec.run,
        "catheter": spec.catheter.name,
        "setting": spec.setting.name,
        "repeat": spec.repeat,
        "bend_level": spec.setting.level,
        "bend_direction_deg": spec.setting.direction_deg,
        "shaft_wrap_deg": spec.setting.bend_deg,
        "n_samples": int(n),
        "n_sweep": int(draw["n_sweep"]),
        "noise_floor_mm": float(np.sqrt(np.nanmean(err**2))),
    }
    if with_change:
        k = draw.get("change_index")
        row["setting_after"] = None if k is None else spec.change.setting.name
        row["change_time_s"] = np.nan if k is None else k / draw["rate_hz"]
    return row


def simulate_runs(specs, *, mechanism="play", field=None, dropout_rate=0.0, run_variation=None,
                  rate_hz=RATE_HZ):
    """Simulate many runs at once.

    Parameters
    ----------
    specs : sequence of RunSpec
        Runs to simulate.
    mechanism : {"play", "bouc_wen", "dahl_creep"}
        Hysteresis mechanism of the tendon transmission.
    field : DistortionField or None
        Field distortion of the tracker (None: no distortion).
    dropout_rate : float
        Probability that the tip sensor is lost at a sample (NaN target).
    run_variation : dict or None
        Per-run variation replacing values of :data:`RUN_VARIATION` (see
        :func:`check_run_variation`).
    rate_hz : float, default=10.0
        Sample rate of the runs (Hz). The protocol, the per-run draws and
        the drifts are those of :data:`RATE_HZ` whatever the rate; the
        dynamics (lags, hysteresis, motor speed) run at ``rate_hz``, and
        the per-sample noise keeps its standard deviation per sample.

    Returns
    -------
    bunch : sklearn.utils.Bunch
        ``X`` (long format), ``y``, ``y_true``, ``sensors`` and ``runs``
        (one row per run with its noise floor); see :func:`make_benchmark`.
        When a spec has a ``change``, ``runs`` has two more columns:
        ``setting_after`` (name of the setting from the change on, None for
        runs without a change) and ``change_time_s`` (time ``t`` of the
        first sample in the new setting, s; NaN without a change).
    """
    if mechanism not in MECHANISMS:
        raise ValueError(f"mechanism={mechanism!r} is not one of {MECHANISMS}.")
    if not 0.0 <= dropout_rate < 1.0:
        raise ValueError(f"dropout_rate must be in [0, 1); got {dropout_rate!r}.")
    variation = check_run_variation(run_variation)
    draws = [_draw_run(s, variation, float(rate_hz)) for s in specs]
    lengths = np.array([len(d["q"]) for d in draws])
    n_max = lengths.max()
    u = np.empty((n_max, len(specs), 2))
    for j, d in enumerate(draws):
        u[: lengths[j], j] = d["u"]
        u[lengths[j]:, j] = d["u"][-1]
    v_all, phi_all = simulate_transmission(
        u, 1.0 / float(rate_hz), _transmission_params(specs, [d["cfg"] for d in draws]), mechanism
    )
    windup_all = torsional_windup(u, np.array([d["cfg"]["windup"] for d in draws]))
    changed = [j for j, d in enumerate(draws) if "change_index" in d]
    if changed:
        _splice_changes(u, v_all, phi_all, windup_all, changed, specs, draws, lengths, mechanism)

    frames, ys, ys_true, sensors, rows = [], [], [], [], []
    for j, (spec, d) in enumerate(zip(specs, draws)):
        n = lengths[j]
        tau, y, y_true, sens = _finish_run(
            spec, d, v_all[:n, j], phi_all[:n, j], windup_all[:n, j], field, dropout_rate,
            variation,
        )
        frames.append(_run_frame(spec, d, tau, y))
        ys.append(y)
        ys_true.append(y_true)
        sensors.append(sens)
        rows.append(_run_row(spec, d, y, y_true, with_change=bool(changed)))
    X = pd.concat(frames, ignore_index=True)
    for col in (*fmt.ID_COLUMNS, fmt.PHASE):
        X[col] = X[col].astype("category")
    sensor_cols = [c for group in fmt.SENSOR_POSE_COLUMNS.values() for c in group]
    runs = pd.DataFrame(rows)
    return Bunch(
        X=X,
        y=np.concatenate(ys),
        y_true=np.concatenate(ys_true),
        sensors=pd.DataFrame(np.concatenate(sensors), columns=sensor_cols),
        runs=runs,
        noise_floor=float(runs["noise_floor_mm"].mean()),
        mechanism=mechanism,
    )


@validate_params(
    {
        "catheter": [Catheter, None],
        "setting": [ShaftSetting, str, None],
        "mechanism": [StrOptions(set(MECHANISMS))],
        "random_state": [Interval(Integral, 0, None, closed="left"), np.random.Generator, None],
        "run": [str],
        "field": ["boolean"],
        "dropout_rate": [Interval(Real, 0, 1, closed="left")],
        "setting_after": [ShaftSetting, str, None],
        # a right end of inf, open: the time must be finite
        "change_after_s": [Interval(Real, 0, np.inf, closed="left")],
        "rate_hz": [Interval(Real, 1, MAX_RATE_HZ, closed="both")],
    },
    prefer_skip_nested_validation=True,
)
def simulate_run(
    catheter=None,
    setting=None,
    *,
    mechanism="play",
    random_state=None,
    run="run-0",
    field=True,
    dropout_rate=0.0,
    setting_after=None,
    change_after_s=60.0,
    rate_hz=RATE_HZ,
):
    """Simulate one recording: an 8-ray sweep then a 100-step random walk, at 10 Hz by default.

    With ``setting_after``, the shaft is repositioned during the motion
    phase: from ``change_after_s`` seconds after the first motion sample on,
    the run continues in the new setting (see :func:`make_benchmark`,
    ``shaft_change``).

    Parameters
    ----------
    catheter : Catheter or None
        Catheter unit; None draws one from ``random_state``.
    setting : ShaftSetting, str or None
        Shaft setting, or the name of one of :func:`shaft_settings`
        (``"S00"`` straight, ``"S01"``-``"S08"`` low, ``"S09"``-``"S16"``
        high bend); None is ``"S01"``.
    mechanism : {"play", "bouc_wen", "dahl_creep"}
        Hysteresis mechanism of the tendon transmission.
    random_state : int, numpy.random.Generator or None
        Seed of the catheter draw (when ``catheter`` is None), the field
        distortion, the protocol and all noise.
    run : str
        Run id written to the ``run`` column.
    field : bool
        Whether the tracker field is distorted.
    dropout_rate : float
        Probability that the tip sensor is lost at a sample (NaN target).
    setting_after : ShaftSetting, str or None
        Shaft setting after a repositioning of the shaft during motion, or
        its name; None (default) keeps ``setting`` for the whole run.
    change_after_s : float, default=60.0
        Time of the repositioning after the first motion sample (s); used
        only with ``setting_after``. The motion phase lasts 164-218 s.
    rate_hz : float, default=10.0
        Sample rate (Hz), from 1 to 1000. The same run (motion, catheter,
        drifts, base pose) sampled at this rate, with fresh per-sample noise
        of the same standard deviation (``docs/simulator.rst``, *Sample
        rate*); 10 gives the runs of the benchmark.

    Returns
    -------
    bunch : sklearn.utils.Bunch
        ``X`` (long format, see ``docs/data_format.rst``), ``y`` (n, 3)
        measured tip in the base frame (mm), ``y_true`` (n, 3) noise-free tip,
        ``sensors`` (raw EM poses), ``runs`` (one row), ``noise_floor`` (mm).
        With ``setting_after``, ``runs`` also has ``setting_after`` and
        ``change_time_s`` (time ``t`` of the first sample in the new
        setting, s). Up to the change, the run is identical to the same run
        without a change.
    """
    root = np.random.SeedSequence(_entropy(random_state))
    seeds = root.spawn(3)
    if catheter is None:
        catheter = sample_catheter(seeds[0], "C1")
    setting = _lookup_setting("setting", "S01" if setting is None else setting)
    change = None
    if setting_after is not None:
        setting_after = _lookup_setting("setting_after", setting_after)
        if setting_after.name == setting.name:
            raise ValueError(f"setting_after={setting_after.name!r} must differ from setting.")
        change = ShaftChange(setting_after, float(change_after_s), root.spawn(1)[0])
    spec = RunSpec(run=run, catheter=catheter, setting=setting, repeat=0, seed=seeds[1], change=change)
    dist = DistortionField(seeds[2]) if field else None
    return simulate_runs(
        [spec], mechanism=mechanism, field=dist, dropout_rate=dropout_rate, rate_hz=rate_hz
    )


def _lookup_setting(name, setting):
    """A ShaftSetting from itself or from its name in :func:`shaft_settings`."""
    if isinstance(setting, ShaftSetting):
        return setting
    table = {s.name: s for s in shaft_settings()}
    if setting not in table:
        raise ValueError(f"{name}={setting!r} is not one of {sorted(table)}.")
    return table[setting]


def _entropy(random_state):
    """Integer entropy from an int, a Generator or None."""
    if isinstance(random_state, np.random.Generator):
        return int(random_state.integers(2**63))
    return None if random_state is None else int(random_state)
