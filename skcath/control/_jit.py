"""The controller's step compiled by numba: one call from observation to command.

Imported only for an estimator on the numba engine (it imports numba).
:func:`control_step` does what the Python methods of the controllers do
(:mod:`skcath.control._controllers`), with the same steps, acceptance rules
and limits: it advances the model by the commands not observed yet, updates
the feedback's correction, solves the model for the target (from the
previous solution, then from the nearest seed of the grid), inverts the
hysteresis (the play, or the Prandtl-Ishlinskii model), keeps the command
within the motor and rate limits and queues it. The
model is evaluated through the compiled look-ahead kernels of the estimator
(:meth:`ModelView.compiled <skcath.online._model_view.ModelView.compiled>`).
The controller's parameters and state live in one float array, laid out as
this module names it (:func:`layout`).
"""

from __future__ import annotations

import math

import numpy as np

from .._kernel import compiled, offsets
from ..online._model_view_jit import advance as _advance
from ..online._model_view_jit import restore as _restore
from ..online._model_view_jit import tip as _tip
from ..backbones._pi import pi_step
from ._hysteresis import TOL_DEG, pi_command
from ._modes import MODE_FEEDFORWARD, MODE_INTERNAL_MODEL, MODE_RESOLVED_RATE


__all__ = ["KIND_NONE", "KIND_PI", "KIND_PLAY", "control_kernel", "control_step", "layout"]

#: Scalars of the state array: parameters, then state; blocks of ``n_motors`` follow from ``S_BLOCKS``.
(S_GAIN, S_DAMPING, S_EPS, S_TOL, S_MAX_ITER, S_MAX_STEP, S_WIDTH, S_BAND, S_RADIUS, S_MARGIN,
 S_MODE, S_LATENCY, S_KIND, S_ISSUED_AT, S_AIMS_AT, S_LIMITED, S_N_AHEAD, S_CORRECTION, S_AIMED,
 S_BLOCKS) = offsets(*([1] * 17), 3, 3)
#: The hysteresis inverted (``S_KIND``): none, the play (half-width ``S_WIDTH``), the Prandtl-Ishlinskii model.
KIND_NONE, KIND_PLAY, KIND_PI = 0, 1, 2
#: Blocks of ``n_motors`` (deg): limits, last command, last solution, wanted angles, effective angles.
B_LOW, B_HIGH, B_NEUTRAL, B_COMMAND, B_SOLUTION, B_WANTED, B_EFFECTIVE, N_BLOCKS = range(8)


def layout(n_motors):
    """Size of the state array and the offset of each block, ``{B_...: offset}``."""
    return S_BLOCKS + N_BLOCKS * n_motors, {b: S_BLOCKS + b * n_motors for b in range(N_BLOCKS)}


def _block(s, b, n):
    """Block ``b`` of the state array ``s`` (a view)."""
    return s[S_BLOCKS + b * n : S_BLOCKS + (b + 1) * n]


def _project(z, low, high, neutral, radius):
    """``z`` (deg) into the box, then radially into the disk, in place."""
    r2 = 0.0
    for j in range(z.shape[0]):
        z[j] = min(max(z[j], low[j]), high[j])
        r2 += (z[j] - neutral[j]) ** 2
    r = math.sqrt(r2)
    if r > radius:
        for j in range(z.shape[0]):
            z[j] = neutral[j] + (z[j] - neutral[j]) * (radius / r)


def _damped_step(J, r, mu, dz, A, b):
    """``dz = (J^T J + mu^2 I)^-1 J^T r`` by Gaussian elimination with partial pivoting."""
    n = dz.shape[0]
    for i in range(n):
        b[i] = 0.0
        for k in range(3):
            b[i] += J[k, i] * r[k]
        for j in range(n):
            s = 0.0
            for k in range(3):
                s += J[k, i] * J[k, j]
            A[i, j] = s + (mu * mu if i == j else 0.0)
    for c in range(n):
        p = c
        for i in range(c + 1, n):
            if abs(A[i, c]) > abs(A[p, c]):
                p = i
        for j in range(n):
            A[c, j], A[p, j] = A[p, j], A[c, j]
        b[c], b[p] = b[p], b[c]
        for i in range(c + 1, n):
            m = A[i, c] / A[c, c]
            for j in range(c, n):
                A[i, j] -= m * A[c, j]
            b[i] -= m * b[c]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= A[i, j] * dz[j]
        dz[i] = s / A[i, i]


def _solve(view, target, z, torques, s, tip, J):
    """The Levenberg-Marquardt solve from ``z``; ``z``, ``tip`` and ``J`` are written in place.

    As :meth:`ModelInverse.solve <skcath.control._model.ModelInverse.solve>`;
    the limits and the settings are read from the state array ``s``.
    """
    n = z.shape[0]
    low, high, neutral = _block(s, B_LOW, n), _block(s, B_HIGH, n), _block(s, B_NEUTRAL, n)
    radius, tol = s[S_RADIUS], s[S_TOL]
    sample = np.empty(n + torques.shape[0])
    trial_tip, r, dz, z_new = np.empty(3), np.empty(3), np.empty(n), np.empty(n)
    A, b = np.empty((n, n)), np.empty(n)
    _project(z, low, high, neutral, radius)
    _look(view, z, torques, sample, tip)
    cost = 0.0
    for k in range(3):
        r[k] = target[k] - tip[k]
        cost += r[k] * r[k]
    _jacobian(view, z, torques, s[S_EPS], tip, J, sample, trial_tip)
    mu = max(s[S_DAMPING], 1e-6)
    for _ in range(int(s[S_MAX_ITER])):
        _damped_step(J, r, mu, dz, A, b)
        moved = 0.0
        for j in range(n):
            z_new[j] = z[j] + dz[j]
        _project(z_new, low, high, neutral, radius)
        for j in range(n):
            moved = max(moved, abs(z_new[j] - z[j]))
        if moved < tol:
            break
        _look(view, z_new, torques, sample, trial_tip)
        cost_new = 0.0
        for k in range(3):
            cost_new += (target[k] - trial_tip[k]) ** 2
        if cost_new < cost:
            cost, mu = cost_new, mu / 3.0
            for j in range(n):
                z[j] = z_new[j]
            for k in range(3):
                tip[k] = trial_tip[k]
                r[k] = target[k] - tip[k]
            _jacobian(view, z, torques, s[S_EPS], tip, J, sample, trial_tip)
        else:
            mu *= 4.0


def _look(view, z, torques, sample, out):
    """The model's tip at effective angles ``z`` (the look-ahead kernel on the view's arrays)."""
    meta, a64, anet, w32, saved_f, saved_buf, f0, buf0 = view
    _tip(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0, z, torques, sample, out)


def _jacobian(view, z, torques, eps, tip, J, sample, out):
    """Forward-difference Jacobian (mm/deg) at ``z``, whose tip is ``tip``, into ``J``."""
    for j in range(z.shape[0]):
        z[j] += eps
        _look(view, z, torques, sample, out)
        z[j] -= eps
        for k in range(3):
            J[k, j] = (out[k] - tip[k]) / eps


def _nearest(view, target, torques, s, grid_z, grid_tips, z, tip, J):
    """Solve for ``target`` from ``z``, again from the nearest grid seed if closer.

    As :meth:`_Controller._nearest <skcath.control._controllers._Controller._nearest>`:
    ``z`` (the start) and ``tip``, ``J`` receive the solution, its tip and
    Jacobian; returns the squared distance of the tip from the target (mm^2).
    """
    _solve(view, target, z, torques, s, tip, J)
    miss2 = _distance2(target, tip)
    margin = s[S_MARGIN]
    if miss2 > margin:  # else no grid tip can be closer by the margin
        best, best_d2 = 0, np.inf
        for i in range(grid_tips.shape[0]):
            d2 = _distance2(grid_tips[i], target)
            if d2 < best_d2:
                best, best_d2 = i, d2
        if best_d2 + margin < miss2:
            z2, tip2, J2 = grid_z[best].copy(), np.empty(3), np.empty(J.shape)
            _solve(view, target, z2, torques, s, tip2, J2)
            miss2_grid = _distance2(target, tip2)
            if miss2_grid < miss2:
                z[:], tip[:], J[:, :] = z2, tip2, J2
                miss2 = miss2_grid
    return miss2


def _aim(view, target, torques, s, grid_z, grid_tips, z, tip, J):
    """Solve for ``target`` from the last solution (:func:`_nearest`), which it becomes.

    As :meth:`_Controller._aim <skcath.control._controllers._Controller._aim>`:
    ``z``, ``tip`` and ``J`` receive the solution, its tip and Jacobian;
    returns the squared distance of the tip from the target (mm^2).
    """
    solution = _block(s, B_SOLUTION, z.shape[0])
    z[:] = solution
    miss2 = _nearest(view, target, torques, s, grid_z, grid_tips, z, tip, J)
    solution[:] = z
    return miss2


def _distance2(a, b):
    """Squared distance (mm^2) of two tips, summed over x, y, z in order."""
    total = 0.0
    for k in range(3):
        total += (a[k] - b[k]) ** 2
    return total


def _play_command(z_wanted, z_state, q_previous, width, dead_band, q):
    """The play's inverse with its reversal dead band, into ``q``: as :meth:`PlayInverse.command
    <skcath.control._hysteresis.PlayInverse.command>` (with ``width=0``: the wanted angles)."""
    band = max(dead_band, TOL_DEG)
    for j in range(q.shape[0]):
        zj, sj, qj = z_wanted[j], z_state[j], q_previous[j]
        tol_up, tol_down = (TOL_DEG, band) if qj >= sj else (band, TOL_DEG)
        if zj > sj + tol_up:
            q[j] = zj + width
        elif zj < sj - tol_down:
            q[j] = zj - width
        else:
            q[j] = min(max(qj, zj - width), zj + width)


def _pi_commands(pi, z_wanted, z_state, q_previous, dead_band, q):
    """The PI's inverse into ``q``: as :meth:`PIInverse.command <skcath.control._hysteresis.PIInverse.command>`.

    ``pi`` is ``(link, theta, forward, dt, up, down)``: :func:`~skcath.control._hysteresis.pi_link`,
    the packed inverse, the stream's forward state, its next time step (s) and the dead band up and down.
    """
    link, theta, forward, dt, up, down = pi
    size = int(link[0]) + 2
    scratch = np.empty(int(theta[0]) + 3)
    for j in range(q.shape[0]):
        q[j] = pi_command(link, theta, forward, j * size, scratch, z_wanted[j], q_previous[j], z_state[j],
                          dt[0], up[j], down[j], dead_band)


def _angles_ahead(view, s, grid_z, grid_tips, torques, target, ahead, window, correction, out):
    """Wanted effective angles (deg) of the samples ahead into ``out``, each target solved once as it comes in view.

    As :meth:`_Controller._angles_ahead <skcath.control._controllers._Controller._angles_ahead>`:
    ``ahead`` (k, 3) holds the targets of the next samples (mm); ``window``
    the targets in view and their solutions, a row ``[x, y, z, angles...]``
    each, ``S_N_AHEAD`` of them, the first that of this sample; updated.
    A target is solved for minus ``correction`` (mm) from the solution of
    the one before; one equal to this sample's ``target`` takes its solution.
    """
    n = out.shape[1]
    solution = _block(s, B_SOLUTION, n)
    count = max(int(s[S_N_AHEAD]) - 1, 0)  # the window moved on by a sample
    for i in range(count):
        window[i, :] = window[i + 1, :]
    z, aim, tip, J = solution.copy(), np.empty(3), np.empty(3), np.empty((3, n))
    for i in range(ahead.shape[0]):
        now, same = True, i < count
        for k in range(3):
            now = now and ahead[i, k] == target[k]
            same = same and window[i, k] == ahead[i, k]
        if now:
            z[:] = solution
        elif same:
            z[:] = window[i, 3:]
        else:
            for k in range(3):
                aim[k] = ahead[i, k] - correction[k]
            _nearest(view, aim, torques, s, grid_z, grid_tips, z, tip, J)
        if not same:  # the window from here on is new
            count = i + 1
        window[i, :3] = ahead[i]
        window[i, 3:] = z
        out[i] = z
    s[S_N_AHEAD] = count


def _lead(s, pi, pi_forward, z_wanted, z_ahead, q):
    """The previewed command (deg) into ``q``: the plan of the wanted angles ahead and the midpoint of its envelopes.

    As :func:`~skcath.control._preview.plan` then :func:`~skcath.control._preview.lead`:
    the hysteresis inverse along ``z_wanted`` then the rows of ``z_ahead``
    (deg), each command from the previous, within the motor limits, the
    effective angles (for the PI, a copy of the forward state) followed
    through the hysteresis; ``pi_forward`` is the PI's
    :meth:`~skcath.backbones.PrandtlIshlinskii.pack`, then its dead band up
    and down (one value per motor each).
    """
    n, h = q.shape[0], z_ahead.shape[0] + 1
    low, high, neutral, radius = _block(s, B_LOW, n), _block(s, B_HIGH, n), _block(s, B_NEUTRAL, n), s[S_RADIUS]
    z_state, q_previous = _block(s, B_EFFECTIVE, n).copy(), _block(s, B_COMMAND, n).copy()
    link, theta, forward, dt, up, down = pi
    plan_pi = (link, theta, forward.copy(), dt, up, down)  # the stream's forward state left alone
    size, width, pi_kind = int(pi_forward[0]) + 2, s[S_WIDTH], s[S_KIND] == KIND_PI
    packed = 3 + 2 * int(pi_forward[0])  # [K, kappa, tau, g..., w...]
    forward_theta, forward_up, forward_down = pi_forward[:packed], pi_forward[packed:], pi_forward[packed + n:]
    u, z = np.empty((h, n)), np.empty(n)
    for r in range(h):
        if r == 0:
            z[:] = z_wanted
        else:
            z[:] = z_ahead[r - 1]
        _project(z, low, high, neutral, radius)
        if pi_kind:
            _pi_commands(plan_pi, z, z_state, q_previous, s[S_BAND], q)
        else:
            _play_command(z, z_state, q_previous, width, s[S_BAND], q)
        _project(q, low, high, neutral, radius)
        u[r, :] = q
        q_previous[:] = q
        for j in range(n):
            if pi_kind:
                z_state[j] = pi_step(forward_theta, plan_pi[2], j * size, q[j], dt[0], forward_up[j],
                                     forward_down[j])
            else:
                z_state[j] = min(max(z_state[j], q[j] - width), q[j] + width)
    max_step = s[S_MAX_STEP]
    q[:] = u[0]
    if h >= 2 and math.isfinite(max_step):
        for j in range(n):
            above, below = -np.inf, np.inf
            for r in range(h):
                above = max(above, u[r, j] - max_step * r)
                below = min(below, u[r, j] + max_step * r)
            q[j] = 0.5 * (above + below)


def _issue(s, z_wanted, issued, pi, pi_forward, z_ahead):
    """The command for the wanted effective angles: the hysteresis' inverse, the preview, the motor and rate limits.

    As :meth:`_Controller._issue <skcath.control._controllers._Controller._issue>`,
    the wanted angles of the samples ahead in the rows of ``z_ahead`` (none: no preview, :func:`_lead`):
    the command goes to the block ``B_COMMAND`` and the queue ``issued``
    (a ring of the last ``latency`` commands), ``S_LIMITED`` says whether a
    limit changed it.
    """
    n = z_wanted.shape[0]
    low, high, neutral = _block(s, B_LOW, n), _block(s, B_HIGH, n), _block(s, B_NEUTRAL, n)
    command = _block(s, B_COMMAND, n)
    z = z_wanted.copy()
    _project(z, low, high, neutral, s[S_RADIUS])
    q = np.empty(n)
    if s[S_KIND] == KIND_PI:
        _pi_commands(pi, z, _block(s, B_EFFECTIVE, n), command, s[S_BAND], q)
    else:
        _play_command(z, _block(s, B_EFFECTIVE, n), command, s[S_WIDTH], s[S_BAND], q)
    limited_q = q.copy()
    _project(limited_q, low, high, neutral, s[S_RADIUS])
    limited = False
    largest = 0.0
    for j in range(n):
        limited = limited or limited_q[j] != q[j]
    if z_ahead.shape[0] > 0:
        led = np.empty(n)
        _lead(s, pi, pi_forward, z_wanted, z_ahead, led)
        _project(led, low, high, neutral, s[S_RADIUS])
        for j in range(n):
            limited = limited or led[j] != limited_q[j]
        limited_q[:] = led
    for j in range(n):
        largest = max(largest, abs(limited_q[j] - command[j]))
    max_step = s[S_MAX_STEP]
    if largest > max_step:  # the move scaled as a whole: its direction kept
        limited = True
        for j in range(n):
            limited_q[j] = command[j] + (limited_q[j] - command[j]) * (max_step / largest)
    command[:] = limited_q
    s[S_LIMITED] = 1.0 if limited else 0.0
    latency = int(s[S_LATENCY])
    if latency > 0:
        at = int(s[S_ISSUED_AT])
        issued[at] = limited_q
        s[S_ISSUED_AT] = (at + 1) % latency


def _observe(view, s, issued, sample, torques):
    """Advance the model by the commands not observed yet; the effective angles the command moves from."""
    n = issued.shape[1]
    latency = int(s[S_LATENCY])
    pending = np.empty((max(latency, 1), n))
    at = int(s[S_ISSUED_AT])
    for k in range(latency):  # oldest first
        pending[k] = issued[(at + k) % latency]
    meta, a64, anet, w32, saved_f, saved_buf, f0, buf0 = view
    scratch = np.empty(n + torques.shape[0])
    effective = _block(s, B_EFFECTIVE, n)
    _advance(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0, pending, latency, torques, scratch,
             np.empty(3), effective)
    if s[S_KIND] != KIND_NONE:  # the effective angles after the pending commands, as the view gave them
        return
    if latency > 0:
        effective[:] = pending[latency - 1]
    else:
        for j in range(n):
            effective[j] = sample[j]


def _preview_angles(view, s, grid_z, grid_tips, torques, target, ahead, window, z, z_ahead):
    """Wanted effective angles (deg) of the samples ahead into ``z_ahead``, corrected as this sample's ``z`` is.

    As :meth:`FeedbackController._feedback <skcath.control._controllers.FeedbackController._feedback>`:
    the internal model solves them for the corrected targets, the resolved
    rate moves them by the feedback's offset from this sample's solution ``z``.
    """
    n, mode = z.shape[0], int(s[S_MODE])
    correction = np.zeros(3)
    if mode == MODE_INTERNAL_MODEL:
        correction[:] = s[S_CORRECTION : S_CORRECTION + 3]
    _angles_ahead(view, s, grid_z, grid_tips, torques, target, ahead, window, correction, z_ahead)
    if mode == MODE_RESOLVED_RATE:
        offset = _block(s, B_WANTED, n) - z
        for i in range(z_ahead.shape[0]):
            for j in range(n):
                z_ahead[i, j] += offset[j]


def control_step(view, s, issued, aims, grid_z, grid_tips, pi, pi_forward, window, target, measured, sample,
                 ahead):
    """One step of a controller, from the observed sample to the command (block ``B_COMMAND``).

    Parameters
    ----------
    view : tuple of ndarray
        The look-ahead arrays of the estimator (:meth:`ModelView.compiled
        <skcath.online._model_view.ModelView.compiled>`), already stepped
        with the observed sample.
    s : ndarray
        The controller's parameters and state (:func:`layout`); updated.
    issued : ndarray of shape (max(latency, 1), n_motors)
        Ring of the commands not observed yet (deg); updated.
    aims : ndarray of shape (latency + 1, 4)
        Ring of the feedback's aims not observed yet: the tip aimed at (mm)
        and whether its command went out unlimited (1.0) or not (0.0); updated.
    grid_z, grid_tips : ndarray of shape (n_seeds, n_motors), (n_seeds, 3)
        The seeds of the solve: effective angles (deg) and the backbone's tips there (mm).
    pi, pi_forward : tuple of ndarray, ndarray
        The PI's inverse (see :func:`_pi_commands`) and forward step (see
        :func:`_lead`); read with ``S_KIND == KIND_PI`` only.
    window : ndarray of shape (max(preview, 1), 3 + n_motors)
        The targets ahead in view and their solutions (see :func:`_angles_ahead`); updated.
    target : ndarray of shape (3,)
        Wanted tip (mm).
    measured : ndarray of shape (3,)
        The tip the feedback compares with its aim (mm): the estimate or the tracker's.
    sample : ndarray of shape (n_channels,)
        The observed sample (deg, then the torques).
    ahead : ndarray of shape (k, 3)
        The targets of the next ``k`` samples (mm); ``k = 0``: no preview this sample.

    Returns
    -------
    miss2 : float
        Squared distance from the (corrected) target of the tip aimed at (mm^2).
    """
    n = issued.shape[1]
    torques = sample[n:]
    _observe(view, s, issued, sample, torques)
    mode = int(s[S_MODE])
    z, tip, J = np.empty(n), np.empty(3), np.empty((3, n))
    wanted = _block(s, B_WANTED, n)
    correction = s[S_CORRECTION : S_CORRECTION + 3]
    aimed = target.copy()
    if mode == MODE_INTERNAL_MODEL:
        oldest = int(s[S_AIMS_AT])
        if aims[oldest, 3] > 0.0:  # the aim of the command the observation shows, unlimited
            for k in range(3):
                correction[k] = correction[k] + s[S_GAIN] * (measured[k] - aims[oldest, k] - correction[k])
        for k in range(3):
            aimed[k] = target[k] - correction[k]
    miss2 = _aim(view, aimed, torques, s, grid_z, grid_tips, z, tip, J)
    if mode == MODE_RESOLVED_RATE:
        r, dz = np.empty(3), np.empty(n)
        for k in range(3):
            r[k] = tip[k] - measured[k]
        _damped_step(J, r, s[S_DAMPING], dz, np.empty((n, n)), np.empty(n))
        for j in range(n):
            wanted[j] = wanted[j] + s[S_GAIN] * dz[j]
        _project(wanted, _block(s, B_LOW, n), _block(s, B_HIGH, n), _block(s, B_NEUTRAL, n), s[S_RADIUS])
    else:
        wanted[:] = z
    z_ahead = np.empty((ahead.shape[0], n))
    if ahead.shape[0] > 0:
        _preview_angles(view, s, grid_z, grid_tips, torques, target, ahead, window, z, z_ahead)
    _issue(s, wanted, issued, pi, pi_forward, z_ahead)
    s[S_AIMED : S_AIMED + 3] = tip
    if mode != MODE_FEEDFORWARD:
        at = int(s[S_AIMS_AT])
        aims[at, :3] = tip
        aims[at, 3] = 1.0 - s[S_LIMITED]
        s[S_AIMS_AT] = (at + 1) % aims.shape[0]
    meta, a64, anet, w32, saved_f, saved_buf, f0, buf0 = view
    _restore(meta, a64, anet, w32, saved_f, saved_buf, f0, buf0)
    return miss2


_compiled_step = {}


def control_kernel():
    """The compiled :func:`control_step` (loaded from numba's cache when a previous process compiled it)."""
    if not _compiled_step:
        g = globals()
        for name in ("_project", "_damped_step", "_look", "_jacobian", "_solve", "_distance2", "_nearest", "_aim",
                     "_play_command", "_pi_commands", "_angles_ahead", "_lead", "_preview_angles", "_issue",
                     "_observe", "_block"):
            g[name] = compiled(g[name])  # the step calls them compiled
        _compiled_step["step"] = compiled(control_step)
    return _compiled_step["step"]
