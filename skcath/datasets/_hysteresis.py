"""Hysteresis of the tendon transmission: three interchangeable mechanisms.

Each mechanism maps the motor input ``u`` (degrees, one column per motor:
a tendon pair, or a single tendon of a three-tendon instrument) to the
effective tendon input ``v`` that reaches the bending section,
and reports the friction utilisation ``phi`` in [-1, 1] (+1 while the
proximal tendon is being pulled through the sheath, -1 while it is being
released), which sets the capstan factor of the drive torque.

All mechanisms share a load-dependent width

    w(u) = w0 + a (|u_i| + c sum_{j != i} |u_j|),

where ``c`` is the share of the other motors' loads ``u_j`` that presses on
the sheath (the other pair's, for two motors; none for one), and ``a`` grows
with the capstan wrap of the shaft (``1 - exp(-mu Theta)``), so loops widen
with shaft bend and with load. The time loop is vectorised across runs and
motors: arrays have shape ``(n_steps, n_runs, n_motors)``.
"""

import numpy as np

__all__ = ["MECHANISMS", "WindupStepper", "play_width", "simulate_transmission", "torsional_windup", "transmission_stepper"]

MECHANISMS = ("play", "bouc_wen", "dahl_creep")


def play_width(u, params):
    """Load-dependent width ``w(u)`` (deg) of the play at motor inputs ``u`` (deg), shape (n, n_motors)."""
    load = np.abs(u)
    return params["w0"] + params["growth"] * (load + params["cross_load"] * (load @ params["others"]))


#: Width multipliers of the play elements of the distributed-friction model:
#: friction acts all along the sheath, so some stretches of tendon slip early
#: and others only after a long travel.
PLAY_ELEMENTS = np.geomspace(0.3, 8.0, 6)


class _Play:
    """Load-dependent play operators in parallel (distributed Coulomb friction).

    Each element ``m`` follows ``z_k = clip(z_{k-1}, u_k - m w(u_k), u_k + r m w(u_k))``
    (it lags the input by ``m w`` while loading and by ``r m w`` while
    unloading); the output is the mean of the elements, with multipliers
    ``m`` in :data:`PLAY_ELEMENTS`. Wide elements slide only after long
    excursions and then keep a memory of them; where ``m a (1 + c) >= 1`` an
    element never slides at all (a stretch of tendon held by static friction
    for the whole run), which lowers the transmission ratio of a strongly
    bent shaft. The friction
    utilisation ``phi`` is the mean over elements of where each sits
    between its two branches.
    """

    def __init__(self, u0, dt, params):
        self.params = params
        self.z = np.repeat(u0[None], len(PLAY_ELEMENTS), axis=0)

    def step(self, uk):
        r = self.params["asym"]
        w = PLAY_ELEMENTS[:, None, None] * play_width(uk, self.params)
        self.z = z = np.clip(self.z, uk - w, uk + r * w)
        phi = ((2.0 * (uk - z) + (r - 1.0) * w) / ((1.0 + r) * w)).mean(axis=0)
        return z.mean(axis=0), phi


class _BoucWen:
    """Asymmetric Bouc-Wen lag ``h`` (degrees); output ``v = u - h``.

    Discrete update with ``A = 1``::

        h_k = (h + du + delta |du| - gamma du |h|) / (1 + beta |du|),
        W = w(u) (1 + r) / 2,  beta + gamma = 1 / W,  gamma = kappa / W,
        delta = (1 - r) / (1 + r),

    so the lag saturates at ``w`` while loading and at ``-r w`` while
    unloading (as the play operator), and ``kappa`` sets how sharply the
    branch turns after a reversal. As for the play, friction is distributed:
    elements of widths ``m w`` (:data:`PLAY_ELEMENTS`) act in parallel and the
    output is their mean.
    """

    def __init__(self, u0, dt, params):
        self.params = params
        self.h = np.zeros((len(PLAY_ELEMENTS), *u0.shape))
        self.u_prev = u0

    def step(self, uk):
        r, kappa = self.params["asym"], self.params["kappa"]
        delta = (1.0 - r) / (1.0 + r)
        du = uk - self.u_prev
        self.u_prev = uk
        w = PLAY_ELEMENTS[:, None, None] * play_width(uk, self.params) * (0.5 + 0.5 * r)
        adu = np.abs(du)
        h = self.h
        self.h = h = (h + du + delta * adu - (kappa / w) * du * np.abs(h)) / (1.0 + ((1.0 - kappa) / w) * adu)
        return uk - h.mean(axis=0), np.clip(h / w - delta, -1.0, 1.0).mean(axis=0)


class _DahlCreep:
    """Rate-dependent Dahl friction with viscoelastic tendon creep.

    The friction lag ``h`` follows a Dahl model whose limit grows with the
    motor speed (viscous drag in the sheath)::

        w_v = w(u) (1 + c_v tanh(|du/dt| / v_s)),   h_k = (h + du) / (1 + |du| / w_v).

    The tendon creeps under load: ``c`` relaxes towards ``kappa_c (u - h)``
    with time constant ``tau_c``, so a slow sweep and a fast move reach the
    same motor angle with different outputs. Output ``v = u - h - c``, with
    ``h`` the mean lag of distributed elements of widths ``m w``
    (:data:`PLAY_ELEMENTS`), as for the play.
    """

    def __init__(self, u0, dt, params):
        self.params, self.dt = params, dt
        self.relax = 1.0 - np.exp(-dt / params["creep_tau"])
        self.h = np.zeros((len(PLAY_ELEMENTS), *u0.shape))
        self.c = np.zeros_like(u0)
        self.u_prev = u0

    def step(self, uk):
        p = self.params
        du = uk - self.u_prev
        self.u_prev = uk
        w = PLAY_ELEMENTS[:, None, None] * play_width(uk, p)
        w = w * (1.0 + p["rate_gain"] * np.tanh(np.abs(du) / (self.dt * p["rate_speed"])))
        self.h = h = (self.h + du) / (1.0 + np.abs(du) / w)
        lag = h.mean(axis=0)
        self.c = c = self.c + (p["creep_gain"] * (uk - lag) - self.c) * self.relax
        return uk - lag - c, np.clip(h / w, -1.0, 1.0).mean(axis=0)


_STEPPERS = {"play": _Play, "bouc_wen": _BoucWen, "dahl_creep": _DahlCreep}


def transmission_stepper(u0, dt, params, mechanism="play"):
    """The transmission of :func:`simulate_transmission`, one sample at a time.

    Parameters
    ----------
    u0 : ndarray of shape (n_runs, n_motors)
        Motor input at the first sample (degrees), which sets the initial
        state (the mechanism starts at rest there).
    dt, params, mechanism
        As for :func:`simulate_transmission`.

    Returns
    -------
    stepper : object
        Its ``step(u_k)`` takes the input of the next sample, the first
        being ``u0``, and returns ``v_k, phi_k`` of shape (n_runs, n_motors),
        the rows of :func:`simulate_transmission`'s output, bit for bit.
    """
    if mechanism not in _STEPPERS:
        raise ValueError(f"mechanism={mechanism!r} is not one of {MECHANISMS}.")
    u0 = np.asarray(u0, dtype=float)
    # the loads of the other motors: a 0/1 matrix, exact for two motors
    others = 1.0 - np.eye(u0.shape[-1])
    return _STEPPERS[mechanism](u0, dt, {**params, "others": others})


def simulate_transmission(u, dt, params, mechanism="play"):
    """Run a hysteresis mechanism over padded motor inputs of many runs.

    Parameters
    ----------
    u : ndarray of shape (n_steps, n_runs, n_motors)
        Motor input of each motor (degrees), after configuration offsets.
        Pad finished runs by repeating their last value.
    dt : float
        Sampling period (s).
    params : dict of ndarray of shape (n_runs, n_motors)
        ``w0`` (deg), ``growth`` (deg/deg), ``cross_load``, ``asym`` (unloading/loading width
        ratio); ``kappa`` for ``"bouc_wen"``; ``rate_gain``, ``rate_speed``
        (deg/s), ``creep_gain``, ``creep_tau`` (s) for ``"dahl_creep"``.
    mechanism : {"play", "bouc_wen", "dahl_creep"}
        Hysteresis mechanism.

    Returns
    -------
    v : ndarray of shape (n_steps, n_runs, n_motors)
        Effective tendon input at the bending section (degrees).
    phi : ndarray of shape (n_steps, n_runs, n_motors)
        Friction utilisation in [-1, 1].
    """
    if mechanism not in _STEPPERS:
        raise ValueError(f"mechanism={mechanism!r} is not one of {MECHANISMS}.")
    u = np.asarray(u, dtype=float)
    if u.ndim != 3 or u.shape[2] < 1:
        raise ValueError(f"u must have shape (n_steps, n_runs, n_motors); got {u.shape}.")
    stepper = transmission_stepper(u[0], dt, params, mechanism)
    v = np.empty_like(u)
    phi = np.empty_like(u)
    for k in range(u.shape[0]):
        v[k], phi[k] = stepper.step(u[k])
    return v, phi


def torsional_windup(u, width):
    """Play in the azimuth of the bend: the shaft winds up in torsion.

    The bend-plane azimuth follows the azimuth ``psi`` of the motor input
    (unwrapped over time) through a play of half-width
    ``width * tanh(rho / 20 deg)``, so the plane lags when the bend direction
    turns, by more when the section is bent further (and not at all when it
    is straight, where the azimuth is meaningless).

    Parameters
    ----------
    u : ndarray of shape (n_steps, n_runs, 2)
        The two bending inputs of the motor input (degrees).
    width : ndarray of shape (n_runs,)
        Largest azimuth lag (rad).

    Returns
    -------
    offset : ndarray of shape (n_steps, n_runs)
        Azimuth of the bend plane minus the input azimuth (rad).
    """
    psi = np.unwrap(np.arctan2(u[..., 1], u[..., 0]), axis=0)
    w = width * np.tanh(np.hypot(u[..., 0], u[..., 1]) / 20.0)
    offset = np.empty(psi.shape)
    state = psi[0].copy()
    for k in range(len(psi)):
        state = np.clip(state, psi[k] - w[k], psi[k] + w[k])
        offset[k] = state - psi[k]
    return offset


class WindupStepper:
    """The torsional wind-up of :func:`torsional_windup`, one sample at a time.

    Unwraps the input azimuth as :func:`numpy.unwrap` does (the same
    corrections, summed in the same order), so that its outputs are those of
    :func:`torsional_windup` bit for bit.

    Parameters
    ----------
    width : ndarray of shape (n_runs,)
        Largest azimuth lag (rad).
    """

    def __init__(self, width):
        self.width = width
        self.raw = None

    def step(self, uk):
        """Azimuth offset (rad) of shape (n_runs,) at the next sample of bending inputs ``uk`` (n_runs, 2)."""
        raw = np.arctan2(uk[..., 1], uk[..., 0])
        if self.raw is None:
            self.correction = np.zeros_like(raw)
            psi = raw.copy()
            self.state = psi.copy()
        else:
            dd = raw - self.raw
            ddmod = np.mod(dd + np.pi, 2.0 * np.pi) - np.pi
            ddmod = np.where((ddmod == -np.pi) & (dd > 0), np.pi, ddmod)
            fix = np.where(np.abs(dd) < np.pi, 0.0, ddmod - dd)
            self.correction = self.correction + fix
            psi = raw + self.correction
        self.raw = raw
        w = self.width * np.tanh(np.hypot(uk[..., 0], uk[..., 1]) / 20.0)
        self.state = np.clip(self.state, psi - w, psi + w)
        return self.state - psi
