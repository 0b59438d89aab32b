"""A simulated catheter driven one sample at a time: the benchmark's physics in closed loop.

:class:`SimulatedCatheter` is a run of the simulated benchmark whose motion
phase takes its motor angles from the caller instead of the protocol's
random walk. It performs the run's calibration sweep at :meth:`reset`, then
advances one sample per :meth:`step`. Every random number of the run is the
one :func:`~skcath.datasets.make_benchmark` draws for it (the run's noise is
drawn at ``reset`` for the run's length and, past it, in blocks from a
stream of its own), so that a rig driven with the motor path of a benchmark
run records that run sample for sample, bit for bit as ``simulate_runs``
simulates it alone (a three-motor run simulated among others differs by
about 1e-13 mm: the matrix products of the wind-up round differently with
the number of runs).

The stateless part of a sample (kinematics, torque, sensors) is evaluated
on two identical rows: numpy's matrix product of a single row takes
another code path than that of many rows, whose rounding differs in the
last bit.
"""

import copy
import dataclasses
import warnings
from numbers import Integral, Real

import numpy as np
from scipy.spatial.transform import Rotation
from sklearn.base import BaseEstimator
from sklearn.exceptions import NotFittedError
from sklearn.utils._param_validation import Interval, StrOptions

from .. import _format as fmt
from ..exceptions import MotorLimitWarning
from ._benchmark import _benchmark_field, benchmark_catheter, benchmark_specs
from ._catheter import UNIT_SPREAD, Catheter, ShaftSetting
from ._hysteresis import MECHANISMS, WindupStepper, play_width, transmission_stepper
from ._simulator import (
    MAX_RATE_HZ,
    RATE_HZ,
    _base_pose,
    _draw_run,
    _lookup_setting,
    _base_sensor_pose,
    _measured_tip,
    _measurement_noise,
    _mechanics,
    _noise_stream,
    _ou_from,
    _Recording,
    _run_frame,
    _tip_pose,
    _torque_reading,
    _transmission_params,
    check_run_variation,
)
from ._sensors import noisy_pose
from ._tendons import MotorCount, tendon_layout

__all__ = ["SimulatedCatheter"]

#: Length of each block of noise and drift drawn past the end of the benchmark run (s).
_BLOCK_S = 60.0


class _Lag:
    """The first-order lag of ``_lag`` (``scipy.signal.lfilter``), one sample at a time, bit for bit."""

    def __init__(self, tau_s, rate_hz):
        self.alpha = 1.0 - np.exp(-1.0 / (rate_hz * tau_s))
        self.a1 = self.alpha - 1.0
        self.z = None

    def step(self, x):
        if self.z is None:  # starts at rest at the first input
            self.z = (1.0 - self.alpha) * x
        y = x * self.alpha + self.z
        self.z = 0.0 * x - y * self.a1
        return y


class _Dynamics:
    """The stateful part of a run: transmission, wind-up, tendon creep and section lag.

    ``step(u_k)`` takes the motor input (deg, shape (1, n_motors)) of the next
    sample and returns its lagged effective input, friction utilisation and
    wind-up, as ``simulate_runs`` computes them over the whole run.
    """

    def __init__(self, spec, cfg, mechanism, rate_hz):
        cat = spec.catheter
        self.spec, self.cfg, self.mechanism, self.rate_hz = spec, cfg, mechanism, rate_hz
        self.layout = tendon_layout(cat.n_motors)
        self.windup = WindupStepper(np.array([cfg["windup"]]))
        self.creep = _Lag(cat.slow_creep_tau, rate_hz)
        self.lag = _Lag(cat.tip_lag, rate_hz)
        self.transmission = None

    def step_rows(self, u):
        """Lagged effective inputs, friction utilisations and wind-ups of the rows of ``u``.

        ``u`` of shape (n, n_motors): n alternative motor inputs (deg) of the
        next sample, each stepped from the same state (the state then holds
        n rows); returns three arrays of n rows.
        """
        if self.transmission is None:
            params = _transmission_params([self.spec], [self.cfg])
            self.transmission = transmission_stepper(u, 1.0 / self.rate_hz, params, self.mechanism)
        v, phi = self.transmission.step(u)
        windup = self.windup.step(self.layout.bending_inputs(u[None])[0])
        v = v - self.spec.catheter.slow_creep_gain * self.creep.step(v)
        return self.lag.step(v), phi, windup

    def step(self, u):
        lagged, phi, windup = self.step_rows(u)
        return lagged[0], phi[0], windup[0]


def _check_command(command, n_motors):
    """The command as a float array of shape (n_motors,), or a clear error."""
    try:
        c = np.asarray(command, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"command must be {n_motors} motor angle(s) in degrees; got {command!r}."
        ) from exc
    if c.ndim > 1 or c.size != n_motors:
        raise ValueError(
            f"command must hold one angle per motor, {n_motors} value(s) (n_motors={n_motors}); "
            f"got shape {c.shape}."
        )
    c = c.reshape(n_motors)
    if not np.all(np.isfinite(c)):
        raise ValueError(f"command must be finite motor angles in degrees; got {c.tolist()}.")
    return c


class SimulatedCatheter(BaseEstimator):
    """A simulated catheter and tracker that a controller drives one sample at a time.

    The rig is a run of :func:`make_benchmark`: the unit ``catheter`` in the
    shaft ``setting``, its run ``repeat``, with the physics of the benchmark
    (hysteresis ``mechanism``, tendon creep, lag of the section, wind-up,
    drifting offsets and gains, capstan torque, noisy EM sensors in the
    distorted field of ``random_state``). :meth:`reset` performs the run's
    calibration sweep and returns its rows; each :meth:`step` then takes the
    motor angles of the next sample and returns what the rig measures.

    Timing: the motor is an ideal position servo, as in the simulator: a
    command is the motor angle at the *next* sample. The torque of a sample
    holds the motor's speed there, the central difference of the angles
    before and after it (``numpy.gradient``), so a sample's record is
    complete once the next angle is known: ``step(command)`` returns the
    record of the current sample ``k`` (whose angle is the previous
    command) and sets the angle of sample ``k + 1`` to ``command``. The
    first motion sample, which :meth:`reset` leaves pending, holds the
    protocol's own first motion angle (the start of its random walk, within
    a tenth of a degree of neutral), so the first command acts one sample
    later. A controller that reads the record of sample ``k`` thus moves the
    motor at sample ``k + 2``.

    Parameters
    ----------
    catheter : int or Catheter, default=1
        The unit: its number ``k`` (the unit ``"Ck"`` of
        :func:`benchmark_catheter` ``(k, random_state, unit_spread=unit_spread,
        n_motors=n_motors)``), or a :class:`Catheter` named ``"Ck"`` of
        ``n_motors`` motors, which runs the runs of unit ``Ck`` (as
        ``make_benchmark(catheters=...)``).
    setting : str or ShaftSetting, default="S01"
        Shaft setting, or the name of one of :func:`shaft_settings`.
    repeat : int, default=1
        Which run of the unit in the setting: its sweep speed and length,
        per-run variation, base pose and noise are those of the benchmark's
        run ``"Ck-<setting>-R<repeat>"`` (a repeat above the benchmark's
        ``n_runs`` is a run no benchmark of that size holds).
    mechanism : {"play", "bouc_wen", "dahl_creep"}, default="play"
        Hysteresis mechanism of the tendon transmission.
    n_motors : {1, 2, 3}, default=2
        Motors of the instrument (see :func:`make_benchmark`).
    rate_hz : float, default=10.0
        Sample rate (Hz), from 1 to 1000.
    tracker : bool, default=False
        Whether the EM tracker stays on after the sweep: the records hold the
        measured tip ``x``, ``y``, ``z`` (mm, base frame) only then. The
        sweep is always tracked.
    unit_spread : float in [0, 1], default=0.35
        Unit-to-unit spread of a unit given by its number.
    run_variation : dict or None, default=None
        Per-run variation replacing values of the simulator's defaults (see
        :func:`make_benchmark`).
    dropout_rate : float in [0, 1), default=0.0
        Probability that the tip sensor is lost at a sample (NaN tip).
    motor_limit_deg : float, default=60.0
        Range of each motor, ``[-motor_limit_deg, motor_limit_deg]`` (deg);
        the benchmark's motors stay within 60 degrees. A command beyond it
        is clipped to it, with a :class:`~skcath.exceptions.MotorLimitWarning`
        at the first clipped command of a run.
    random_state : int, default=0
        Seed of the benchmark the run belongs to (as ``make_benchmark``'s):
        the drawn unit, the run's draws and the tracker's field distortion.

    Attributes
    ----------
    sweep_ : pandas.DataFrame
        The sweep's rows in the recording format (``docs/data_format.rst``),
        with the tracked tip in ``ref_x``, ``ref_y``, ``ref_z``.
    catheter_ : Catheter
        The unit.
    run_length_ : int
        Samples of the benchmark run; a rig stepped past them goes on with
        drifts and noise drawn in blocks of 60 s from a stream of the run's
        own.
    t_ : float
        Time (s) of the sample of the last record (the last sweep row after
        :meth:`reset`).
    tip_ : ndarray of shape (3,)
        Noise-free tip (mm, base frame) of the sample of the last record.
    n_steps_ : int
        Steps since :meth:`reset`.
    n_clipped_ : int
        Commands clipped to the motor range since :meth:`reset`.

    Examples
    --------
    >>> from skcath.datasets import SimulatedCatheter
    >>> rig = SimulatedCatheter(catheter=5, setting="S05", tracker=True)
    >>> sweep = rig.reset()  # doctest: +SKIP
    >>> obs = rig.step([10.0, -5.0])  # doctest: +SKIP
    >>> sorted(obs)  # doctest: +SKIP
    ['q1', 'q2', 't', 'tau1', 'tau2', 'x', 'y', 'z']
    """

    _parameter_constraints = {
        "catheter": [Interval(Integral, 1, None, closed="left"), Catheter],
        "setting": [str, ShaftSetting],
        "repeat": [Interval(Integral, 1, None, closed="left")],
        "mechanism": [StrOptions(set(MECHANISMS))],
        "n_motors": [MotorCount()],
        "rate_hz": [Interval(Real, 1, MAX_RATE_HZ, closed="both")],
        "tracker": ["boolean"],
        "unit_spread": [Interval(Real, 0, 1, closed="both")],
        "run_variation": [dict, None],
        "dropout_rate": [Interval(Real, 0, 1, closed="left")],
        "motor_limit_deg": [Interval(Real, 0, None, closed="neither")],
        "random_state": [Interval(Integral, 0, None, closed="left")],
    }

    def __init__(self, catheter=1, setting="S01", *, repeat=1, mechanism="play", n_motors=2,
                 rate_hz=RATE_HZ, tracker=False, unit_spread=UNIT_SPREAD, run_variation=None,
                 dropout_rate=0.0, motor_limit_deg=60.0, random_state=0):
        self.catheter = catheter
        self.setting = setting
        self.repeat = repeat
        self.mechanism = mechanism
        self.n_motors = n_motors
        self.rate_hz = rate_hz
        self.tracker = tracker
        self.unit_spread = unit_spread
        self.run_variation = run_variation
        self.dropout_rate = dropout_rate
        self.motor_limit_deg = motor_limit_deg
        self.random_state = random_state

    def _unit(self):
        if isinstance(self.catheter, Catheter):
            cat = self.catheter
            if cat.n_motors != self.n_motors:
                raise ValueError(
                    f"catheter {cat.name!r} has {cat.n_motors} motor(s), but "
                    f"n_motors={self.n_motors}; pass n_motors={cat.n_motors} or a unit of "
                    f"{self.n_motors}."
                )
            return cat
        return benchmark_catheter(
            int(self.catheter), int(self.random_state), unit_spread=self.unit_spread,
            n_motors=self.n_motors,
        )

    def _spec(self, cat, setting):
        """The benchmark's run ``repeat`` of the unit in the setting."""
        specs = benchmark_specs([cat], int(self.repeat), int(self.random_state))
        found = [s for s in specs if s.setting.name == setting.name and s.repeat == self.repeat]
        if not found:
            raise ValueError(
                f"setting {setting.name!r} is not one of the benchmark's settings "
                f"{sorted({s.setting.name for s in specs})}; the rig runs the benchmark's runs."
            )
        return dataclasses.replace(found[0], setting=setting)

    def reset(self):
        """Start the run: perform its calibration sweep.

        Returns
        -------
        sweep : pandas.DataFrame
            The sweep's rows in the recording format, as the benchmark's run
            starts (``catheter``, ``setting``, ``run``, ``t``, ``phase``,
            ``q1 .. qN``, ``tau1 .. tauN``, ``ref_x``, ``ref_y``, ``ref_z``).
        """
        self._validate_params()
        variation = check_run_variation(self.run_variation)
        cat = self._unit()
        setting = _lookup_setting("setting", self.setting)
        spec = self._spec(cat, setting)
        rate = float(self.rate_hz)
        draw = _draw_run(spec, variation, rate)
        n, n_sweep = len(draw["q"]), draw["n_sweep"]
        noise = _noise_stream(spec, draw, (draw["n_protocol"], cat.n_motors))
        self._noise = {
            "offsets": draw["offsets"], "gain_scale": draw["gain_scale"],
            "torque": noise.normal(0.0, cat.torque_noise, size=(n, cat.n_motors)),
        }
        self._base = _base_pose(draw["rng"], setting, variation)
        self._draw, self._variation, self._field = (
            draw, variation, _benchmark_field(int(self.random_state))
        )
        self.catheter_, self.run_length_ = cat, n
        self._mount = Rotation.from_rotvec(cat.mount_rotvec)
        self._add_sensor_noise(_measurement_noise(noise, n, self.dropout_rate))
        key = (*spec.seed.spawn_key, 3)
        self._extra = np.random.default_rng(np.random.SeedSequence(spec.seed.entropy, spawn_key=key))
        self.n_steps_, self.n_clipped_ = 0, 0
        self.sweep_ = self._sweep(spec, draw)
        return self.sweep_

    def _sweep(self, spec, draw):
        """Simulate the sweep and the first motion sample; the sweep's rows."""
        cat, n_sweep, rate = spec.catheter, draw["n_sweep"], float(self.rate_hz)
        self._dynamics = _Dynamics(spec, draw["cfg"], self.mechanism, rate)
        rows = np.arange(n_sweep + 1)
        states = [self._dynamics.step(draw["u"][k][None]) for k in rows]
        lagged, phi, windup = (np.array(x) for x in zip(*states))
        drive, y_true, y, sensors = self._rows(rows, lagged, phi, windup, tracked=True)
        q = draw["q"][: n_sweep + 1]
        omega = np.gradient(q, 1.0 / rate, axis=0)[:n_sweep]
        tau = _torque_reading(cat, omega, drive[:n_sweep], self._noise["torque"][:n_sweep])
        rec = _Recording(
            spec.run, spec.setting, 0, q[:n_sweep], n_sweep, tau, y[:n_sweep], y_true[:n_sweep],
            sensors[:n_sweep], rate, {}, {},
        )
        frame = _run_frame(rec, cat)
        for col in (*fmt.ID_COLUMNS, fmt.PHASE):
            frame[col] = frame[col].astype("category")
        # the pending sample: the protocol's first motion angle
        self._k = n_sweep
        self._q = (q[n_sweep - 1], q[n_sweep])
        self._pending = (drive[n_sweep], y_true[n_sweep], y[n_sweep])
        self.t_, self.tip_ = (n_sweep - 1) / rate, y_true[n_sweep - 1]
        return frame

    def _add_sensor_noise(self, noise):
        """Append the sensor noise of samples to come, and the base sensor's reading at them.

        The base of the section does not move during a run, so the base
        sensor's reading depends on its noise only.
        """
        tip, base, lost = noise
        base_pose = _base_sensor_pose(self.catheter_, *self._base, len(tip[0]))
        reading = noisy_pose(*base_pose, self._field, base)
        parts = (tip, reading, lost)
        old = self._noise.get("sensors")
        if old is not None:
            parts = (
                tuple(np.concatenate(pair) for pair in zip(old[0], tip)),
                tuple(np.concatenate(pair) for pair in zip(old[1], reading)),
                None if lost is None else np.concatenate([old[2], lost]),
            )
        self._noise["sensors"] = parts

    def _rows(self, rows, lagged, phi, windup, *, tracked):
        """Drive torque, noise-free and measured tip, sensor poses of samples ``rows``.

        Stateless given the dynamics' outputs; ``y`` and the poses are None
        when not ``tracked``.
        """
        cat, cfg = self.catheter_, self._draw["cfg"]
        gain_scale = self._noise["gain_scale"][rows]
        a, delta, p_k, drive = _mechanics(cat, cfg, lagged, phi, windup, gain_scale)
        y_true = self._mount.apply(p_k - cat.mount_position)  # _mounted
        if not tracked:
            return drive, y_true, None, None
        tip, base, lost = self._noise["sensors"]
        y, sensors = _measured_tip(
            _tip_pose(*self._base, p_k, a, delta), (base[0][rows], base[1][rows]), self._field,
            (tip[0][rows], tip[1][rows]), None if lost is None else lost[rows],
        )
        return drive, y_true, y, sensors

    def _extend(self):
        """Draw the drifts and the noise of the next block of samples past the run's end."""
        nz, draw, rate, cat = self._noise, self._draw, float(self.rate_hz), self.catheter_
        v = self._variation
        n0 = len(nz["torque"])
        m = int(round(_BLOCK_S * rate))
        t0, t = (n0 - 1) / rate, np.arange(n0, n0 + m) / rate
        knots = t0 + np.arange(int(np.ceil(_BLOCK_S * RATE_HZ)) + 2) / RATE_HZ
        rng = self._extra
        moved = {}
        for name, std, tau in (("offsets", "offset_drift_deg", "offset_drift_tau_s"),
                               ("gains", "gain_drift", "gain_drift_tau_s")):
            jitter, drift = draw["drifts"][name]
            last = drift[-1]
            ahead = np.vstack([last, _ou_from(rng, last, len(knots) - 1, v[std], v[tau])])
            interp = np.column_stack([np.interp(t, knots, ahead[:, j]) for j in range(len(last))])
            draw["drifts"][name] = (jitter, interp)
            moved[name] = jitter + interp
        nz["offsets"] = np.vstack([nz["offsets"], draw["cfg"]["offsets"] + moved["offsets"]])
        nz["gain_scale"] = np.vstack([nz["gain_scale"], 1.0 + moved["gains"]])
        nz["torque"] = np.vstack([nz["torque"], rng.normal(0.0, cat.torque_noise, size=(m, cat.n_motors))])
        self._add_sensor_noise(_measurement_noise(rng, m, self.dropout_rate))

    def _clip(self, c):
        limit = float(self.motor_limit_deg)
        clipped = np.clip(c, -limit, limit)
        if np.any(clipped != c):
            if self.n_clipped_ == 0:
                warnings.warn(
                    f"command {c.tolist()} leaves the motor range of +-{limit:g} deg "
                    f"(motor_limit_deg); clipped to {clipped.tolist()}.",
                    MotorLimitWarning,
                    stacklevel=3,
                )
            self.n_clipped_ += 1
        return clipped

    def _check_reset(self, method):
        if not hasattr(self, "_pending"):
            raise NotFittedError(f"This SimulatedCatheter has no run yet; call reset() before {method}().")

    def tips_ahead(self, paths):
        """Noise-free tips of the next samples along candidate command paths; the rig does not move.

        The truth a controller cannot measure, for bounds of what steering
        can reach: each candidate path is stepped through copies of the run's
        transmission, wind-up, tendon creep and section lag from their
        present state, with the run's own offsets and gains of those samples
        (the draws its :meth:`step` calls will make), as :meth:`step` would
        (commands clipped to the motor range, without warning). The first
        command of a path is the one the next :meth:`step` would take.

        Parameters
        ----------
        paths : array-like of shape (n_ahead, n_candidates, n_motors)
            Motor commands (deg) of the next ``n_ahead`` samples of each
            candidate path.

        Returns
        -------
        tips : ndarray of shape (n_ahead, n_candidates, 3)
            The noise-free tip (mm, base frame) of each of those samples:
            ``tips[i, c]`` is the tip :attr:`tip_` shows after the ``i + 2``-th
            :meth:`step` along path ``c`` (the record of a commanded sample
            comes back one step later), equal to it within rounding (about
            1e-13 mm: the candidates are evaluated together).
        """
        self._check_reset("tips_ahead")
        paths = np.asarray(paths, dtype=float)
        if paths.ndim != 3 or paths.shape[2] != self.n_motors or 0 in paths.shape[:2]:
            raise ValueError(
                f"paths must have shape (n_ahead, n_candidates, {self.n_motors}) (commands, deg); "
                f"got shape {paths.shape}."
            )
        if not np.all(np.isfinite(paths)):
            raise ValueError("paths must be finite motor angles in degrees; they contain NaN or inf.")
        while self._k + len(paths) >= len(self._noise["torque"]):
            self._extend()  # the same draws that the rig's own steps make
        limit = float(self.motor_limit_deg)
        dynamics, tips = copy.deepcopy(self._dynamics), []
        for j, commands in enumerate(paths, start=self._k + 1):
            u = np.clip(commands, -limit, limit) - self._noise["offsets"][j]
            tips.append(self._rows(np.full(len(u), j), *dynamics.step_rows(u), tracked=False)[1])
        return np.array(tips)

    def play_crossing(self, command):
        """The motor travel (deg) after a reversal at ``command`` before the unit play element moves.

        ``(1 + asym) w(u)`` per motor, with ``w`` the load-dependent width of
        the run's play (:mod:`skcath.datasets._hysteresis`) at the motor input
        of ``command``; the play's elements are 0.3 to 8 times as wide. NaN
        for the other mechanisms.

        Parameters
        ----------
        command : array-like of shape (n_motors,)
            Motor angles (deg).

        Returns
        -------
        crossing : ndarray of shape (n_motors,)
        """
        self._check_reset("play_crossing")
        c = _check_command(command, self.n_motors)
        if self.mechanism != "play":
            return np.full(self.n_motors, np.nan)
        params = self._dynamics.transmission.params
        return ((1.0 + params["asym"]) * play_width(c[None], params))[0]

    def step(self, command):
        """Set the motor angles of the next sample; the record of the current one.

        Parameters
        ----------
        command : array-like of shape (n_motors,)
            Motor angles (deg) of the next sample. Commands beyond
            ``motor_limit_deg`` are clipped (see the class's description).

        Returns
        -------
        obs : dict
            The record of the current sample: ``t`` (s), ``q1 .. qN`` (deg),
            ``tau1 .. tauN`` (N mm) and, with ``tracker``, the measured tip
            ``x``, ``y``, ``z`` (mm, base frame; NaN when the sensor is lost).
            Its noise-free tip is :attr:`tip_`.

        Raises
        ------
        ValueError
            For a command that is not ``n_motors`` finite numbers.
        sklearn.exceptions.NotFittedError
            Before :meth:`reset`.
        """
        self._check_reset("step")
        c = self._clip(_check_command(command, self.n_motors))
        k, rate, (q_prev, q_k) = self._k, float(self.rate_hz), self._q
        drive, y_true, y = self._pending
        omega = (c - q_prev) / (2.0 * (1.0 / rate))  # numpy.gradient inside a run
        tau = _torque_reading(self.catheter_, omega, drive, self._noise["torque"][k])
        obs = {"t": k / rate}
        obs.update({f"q{j + 1}": float(x) for j, x in enumerate(q_k)})
        obs.update({f"tau{j + 1}": float(x) for j, x in enumerate(tau)})
        if self.tracker:
            obs.update(zip("xyz", map(float, y)))
        self.t_, self.tip_ = obs["t"], y_true
        # the next sample
        if k + 1 >= len(self._noise["torque"]):
            self._extend()
        lagged, phi, windup = self._dynamics.step((c - self._noise["offsets"][k + 1])[None])
        rows = np.array([k + 1, k + 1])  # two rows: see the module's docstring
        drive, y_true, y, _ = self._rows(
            rows, np.array([lagged] * 2), np.array([phi] * 2), np.array([windup] * 2),
            tracked=self.tracker,
        )
        self._pending = (drive[0], y_true[0], None if y is None else y[0])
        self._k, self._q = k + 1, (q_k, c)
        self.n_steps_ += 1
        return obs
