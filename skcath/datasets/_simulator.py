"""Simulation of recordings: protocol -> transmission -> kinematics -> sensors.

The per-sample time loop (hysteresis state) runs once for all runs at once;
everything stateless is vectorised over samples.
"""

from dataclasses import dataclass
from numbers import Integral, Real
from typing import NamedTuple

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
from ._protocol import protocol_trajectory, resweep_trajectory
from ._sensors import DistortionField, noisy_pose, pose_noise
from ._tendons import MotorCount, tendon_layout

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

#: Highest sample rate the simulator accepts (Hz).
MAX_RATE_HZ = 1000.0

#: Suffix of the run id of the part of a run after its shaft change and re-sweep.
AFTER_SUFFIX = "/after"

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
        section moves with the shaft); with ``resweep``, its first child
        seeds the noise and the drift of the part after the change.
    resweep : bool, default=False
        Whether the run sweeps again after the change: the motors return to
        neutral, perform the run's sweep in the new setting and go on with
        the rest of the motion (``resweep_trajectory`` of
        ``skcath/datasets/_protocol.py``). The part after the change is then
        recorded as a run of its own.
    """

    setting: ShaftSetting
    after_s: float
    seed: np.random.SeedSequence
    resweep: bool = False


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


def _ou_from(rng, last, n, std, tau_s):
    """Continuation of an Ornstein-Uhlenbeck series of shape (n, len(last)) after its value ``last``."""
    phi = np.exp(-1.0 / (RATE_HZ * tau_s))
    white = rng.normal(0.0, std * np.sqrt(1.0 - phi**2), size=(n, len(last)))
    out, _ = lfilter([1.0], [1.0, -phi], white, axis=0, zi=phi * np.asarray(last, dtype=float)[None])
    return out


def _resweep_seed(seed):
    """The first child of a shaft change's seed: the noise and drift after a re-sweep."""
    return np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, 0), pool_size=seed.pool_size)


def _lag(v, tau_s, rate_hz=RATE_HZ):
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
    The protocol is drawn in the command space of the catheter's tendon
    layout and turned into its motor angles; the jitter and drifts are per
    motor.
    """
    layout = tendon_layout(spec.catheter.n_motors)
    if spec.change is not None and spec.change.resweep:
        if rate_hz != RATE_HZ:
            raise ValueError(
                f"a re-sweep after the shaft change (resweep=True) is simulated at "
                f"rate_hz={RATE_HZ:g} only; got rate_hz={rate_hz!r}."
            )
        if layout.n_motors != 2:
            raise ValueError(
                f"a re-sweep after the shaft change (resweep=True) is simulated for "
                f"two motors only; got n_motors={layout.n_motors}."
            )
    rng = np.random.default_rng(spec.seed)
    trajectory = protocol_trajectory(
        rng, rate_hz=RATE_HZ, n_rays=layout.sweep_rays, n_dims=layout.n_commands
    )
    command, n_sweep = trajectory.sample(rate_hz)
    q = layout.motor_angles(command)
    n, n_protocol, n_motors = len(q), trajectory.n_samples, layout.n_motors
    t = np.arange(n) / rate_hz
    cfg = setting_parameters(spec.catheter, spec.setting)
    v = variation
    jitter = rng.normal(0.0, v["offset_jitter_deg"], n_motors)
    drift = _ou(rng, n_protocol, v["offset_drift_deg"], v["offset_drift_tau_s"], t, n_motors)
    offsets = cfg["offsets"] + jitter + drift
    gain_jitter = rng.normal(0.0, v["gain_jitter"], n_motors)
    gain_drift = _ou(rng, n_protocol, v["gain_drift"], v["gain_drift_tau_s"], t, n_motors)
    gain_scale = 1.0 + gain_jitter + gain_drift
    draw = {"rng": rng, "q": q, "n_sweep": n_sweep, "cfg": cfg, "u": q - offsets, "offsets": offsets,
            "gain_scale": gain_scale, "rate_hz": rate_hz, "n_protocol": n_protocol,
            "drifts": {"offsets": (jitter, drift), "gains": (gain_jitter, gain_drift)}}
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
        if spec.change.resweep:
            draw["resweep"] = _draw_resweep(
                spec, draw, (jitter, drift[k - 1]), (gain_jitter, gain_drift[k - 1]), v
            )
    return draw


def _draw_resweep(spec, draw, offset_state, gain_state, variation):
    """The part of a run after its shaft change when it sweeps again.

    The motor angles of :func:`resweep_trajectory`; the offsets of the new
    setting with the run's own jitter, and the slow drifts of the offsets and
    gains carried on from their values just before the change (the pairs
    ``offset_state`` and ``gain_state`` hold the jitter and that value);
    the noise from the change's own seed. ``u`` is the input of the
    transmission over the whole run: the motor history up to the change
    with the new setting's offsets (as for a change without a re-sweep),
    then this part.
    """
    k, v = draw["change_index"], variation
    rng = np.random.default_rng(_resweep_seed(spec.change.seed))
    q, n_home = resweep_trajectory(draw["q"], draw["n_sweep"], k, rate_hz=RATE_HZ)
    m = len(q)
    jitter, drift = offset_state
    offsets = draw["cfg_after"]["offsets"] + jitter
    offsets = offsets + _ou_from(rng, drift, m, v["offset_drift_deg"], v["offset_drift_tau_s"])
    gain_jitter, gain_drift = gain_state
    gain_scale = 1.0 + gain_jitter + _ou_from(rng, gain_drift, m, v["gain_drift"], v["gain_drift_tau_s"])
    u = np.concatenate([draw["u_after"][:k], q - offsets])
    return {"rng": rng, "q": q, "n_home": n_home, "u": u, "gain_scale": gain_scale}


def _transmission_params(specs, configs):
    """Hysteresis parameters of shape (n_runs, n_motors) for simulate_transmission."""
    cats = [s.catheter for s in specs]
    n_motors = cats[0].n_motors

    def col(values):
        return np.repeat(np.asarray(values, dtype=float)[:, None], n_motors, axis=1)

    return {
        "w0": np.array([np.broadcast_to(c["w0"], n_motors) for c in configs], dtype=float),
        "growth": np.array([c["growth"] for c in configs], dtype=float),
        "asym": col([c.play_asym for c in cats]),
        "cross_load": col([c.cross_load for c in cats]),
        "kappa": col([c.bw_kappa for c in cats]),
        "rate_gain": col([c.rate_gain for c in cats]),
        "rate_speed": col([c.rate_speed for c in cats]),
        "creep_gain": col([c.creep_gain for c in cats]),
        "creep_tau": col([c.creep_tau for c in cats]),
    }


def _tendon_torque(cat, e, exponent, single_tendons):
    """Tendon torque on each motor's pulley (N mm) from its tendon input ``e`` (deg).

    A pair: the pulled tendon's tension through the capstan factor less the
    other's; a single tendon (three motors): its own tension, slack below
    zero.
    """
    if single_tendons:
        return cat.pulley_radius * np.maximum(cat.pretension + cat.stiffness * e, 0.0) * np.exp(exponent)
    pos = (cat.pretension + cat.stiffness * np.maximum(e, 0.0)) * np.exp(exponent)
    neg = (cat.pretension + cat.stiffness * np.maximum(-e, 0.0)) * np.exp(-exponent)
    return cat.pulley_radius * (pos - neg)


def _mechanics(cat, cfg, lagged, phi, windup, gain_scale):
    """Bend, tip position in the kinematic frame and tendon torque of one setting.

    Stateless (vectorised over samples) once the hysteresis output ``phi``,
    the lagged effective input ``lagged`` and the wind-up are known. The
    bends of the motors' tendons add up to the section's two bending inputs
    through the catheter's tendon layout.
    """
    layout = tendon_layout(cat.n_motors)
    e = _soft_dead_zone(lagged, cfg["dead_zone"])
    theta = layout.bending_inputs(_axis_gains(e, cfg["gains"]) * gain_scale)
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

    # drive torque: the motor's tendons through the capstan of the shaft
    exponent = (cfg["capstan_exponent"] + cat.mu * a[:, None]) * phi
    return a, delta, p_k, _tendon_torque(cat, e, exponent, layout.single_tendons)


def _creep_and_lag(cat, v, rate_hz=RATE_HZ):
    """The effective tendon input after the slow tendon creep and the lag of the section."""
    v = v - cat.slow_creep_gain * _lag(v, cat.slow_creep_tau, rate_hz)  # tendon creep under load
    return _lag(v, cat.tip_lag, rate_hz)


def _drive_torque(cat, q, drive, rng, rate_hz=RATE_HZ):
    """Measured motor torques (N mm): the tendon torque plus motor friction, noise and rounding."""
    omega = np.gradient(q, 1.0 / rate_hz, axis=0)
    return _torque_reading(cat, omega, drive, rng.normal(0.0, cat.torque_noise, size=drive.shape))


def _torque_reading(cat, omega, drive, noise):
    """Measured motor torques (N mm) at motor speeds ``omega`` (deg/s), given their ``noise``."""
    tau = drive + cat.motor_friction * np.tanh(omega) + cat.motor_viscous * omega
    tau = tau + noise
    return np.round(tau / cat.torque_step) * cat.torque_step


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


def _mounted(cat, p_k):
    """Noise-free tip in the frame of the base sensor (mm)."""
    return Rotation.from_rotvec(cat.mount_rotvec).apply(p_k - cat.mount_position)


def _poses(cat, r_wk, p_wk, p_k, a, delta):
    """True poses of the tip and base sensors in the tracker frame, the section's base at ``(r_wk, p_wk)``."""
    return (*_tip_pose(r_wk, p_wk, p_k, a, delta), *_base_sensor_pose(cat, r_wk, p_wk, len(p_k)))


def _tip_pose(r_wk, p_wk, p_k, a, delta):
    """True pose of the tip sensor in the tracker frame, the section's base at ``(r_wk, p_wk)``."""
    return p_wk + r_wk.apply(p_k), r_wk * Rotation.from_rotvec(tip_rotvec(a, delta))


def _base_sensor_pose(cat, r_wk, p_wk, n):
    """True pose of the base sensor at ``n`` samples, the section's base at ``(r_wk, p_wk)``."""
    mount = Rotation.from_rotvec(cat.mount_rotvec)  # kinematic frame K -> base-sensor frame B
    base_pos = np.repeat((p_wk + r_wk.apply(cat.mount_position))[None], n, axis=0)
    base_rot = Rotation.from_quat(np.repeat((r_wk * mount.inv()).as_quat()[None], n, axis=0))
    return base_pos, base_rot


def _measure(rng, poses, field, dropout_rate):
    """Measured tip in the base frame and the raw sensor poses, from the true poses."""
    return _measured(poses, field, _measurement_noise(rng, len(poses[0]), dropout_rate))


def _measurement_noise(rng, n, dropout_rate):
    """The sensor jitter of ``n`` samples, tip then base, and which tip samples are lost (None: none)."""
    tip, base = pose_noise(rng, n), pose_noise(rng, n)
    return tip, base, (rng.random(n) < dropout_rate if dropout_rate > 0 else None)


def _measured(poses, field, noise):
    """Measured tip in the base frame and the raw sensor poses, from the true poses and their noise."""
    tip_pos, tip_rot, base_pos, base_rot = poses
    tip_noise, base_noise, lost = noise
    base = noisy_pose(base_pos, base_rot, field, base_noise)
    return _measured_tip((tip_pos, tip_rot), base, field, tip_noise, lost)


def _measured_tip(tip_pose, base, field, tip_noise, lost):
    """Measured tip in the base frame and the raw sensor poses, given the measured base sensor ``base``."""
    tip_meas, tip_quat = noisy_pose(*tip_pose, field, tip_noise)
    base_meas, base_quat = base
    if lost is not None:
        tip_meas[lost] = np.nan
        tip_quat[lost] = np.nan
    y = tip_in_base_frame(tip_meas, base_meas, base_quat, quat_order="wxyz")
    return y, np.column_stack([tip_meas, tip_quat, base_meas, base_quat])


def _finish_run(spec, draw, v, phi, windup, field, dropout_rate, variation):
    """Kinematics, torque and EM sensors of one run, vectorised over samples.

    For a run whose shaft is repositioned at sample ``draw["change_index"]``,
    ``v``, ``phi`` and ``windup`` are already spliced at the change (see
    :func:`_splice_changes`); the stateless mechanics of the new setting take
    over from that sample on, and the base of the bending section moves to a
    pose of the new setting.
    """
    cat, cfg, rng, rate_hz = spec.catheter, draw["cfg"], draw["rng"], draw["rate_hz"]
    lagged = _creep_and_lag(cat, v, rate_hz)
    a, delta, p_k, drive = _mechanics(cat, cfg, lagged, phi, windup, draw["gain_scale"])
    k = draw.get("change_index")
    if k is not None:  # the new setting's mechanics from the change on
        a[k:], delta[k:], p_k[k:], drive[k:] = _mechanics(
            cat, draw["cfg_after"], lagged[k:], phi[k:], windup[k:], draw["gain_scale"][k:]
        )
    noise = _noise_stream(spec, draw, (draw["n_protocol"], cat.n_motors))
    tau = _drive_torque(cat, draw["q"], drive, noise, rate_hz)
    y_true = _mounted(cat, p_k)
    tip_pos, tip_rot, base_pos, base_rot = _poses(
        cat, *_base_pose(rng, spec.setting, variation), p_k, a, delta
    )
    if k is not None:  # the base of the bending section moves with the shaft
        pose_after = _base_pose(np.random.default_rng(spec.change.seed), spec.change.setting, variation)
        tip_after, rot_after, base_after, base_rot_after = _poses(cat, *pose_after, p_k[k:], a[k:], delta[k:])
        tip_pos[k:] = tip_after
        tip_rot = Rotation.concatenate([tip_rot[:k], rot_after])
        base_pos[k:] = base_after
        base_rot = Rotation.concatenate([base_rot[:k], base_rot_after])
    y, sensors = _measure(noise, (tip_pos, tip_rot, base_pos, base_rot), field, dropout_rate)
    return tau, y, y_true, sensors


def _finish_resweep(spec, draw, v, phi, windup, field, dropout_rate, variation):
    """Kinematics, torque and EM sensors of the part of a run after its change and re-sweep.

    ``v`` is the run's effective tendon input up to the change followed by
    that of the part after it, and ``phi`` and ``windup`` those of the new
    setting over the same samples (:func:`_transmission`), so that the creep
    and the lag of the section carry on through the change. The return to
    neutral that starts the part is simulated but not returned: the recorded
    part starts with its sweep.
    """
    cat, k, part = spec.catheter, draw["change_index"], draw["resweep"]
    lagged = _creep_and_lag(cat, v)[k:]
    a, delta, p_k, drive = _mechanics(
        cat, draw["cfg_after"], lagged, phi[k:], windup[k:], part["gain_scale"]
    )
    tau = _drive_torque(cat, part["q"], drive, part["rng"])
    pose = _base_pose(np.random.default_rng(spec.change.seed), spec.change.setting, variation)
    y, sensors = _measure(part["rng"], _poses(cat, *pose, p_k, a, delta), field, dropout_rate)
    recorded = slice(part["n_home"], None)
    return tau[recorded], y[recorded], _mounted(cat, p_k)[recorded], sensors[recorded]


def _padded(inputs):
    """Motor inputs of shape (n_i, n_motors) as one array (n_max, n_runs, n_motors), each padded with its last value."""
    u = np.empty((max(len(x) for x in inputs), len(inputs), inputs[0].shape[1]))
    for j, x in enumerate(inputs):
        u[: len(x), j] = x
        u[len(x):, j] = x[-1]
    return u


def _transmission(u, specs, configs, mechanism, rate_hz=RATE_HZ):
    """Effective tendon input, friction utilisation and wind-up of padded inputs ``u`` sampled at ``rate_hz``.

    The wind-up follows the direction of the two bending inputs of ``u``.
    """
    v, phi = simulate_transmission(u, 1.0 / rate_hz, _transmission_params(specs, configs), mechanism)
    layout = tendon_layout(specs[0].catheter.n_motors)
    windup = torsional_windup(layout.bending_inputs(u), np.array([c["windup"] for c in configs]))
    return v, phi, windup


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
    v_after, phi_after, windup_after = _transmission(
        u_after, [specs[j] for j in changed], [draws[j]["cfg_after"] for j in changed], mechanism,
        draws[changed[0]]["rate_hz"],
    )
    for i, j in enumerate(changed):
        k = draws[j]["change_index"]
        v_all[k:, j] = v_after[k:, i]
        phi_all[k:, j] = phi_after[k:, i]
        windup_all[k:, j] = windup_after[k:, i]


def _resweep_transmission(v_all, specs, draws, mechanism):
    """Transmission of every re-swept run over its history and the part after its change.

    Returns, by run index, ``(v, phi, windup)`` over the samples of
    ``draw["resweep"]["u"]``: ``v`` is the run's own up to the change, then
    that of the new setting; ``phi`` and ``windup`` are the new setting's
    (only their part from the change on is used).
    """
    swept = [j for j, d in enumerate(draws) if "resweep" in d]
    if not swept:
        return {}
    inputs = [draws[j]["resweep"]["u"] for j in swept]
    v, phi, windup = _transmission(
        _padded(inputs), [specs[j] for j in swept], [draws[j]["cfg_after"] for j in swept], mechanism
    )
    out = {}
    for i, j in enumerate(swept):
        n, k = len(inputs[i]), draws[j]["change_index"]
        out[j] = (np.concatenate([v_all[:k, j], v[k:n, i]]), phi[:n, i], windup[:n, i])
    return out


class _Recording(NamedTuple):
    """One recorded run: what its rows in ``X`` and its row in ``runs`` are made of.

    ``start`` is the sample of the simulated run at which the recording
    starts (its time ``t`` is ``(start + i) / rate_hz``); ``drift`` holds
    the run's own offsets and gains at its first motion sample, less its
    setting's (:func:`_drift_columns`), and ``columns`` the extra columns of
    its row in ``runs``.
    """

    run: str
    setting: ShaftSetting
    start: int
    q: np.ndarray
    n_sweep: int
    tau: np.ndarray
    y: np.ndarray
    y_true: np.ndarray
    sensors: np.ndarray
    rate_hz: float
    drift: dict
    columns: dict

    def head(self, n):
        """The recording of the first ``n`` samples."""
        return self._replace(
            q=self.q[:n], tau=self.tau[:n], y=self.y[:n], y_true=self.y_true[:n],
            sensors=self.sensors[:n],
        )


def _drift_columns(q, u, gain_scale, setting_offsets, i):
    """The run's own deviation from its setting at sample ``i``.

    Per-run jitter plus the slow drift until then: motor offsets (deg) and
    relative tendon gains, per motor, as columns of the ``runs`` table
    (``offset_drift1_deg``, ... then ``gain_drift1``, ...).
    """
    offset_drift = (q[i] - u[i]) - setting_offsets
    gain_drift = gain_scale[i] - 1.0
    columns = {f"offset_drift{k + 1}_deg": float(x) for k, x in enumerate(offset_drift)}
    return columns | {f"gain_drift{k + 1}": float(x) for k, x in enumerate(gain_drift)}


def _recordings(spec, draw, finished, swept, *, with_change, with_resweep):
    """The recordings of one simulated run: the run, or its parts before and after a re-sweep.

    ``finished`` is the output of :func:`_finish_run`; ``swept`` that of
    :func:`_finish_resweep` for a run that sweeps again after its change,
    else None. The part after a re-sweep is the run ``"<run>/after"`` in the
    new setting, whose ``before_run`` names the run.
    """
    k = draw.get("change_index")
    columns = {}
    if with_change:
        columns["setting_after"] = None if k is None else spec.change.setting.name
        columns["change_time_s"] = np.nan if k is None else k / draw["rate_hz"]
    if with_resweep:
        columns["before_run"] = None
    drift = _drift_columns(draw["q"], draw["u"], draw["gain_scale"], draw["cfg"]["offsets"], draw["n_sweep"])
    run = _Recording(spec.run, spec.setting, 0, draw["q"], draw["n_sweep"], *finished, draw["rate_hz"], drift, columns)
    if swept is None:
        return [run]
    part = draw["resweep"]
    n_home = part["n_home"]
    # the part's own arrays start at the change; its input u at the run's start
    first = n_home + draw["n_sweep"]
    drift = _drift_columns(
        part["q"], part["u"][k:], part["gain_scale"], draw["cfg_after"]["offsets"], first
    )
    after = _Recording(
        f"{spec.run}{AFTER_SUFFIX}", spec.change.setting, k + n_home, part["q"][n_home:],
        draw["n_sweep"], *swept, draw["rate_hz"], drift,
        {**columns, "setting_after": None, "change_time_s": np.nan, "before_run": spec.run},
    )
    return [run.head(k), after]


def _run_frame(rec, catheter):
    """The long-format rows of one recording (reference tip on sweep rows only)."""
    n = len(rec.q)
    sweep = np.arange(n) < rec.n_sweep
    ref = np.where(sweep[:, None], rec.y, np.nan)
    motors = range(rec.q.shape[1])
    return pd.DataFrame(
        {
            fmt.CATHETER: catheter.name,
            fmt.SETTING: rec.setting.name,
            fmt.RUN: rec.run,
            fmt.TIME: (rec.start + np.arange(n)) / rec.rate_hz,
            fmt.PHASE: np.where(sweep, fmt.SWEEP, fmt.MOTION),
            **{f"q{k + 1}": rec.q[:, k] for k in motors},
            **{f"tau{k + 1}": rec.tau[:, k] for k in motors},
            "ref_x": ref[:, 0], "ref_y": ref[:, 1], "ref_z": ref[:, 2],
        }
    )


def _run_row(rec, spec):
    """The row of one recording in the ``runs`` table (noise floor over motion rows, mm)."""
    n = len(rec.q)
    motion = np.arange(n) >= rec.n_sweep
    err = np.linalg.norm(rec.y[motion] - rec.y_true[motion], axis=1)
    return {
        "run": rec.run,
        "catheter": spec.catheter.name,
        "setting": rec.setting.name,
        "repeat": spec.repeat,
        "bend_level": rec.setting.level,
        "bend_direction_deg": rec.setting.direction_deg,
        "shaft_wrap_deg": rec.setting.bend_deg,
        "n_samples": int(n),
        "n_sweep": int(rec.n_sweep),
        "noise_floor_mm": float(np.sqrt(np.nanmean(err**2))),
        **rec.drift,
        **rec.columns,
    }


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
        the per-sample noise keeps its standard deviation per sample. Runs
        with a re-sweep after their shaft change are simulated at 10 Hz only.

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
    n_motors = {s.catheter.n_motors for s in specs}
    if len(n_motors) > 1:
        raise ValueError(
            f"specs: every run must be of an instrument with the same number of motors; "
            f"got catheters of {sorted(n_motors)} motors."
        )
    draws = [_draw_run(s, variation, float(rate_hz)) for s in specs]
    lengths = np.array([len(d["q"]) for d in draws])
    u = _padded([d["u"] for d in draws])
    v_all, phi_all, windup_all = _transmission(
        u, specs, [d["cfg"] for d in draws], mechanism, float(rate_hz)
    )
    changed = [j for j, d in enumerate(draws) if "change_index" in d]
    if changed:
        _splice_changes(u, v_all, phi_all, windup_all, changed, specs, draws, lengths, mechanism)
    swept = _resweep_transmission(v_all, specs, draws, mechanism)

    recordings = []
    for j, (spec, d) in enumerate(zip(specs, draws)):
        n = lengths[j]
        finished = _finish_run(
            spec, d, v_all[:n, j], phi_all[:n, j], windup_all[:n, j], field, dropout_rate,
            variation,
        )
        after = None
        if j in swept:
            after = _finish_resweep(spec, d, *swept[j], field, dropout_rate, variation)
        recordings += [
            (spec, rec) for rec in _recordings(
                spec, d, finished, after, with_change=bool(changed), with_resweep=bool(swept)
            )
        ]
    frames = [_run_frame(rec, spec.catheter) for spec, rec in recordings]
    rows = [_run_row(rec, spec) for spec, rec in recordings]
    ys, ys_true, sensors = ([getattr(rec, name) for _, rec in recordings] for name in ("y", "y_true", "sensors"))
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
        "resweep": ["boolean"],
        "rate_hz": [Interval(Real, 1, MAX_RATE_HZ, closed="both")],
        "n_motors": [MotorCount()],
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
    resweep=False,
    rate_hz=RATE_HZ,
    n_motors=2,
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
    resweep : bool, default=False
        With ``setting_after``: at the change, the run performs its sweep
        again in the new setting, then goes on with the rest of its motion
        (see :func:`make_benchmark`, ``resweep``). The part after the change
        is the run ``run + "/after"``. Simulated at 10 Hz only.
    rate_hz : float, default=10.0
        Sample rate (Hz), from 1 to 1000. The same run (motion, catheter,
        drifts, base pose) sampled at this rate, with fresh per-sample noise
        of the same standard deviation (``docs/studies/simulator.rst``, *Sample
        rate*); 10 gives the runs of the benchmark.
    n_motors : {1, 2, 3}, default=2
        Motors of the instrument (``docs/studies/simulator.rst``, *Instruments of
        one and three motors*): one tendon pair bending in one plane (a
        2-ray sweep, a walk in an interval), two pairs (the benchmark's), or
        three single tendons at 120 degrees (a 6-ray sweep). The columns are
        ``q1 .. qN`` and ``tau1 .. tauN``. A given ``catheter`` must have
        this number of motors (:func:`sample_catheter`). ``resweep`` is
        simulated for two motors only.

    Returns
    -------
    bunch : sklearn.utils.Bunch
        ``X`` (long format, see ``docs/data_format.rst``), ``y`` (n, 3)
        measured tip in the base frame (mm), ``y_true`` (n, 3) noise-free tip,
        ``sensors`` (raw EM poses), ``runs`` (one row), ``noise_floor`` (mm).
        With ``setting_after``, ``runs`` also has ``setting_after`` and
        ``change_time_s`` (time ``t`` of the first sample in the new
        setting, s). Up to the change, the run is identical to the same run
        without a change. With ``resweep``, ``runs`` has two rows and the
        column ``before_run``.
    """
    root = np.random.SeedSequence(_entropy(random_state))
    seeds = root.spawn(3)
    if catheter is None:
        catheter = sample_catheter(seeds[0], "C1", n_motors=n_motors)
    elif catheter.n_motors != n_motors:
        raise ValueError(
            f"catheter {catheter.name!r} has {catheter.n_motors} motor(s), but "
            f"n_motors={n_motors}; pass n_motors={catheter.n_motors} or a unit of {n_motors}."
        )
    setting = _lookup_setting("setting", "S01" if setting is None else setting)
    change = None
    if setting_after is not None:
        setting_after = _lookup_setting("setting_after", setting_after)
        if setting_after.name == setting.name:
            raise ValueError(f"setting_after={setting_after.name!r} must differ from setting.")
        change = ShaftChange(setting_after, float(change_after_s), root.spawn(1)[0], resweep)
    elif resweep:
        raise ValueError(
            "resweep=True sweeps again after the shaft change; it needs setting_after."
        )
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
