"""Catheter units, shaft settings, and the parameters of one run.

Three levels of variation, as on a bench:

* **catheter** (unit-to-unit): geometry of the bending section, tendon
  gains, offsets, friction coefficient, play, drive-train constants, and the
  mounting of the base sensor;
* **shaft setting** (the passive shaft held bent in one of 8 directions at
  one of 2 levels, or straight): the capstan wrap ``Theta`` of the tendons
  through the shaft, which changes play, dead zone, gains, offsets, coupling
  and resting curvature, each through a physical route documented below;
* **run** (repeats of one setting): small gain and offset jitter, slow drift,
  and the slightly different base pose after re-installation.
"""

from dataclasses import asdict, dataclass, replace
from numbers import Integral, Real

import numpy as np
from scipy.spatial.transform import Rotation
from sklearn.utils._param_validation import Interval, validate_params

from ._tendons import MotorCount, tendon_layout

__all__ = [
    "Catheter",
    "ShaftSetting",
    "TENDON_AZIMUTHS",
    "sample_catheter",
    "setting_parameters",
    "shaft_settings",
]

#: Azimuth of the tendon pulled by a positive / negative input of each axis
#: of the two-motor instrument (rad); axis 1 bends towards +x, axis 2
#: towards +y (:func:`~skcath.datasets._tendons.tendon_layout` gives those of
#: one and three motors).
TENDON_AZIMUTHS = tendon_layout(2).azimuths


@dataclass(frozen=True)
class ShaftSetting:
    """One configuration of the passive shaft, held fixed during a run.

    Attributes
    ----------
    name : str
        Setting id, ``"S00"`` for straight.
    level : str
        ``"straight"``, ``"low"`` or ``"high"``.
    direction_deg : float
        Direction of the shaft bend about the catheter axis (degrees); NaN
        when straight.
    bend_deg : float
        Total capstan wrap of the tendons through the shaft (degrees),
        including the curvature a straight setting still has in the
        introducer and the robot.
    """

    name: str
    level: str
    direction_deg: float
    bend_deg: float

    @property
    def wrap(self):
        """Capstan wrap angle ``Theta`` (rad)."""
        return np.deg2rad(self.bend_deg)

    def bend_vector(self):
        """Unit vector of the bend direction, zero when straight."""
        if self.level == "straight":
            return np.zeros(2)
        b = np.deg2rad(self.direction_deg)
        return np.array([np.cos(b), np.sin(b)])


@validate_params(
    {
        "n_directions": [Interval(Integral, 1, None, closed="left")],
        "levels": ["array-like"],
        "straight_wrap_deg": [Interval(Real, 0, None, closed="left")],
    },
    prefer_skip_nested_validation=True,
)
def shaft_settings(*, n_directions=8, levels=(("low", 90.0), ("high", 180.0)), straight_wrap_deg=30.0):
    """The protocol's shaft settings: straight, then directions x levels.

    Parameters
    ----------
    n_directions : int
        Number of evenly spaced shaft-bend directions.
    levels : sequence of (str, float)
        Name and added capstan wrap (degrees) of each bend level.
    straight_wrap_deg : float
        Wrap of the straight setting (introducer and robot), added to every level.

    Returns
    -------
    settings : list of ShaftSetting
        ``1 + n_directions * len(levels)`` settings named ``S00``, ``S01``, ...
        (17 by default: straight, 8 low, 8 high).
    """
    out = [ShaftSetting("S00", "straight", float("nan"), straight_wrap_deg)]
    for level, wrap in levels:
        for k in range(n_directions):
            out.append(
                ShaftSetting(
                    f"S{len(out):02d}", level, 360.0 * k / n_directions, straight_wrap_deg + wrap
                )
            )
    return out


@dataclass(frozen=True)
class Catheter:
    """Physical parameters of one catheter unit (lengths mm, angles rad unless noted).

    Attributes
    ----------
    name : str
        Catheter id.
    length, tip_length : float
        Bending-section and rigid-tip lengths (mm).
    split_fraction, split_bias, split_slope : float
        Uneven curvature: the proximal sub-arc spans ``split_fraction`` of the
        length and takes the share ``split_fraction + split_bias +
        split_slope (a - 1)`` of the bend ``a``.
    max_bend : float
        Saturation of the bend magnitude (rad).
    twist : float
        Twist of the bend plane per radian of bend.
    coupling : ndarray of shape (2,)
        Cross-axis coupling ``(c12, c21)`` between the tendon pairs.
    rest_bend : ndarray of shape (2,)
        Resting curvature of the bending section (rad).
    gains : ndarray of shape (n_motors, 2)
        Bend per effective tendon input (rad/deg) of each motor (rows) for
        positive / negative inputs (columns).
    offsets : ndarray of shape (n_motors,)
        Motor offsets (degrees); their number is the unit's number of
        motors (2, the benchmark's; 1 and 3 for the instruments of
        :func:`~skcath.datasets._tendons.tendon_layout`).
    mu : float
        Sheath friction coefficient of the capstan law ``exp(mu Theta)``.
    play_w0, play_growth_base, play_growth_scale, play_asym : float
        Play width at zero load and one radian of wrap (deg; it scales
        with each tendon pair's wrap, see :func:`setting_parameters`);
        growth of the width with load, ``base + scale (1 - exp(-mu
        Theta))`` (deg/deg); and the unloading/loading width ratio.
    bw_kappa : float
        Bouc-Wen sharpness.
    rate_gain, rate_speed, creep_gain, creep_tau : float
        Rate dependence of the friction limit (gain, deg/s) and tendon creep
        (gain, s) of the rate-dependent mechanism.
    dead_zone0, dead_zone_growth : float
        Dead-zone width at zero wrap (deg) and its growth (deg per rad of wrap).
    route_a1, route_a3, route_b3, route_shift : float
        Direction-dependent tendon routing: the bend plane of a bend in
        direction ``delta`` is turned by ``A1 cos(delta - zeta1) + A3
        cos(3 delta - zeta3)`` (rad) and its magnitude scaled by ``1 + B3
        cos(3 delta - xi3)``; ``A1`` grows by ``route_shift`` per rad of
        shaft wrap, ``A3`` and ``B3`` by a factor ``1 + Theta / pi``.
    route_phases : ndarray of shape (3,)
        Phases ``zeta1`` (relative to the shaft-bend direction when bent),
        ``zeta3`` and ``xi3`` (rad).
    windup : float
        Largest azimuth lag of the bend plane from torsional wind-up of the
        shaft (rad), grown by ``1 + Theta / pi`` in a bent shaft.
    cross_load : float
        Share of the other pair's load that adds to a pair's friction (the
        tendons share the sheath): play width ``w0 + a (|u_i| + c |u_j|)``.
    slow_creep_gain, slow_creep_tau : float
        Viscoelastic creep of the tendons under load, common to all
        mechanisms: the effective input relaxes by ``gain`` times its
        low-passed value (time constant ``tau``, s).
    tip_lag : float
        Time constant of the first-order lag between the tendon input and the
        bending section (tendon elasticity and damping of the section), s.
    wrap_routing : float
        How much more the tendon pair whose plane contains the shaft bend is
        wrapped than the other pair: the wrap of axis ``i`` is
        ``Theta (1 + wrap_routing cos 2(beta - az_i))``.
    offset_shift : float
        Motor offset per rad of wrap in the shaft-bend direction (deg/rad).
    gain_shift, gain_loss : float
        Relative gain change per rad of wrap along the shaft-bend direction,
        and the fraction of the capstan loss that reduces the gain.
    rest_shift, coupling_shift, twist_shift : float
        Change of resting curvature, coupling and twist per rad of wrap.
    pulley_radius, pretension, stiffness : float
        Drive pulley radius (mm), tendon pretension (N), tendon load per degree
        of effective input (N/deg).
    motor_friction, motor_viscous, torque_noise, torque_step : float
        Coulomb friction (N mm), viscous friction (N mm s/deg), noise standard
        deviation (N mm) and quantisation step (N mm) of the reported torque.
    mount_rotvec : ndarray of shape (3,)
        Rotation from the kinematic base frame to the base-sensor frame B.
    mount_position : ndarray of shape (3,)
        Base-sensor origin in the kinematic base frame (mm).
    """

    name: str
    length: float
    tip_length: float
    split_fraction: float
    split_bias: float
    split_slope: float
    max_bend: float
    twist: float
    coupling: np.ndarray
    rest_bend: np.ndarray
    gains: np.ndarray
    offsets: np.ndarray
    mu: float
    play_w0: float
    play_growth_base: float
    play_growth_scale: float
    play_asym: float
    bw_kappa: float
    rate_gain: float
    rate_speed: float
    creep_gain: float
    creep_tau: float
    dead_zone0: float
    dead_zone_growth: float
    route_a1: float
    route_a3: float
    route_b3: float
    route_shift: float
    route_phases: np.ndarray
    windup: float
    cross_load: float
    slow_creep_gain: float
    slow_creep_tau: float
    tip_lag: float
    wrap_routing: float
    offset_shift: float
    gain_shift: float
    gain_loss: float
    rest_shift: float
    coupling_shift: float
    twist_shift: float
    pulley_radius: float
    pretension: float
    stiffness: float
    motor_friction: float
    motor_viscous: float
    torque_noise: float
    torque_step: float
    mount_rotvec: np.ndarray
    mount_position: np.ndarray

    @property
    def n_motors(self):
        """Number of motors of the unit (one offset each)."""
        return len(self.offsets)

    def to_dict(self):
        """Parameters as a plain dict (arrays as lists)."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}


#: Unit-to-unit spread of the family (version 6): every unit parameter is
#: drawn from its range and then pulled towards the middle of that range by
#: this factor, ``middle + UNIT_SPREAD (draw - middle)``. The default
#: ``unit_spread`` of :func:`sample_catheter`.
UNIT_SPREAD = 0.35


def _toward(value, middle, spread):
    """``value`` pulled towards ``middle``: ``middle + spread (value - middle)``."""
    return middle + spread * (np.asarray(value, dtype=float) - middle)


@validate_params(
    {
        "random_state": [
            Interval(Integral, 0, None, closed="left"),
            np.random.Generator,
            np.random.SeedSequence,
            None,
        ],
        "name": [str],
        "gain_deg_per_deg": [Interval(Real, 0, None, closed="neither")],
        "unit_spread": [Interval(Real, 0, 1, closed="both")],
        "n_motors": [MotorCount()],
    },
    prefer_skip_nested_validation=True,
)
def sample_catheter(random_state, name="C1", *, gain_deg_per_deg=3.2, unit_spread=UNIT_SPREAD,
                    n_motors=2):
    """Draw one catheter unit of the family.

    Parameters
    ----------
    random_state : int, numpy.random.Generator, numpy.random.SeedSequence or None
        Source of randomness; None draws fresh entropy from the system.
    name : str
        Catheter id.
    gain_deg_per_deg : float
        Nominal bend per degree of effective tendon input (deg/deg).
    unit_spread : float in [0, 1], default=0.35
        How far a unit's parameters spread over the family's ranges: each
        parameter marked *(narrowed)* in ``docs/studies/simulator.rst`` is a draw
        ``x`` from its range pulled towards the middle ``m`` of the range,
        ``m + unit_spread (x - m)``, and so is the mean of the four tendon
        gains. 1 draws over the whole ranges (the units of simulator
        version 5, from the same random numbers), 0 gives every unit the
        middle of every narrowed range. The other parameters (direction-
        dependent routing, differences between the tendons, offsets, the
        base-sensor mount) are drawn over their whole ranges in any case.
    n_motors : {1, 2, 3}, default=2
        Motors of the instrument (``docs/studies/simulator.rst``, *Instruments of
        one and three motors*): each has its own tendon gains (positive and
        negative inputs) and offset. The unit is the two-motor unit of the
        same ``random_state`` with these changed: one motor keeps the first
        motor's gains and offset, a third motor's are drawn after all the
        others; the mean gain of the unit is that of its own tendons.

    Returns
    -------
    catheter : Catheter
    """
    rng = np.random.default_rng(random_state)

    def u(low, high, size=None):
        # a unit's value: a draw from the family's range, pulled towards its middle
        return _toward(rng.uniform(low, high, size), 0.5 * (low + high), unit_spread)

    def n(mean=0.0, sd=1.0, size=None):
        return _toward(rng.normal(mean, sd, size), mean, unit_spread)

    relative = 1.0 + rng.normal(0.0, 0.2, size=(2, 2))  # the tendons' relative gains
    mount = _sensor_mount(rng)
    unit = Catheter(
        name=name,
        length=u(38.0, 46.0),
        tip_length=u(9.0, 12.0),
        split_fraction=u(0.4, 0.6),
        split_bias=n(0.0, 0.12),
        split_slope=n(0.12, 0.04),
        max_bend=np.deg2rad(u(110.0, 150.0)),
        twist=rng.normal(0.0, 0.15),
        coupling=rng.normal(0.0, 0.06, size=2),
        rest_bend=np.deg2rad(rng.normal(0.0, 2.0, size=2)),
        gains=_tendon_gains(relative, gain_deg_per_deg, unit_spread),
        offsets=rng.normal(0.0, 1.5, size=2),  # where the robot's adapter grips the knobs
        mu=u(0.10, 0.20),
        play_w0=u(3.0, 5.0),
        play_growth_base=u(0.03, 0.06),
        play_growth_scale=u(0.3, 0.45),
        play_asym=u(0.6, 0.9),
        bw_kappa=u(0.3, 0.6),
        rate_gain=u(0.3, 0.6),
        rate_speed=u(5.0, 15.0),
        creep_gain=u(0.04, 0.08),
        creep_tau=u(3.0, 8.0),
        dead_zone0=u(2.0, 4.0),
        dead_zone_growth=u(1.0, 2.0),
        wrap_routing=u(0.3, 0.6),
        route_a1=abs(rng.normal(0.0, 0.06)),
        route_a3=rng.normal(0.0, 0.15),
        route_b3=rng.normal(0.0, 0.15),
        route_shift=u(0.07, 0.11),
        route_phases=rng.uniform(-np.pi, np.pi, size=3),  # angles on the circle: not narrowed
        windup=np.deg2rad(u(3.0, 5.0)),
        cross_load=u(0.2, 0.4),
        slow_creep_gain=u(0.06, 0.12),
        slow_creep_tau=u(10.0, 30.0),
        tip_lag=u(0.1, 0.25),
        offset_shift=u(1.0, 2.5),
        gain_shift=u(0.06, 0.10),
        gain_loss=u(0.3, 0.5),
        rest_shift=u(0.02, 0.05),
        coupling_shift=u(0.01, 0.03),
        twist_shift=u(0.02, 0.05),
        pulley_radius=u(9.0, 11.0),
        pretension=u(1.5, 2.5),
        stiffness=u(0.12, 0.18),
        motor_friction=u(3.0, 6.0),
        motor_viscous=u(0.1, 0.3),
        torque_noise=3.0,
        torque_step=0.5,
        mount_rotvec=mount.as_rotvec(),
        mount_position=np.array([rng.normal(0.0, 1.5), rng.normal(0.0, 1.5),
                                 -rng.uniform(6.0, 14.0)]),
    )
    if n_motors == 2:
        return unit
    # another number of motors: the two-motor unit with the tendons of its
    # motors, a third motor's drawn after everything else
    extra = max(n_motors - 2, 0)
    relative = np.vstack([relative, 1.0 + rng.normal(0.0, 0.2, size=(extra, 2))])[:n_motors]
    offsets = np.concatenate([unit.offsets, rng.normal(0.0, 1.5, size=extra)])[:n_motors]
    return replace(
        unit, gains=_tendon_gains(relative, gain_deg_per_deg, unit_spread), offsets=offsets
    )


def _tendon_gains(relative, gain_deg_per_deg, unit_spread):
    """Tendon gains (rad/deg) of shape (n_motors, 2) from their relative gains.

    The unit's mean gain is pulled towards the family's by ``unit_spread``;
    the differences between its tendons (direction-dependent, what PDL
    captures and PCC cannot) are kept whole.
    """
    mean_gain = relative.mean()
    return np.deg2rad(gain_deg_per_deg) * (
        relative - mean_gain + _toward(mean_gain, 1.0, unit_spread)
    )


def _sensor_mount(rng):
    """Rotation of the base sensor's mount: a 25-35 deg tilt about a random axis, then a roll.

    The mount is a property of the set-up, not of the unit: drawn over the
    whole range whatever the unit spread.
    """
    tilt_axis = rng.normal(size=2)
    tilt_axis /= np.linalg.norm(tilt_axis)
    tilt = np.deg2rad(rng.uniform(25.0, 35.0))
    return Rotation.from_rotvec(np.r_[tilt * tilt_axis, 0.0]) * Rotation.from_rotvec(
        [0.0, 0.0, rng.uniform(-np.pi, np.pi)]
    )


#: Share of the no-load play width that does not scale with the wrap: the
#: width of axis ``i`` is ``play_w0 (f + (1 - f) Theta_i)`` with ``Theta_i``
#: in rad, so ``play_w0`` is the width at one radian of wrap.
PLAY_FLOOR = 0.2


@validate_params(
    {"catheter": [Catheter], "setting": [ShaftSetting]}, prefer_skip_nested_validation=True
)
def setting_parameters(catheter, setting):
    """Parameters of a catheter unit in a shaft setting (before per-run variation).

    The simulator's ground truth of what a shaft setting does to a unit's
    transmission; every run of the unit in that setting starts from these
    values, then adds its own jitter and drift (``docs/studies/simulator.rst``).

    Physical routes of the shaft configuration (``Theta`` = capstan wrap in
    rad, ``b`` = unit shaft-bend direction):

    * each tendon pair has its own wrap ``Theta_i = Theta (1 + r cos
      2(beta - az_i))``: the pair bent in its own plane rubs harder;
    * play growth ``a_i = base + scale (1 - exp(-mu Theta_i))`` (capstan friction)
      and a dead zone ``d0 + d1 Theta_i`` (slack of the tendon pair);
    * no-load play width ``w0 (0.2 + 0.8 Theta_i)``: the pretension presses
      the tendon on the sheath along the whole wrap, so the stick band the
      motor must cross before a reversal reaches the tip grows with the
      pair's own wrap (simulator version 5);
    * gains: capstan loss ``1 - loss (1 - exp(-mu Theta))`` for all tendons,
      and a path-length change ``1 + shift Theta cos(beta - az_tendon)`` for
      the tendon at azimuth ``az_tendon``;
    * motor offsets ``shift Theta b`` (the outer tendon is pre-stretched);
    * resting curvature, coupling and twist nudged along the bend direction.

    Parameters
    ----------
    catheter : Catheter
        The unit.
    setting : ShaftSetting
        The shaft setting (see :func:`shaft_settings`).

    For a unit of one or three motors (:attr:`Catheter.n_motors`), the
    per-axis quantities are per motor, each motor's tendon at its azimuth
    (:func:`~skcath.datasets._tendons.tendon_layout`); a one-motor section
    bends in one plane (no twist, coupling, routing turn or wind-up).

    Returns
    -------
    params : dict
        ``gains`` (n_motors, 2) bend per effective input of each motor and
        sign (rad/deg); ``offsets`` (n_motors,) motor offsets (deg); ``rest_bend`` (2,)
        resting curvature (rad); ``coupling`` (2,) cross-axis coupling;
        ``twist`` (rad/rad); ``routing`` (6,) amplitudes and phases of the
        direction-dependent routing (rad, ``A1, zeta1, A3, zeta3, B3,
        xi3``); ``windup`` largest wind-up lag (rad); ``w0`` (n_motors,) no-load
        play width per motor (deg); ``growth`` (n_motors,) growth of the
        play width with load (deg/deg); ``dead_zone`` (n_motors,) dead-zone
        width per motor (deg); ``capstan_exponent`` (n_motors,) ``mu
        Theta_i`` of each motor.
    """
    c = catheter
    layout = tendon_layout(c.n_motors)
    azimuths = layout.azimuths
    theta = setting.wrap
    bvec = setting.bend_vector()
    beta = np.arctan2(bvec[1], bvec[0])
    bent = float(np.any(bvec != 0))
    axis_wrap = theta * (1.0 + c.wrap_routing * bent * np.cos(2.0 * (beta - azimuths[:, 0])))
    axis_capstan = 1.0 - np.exp(-c.mu * axis_wrap)
    capstan = axis_capstan.mean()
    path = 1.0 + c.gain_shift * theta * bent * np.cos(beta - azimuths)
    gains = c.gains * (1.0 - c.gain_loss * capstan) * path
    sin2, cos2 = np.sin(2 * beta) * bent, np.cos(2 * beta) * bent
    params = {
        "gains": gains,
        "offsets": c.offsets + c.offset_shift * theta * layout.per_motor(bvec),
        "rest_bend": c.rest_bend + c.rest_shift * theta * bvec,
        "coupling": c.coupling + c.coupling_shift * theta * np.array([sin2, cos2]),
        "twist": c.twist + c.twist_shift * theta * np.sin(beta) * bent,
        "routing": np.array([
            c.route_a1 + c.route_shift * theta * bent,
            c.route_phases[0] + beta * bent,
            c.route_a3 * (1.0 + theta * bent / np.pi),
            c.route_phases[1],
            c.route_b3 * (1.0 + theta * bent / np.pi),
            c.route_phases[2],
        ]),
        "windup": c.windup * (1.0 + theta * bent / np.pi),
        "w0": c.play_w0 * (PLAY_FLOOR + (1.0 - PLAY_FLOOR) * axis_wrap),
        "growth": c.play_growth_base + c.play_growth_scale * axis_capstan,
        "dead_zone": c.dead_zone0 + c.dead_zone_growth * axis_wrap,
        "capstan_exponent": c.mu * axis_wrap,
    }
    return _in_plane(params) if layout.planar else params


def _in_plane(params):
    """The parameters of a section that bends in one plane (one motor).

    Its bend vector stays on the first axis: no resting curvature across
    the plane, no coupling into a second axis, no twist, no turn of the bend
    plane by the routing and no torsional wind-up. The magnitude harmonic of
    the routing stays (the two sides of the plane differ).
    """
    routing = params["routing"].copy()
    routing[[0, 2]] = 0.0
    return {
        **params,
        "rest_bend": params["rest_bend"] * np.array([1.0, 0.0]),
        "coupling": np.zeros(2),
        "twist": 0.0,
        "routing": routing,
        "windup": 0.0,
    }
