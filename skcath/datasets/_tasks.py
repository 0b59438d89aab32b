"""Closed-loop steering tasks on a simulated catheter, their runner and their scores.

A task is a target path of the tip in the base frame, one target per sample
at the rig's rate, inside the workspace the run's sweep reached: reach and
hold a set of targets, follow a circle, follow a figure-eight.
:func:`run_task` drives a :class:`~skcath.datasets.SimulatedCatheter` with a
controller along a task and scores the true tip against the targets.

A controller is any object with ``start(sweep)``, called once with the
sweep's rows, and ``step(target, obs)``, which returns the motor angles
(deg, shape ``(n_motors,)``) for the sample the target is given for; ``obs``
is the rig's latest record (a dict: ``t``, ``q1 .. qN``, ``tau1 .. tauN``,
and ``x``, ``y``, ``z`` when the tracker is on); ``run_task(...,
preview=k)`` calls ``step(target, obs, upcoming=...)`` with the targets of
the next samples that are known. A controller that keeps its
tip estimate in ``estimate_`` (mm, base frame) after each step has it
returned with the path.
"""

from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
from sklearn.utils import Bunch, check_random_state
from sklearn.utils._param_validation import Interval, validate_params

from .. import _format as fmt

__all__ = [
    "Task",
    "circle_task",
    "figure_eight_task",
    "reach_task",
    "run_task",
    "standard_tasks",
    "task_scores",
]

#: Error below which a reach target counts as reached (mm), for the settling time.
SETTLE_MM = 2.0


@dataclass(frozen=True)
class Task:
    """A target path of the tip at a rig's sample rate.

    Attributes
    ----------
    name : str
        Name of the task (``"reach"``, ``"circle"``, ``"figure_eight"``).
    target : ndarray of shape (n, 3)
        Target tip of each sample (mm, base frame).
    rate_hz : float
        Sample rate of the targets (Hz), that of the rig.
    changes : tuple of int
        Samples at which a new target of a reach task starts (empty for a path).
    scored : ndarray of shape (n,) of bool
        Samples counted by :func:`task_scores` (a path's lead-in from the
        neutral tip to its start is not).
    """

    name: str
    target: np.ndarray
    rate_hz: float
    changes: tuple = ()
    scored: np.ndarray = None

    @property
    def duration_s(self):
        """Length of the task (s)."""
        return len(self.target) / self.rate_hz


def _sweep_arrays(sweep):
    """Motor angles (deg), tracked tips (mm) and sample rate (Hz) of a sweep's rows."""
    missing = [c for c in (fmt.TIME, *fmt.REFERENCE_COLUMNS) if c not in sweep.columns]
    channels = [fmt.channel_index(c) for c in sweep.columns]
    motors = [f"{kind}{k}" for kind, k in sorted(c for c in channels if c and c[0] == fmt.MOTOR_PREFIX)]
    if missing or not motors:
        raise ValueError(
            f"sweep must be the sweep's rows in the recording format, with the columns t, "
            f"q1 .. qN and ref_x, ref_y, ref_z; missing {missing or ['q1']}."
        )
    tips = sweep[list(fmt.REFERENCE_COLUMNS)].to_numpy(dtype=float)
    q = sweep[motors].to_numpy(dtype=float)
    keep = np.all(np.isfinite(tips), axis=1)
    t = sweep[fmt.TIME].to_numpy(dtype=float)
    steps = np.diff(t)
    if len(t) < 10 or not np.all(steps > 0) or keep.sum() < 10:
        raise ValueError(
            "sweep must hold at least 10 tracked rows at increasing times t; "
            f"got {len(t)} rows, {int(keep.sum())} tracked."
        )
    return q[keep], tips[keep], round(1.0 / float(np.median(steps)), 6)


def _neutral_tip(q, tips):
    """The tracked tip at neutral: the median over the sweep rows within half a degree of it."""
    rest = np.all(np.abs(q) <= 0.5, axis=1)
    if not rest.any():
        rest = np.linalg.norm(q, axis=1) <= np.quantile(np.linalg.norm(q, axis=1), 0.05)
    return np.median(tips[rest], axis=0)


def _ray_ends(q, u):
    """Mean tip direction (lateral components) at the end of each ray of the sweep."""
    magnitude = np.linalg.norm(q, axis=1)
    end = magnitude >= 0.98 * magnitude.max()
    rays = np.round(q[end] / magnitude[end, None], 1)
    keys, ray = np.unique(rays, axis=0, return_inverse=True)
    return np.array([u[end][ray.ravel() == k].mean(axis=0) for k in range(len(keys))])


def _inradius(center, vertices):
    """Distance from ``center`` to the nearest edge of the polygon of ``vertices`` taken around it."""
    order = np.argsort(np.arctan2(*(vertices - center).T[::-1]))
    a = vertices[order]
    b = np.roll(a, -1, axis=0)
    ab = b - a
    s = np.clip(np.einsum("ij,ij->i", center - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + s[:, None] * ab - center, axis=1)))


def _surface(tips, degree=4):
    """The reachable surface: the tip's distance from the base over its direction, fitted to the swept tips.

    Returns the map from lateral direction components ``(u_x, u_y)`` of shape
    (n, 2) to tips (n, 3) (mm), a polynomial of ``degree`` in ``u_x, u_y``.
    """
    r = np.linalg.norm(tips, axis=1)
    u = tips[:, :2] / r[:, None]

    def features(uv):
        return np.column_stack([uv[:, 0] ** i * uv[:, 1] ** j for i in range(degree + 1) for j in range(degree + 1 - i)])

    coef, *_ = np.linalg.lstsq(features(u), r, rcond=None)

    def tip(uv):
        axial = np.sqrt(np.clip(1.0 - np.sum(uv**2, axis=1), 0.0, None))
        return (features(uv) @ coef)[:, None] * np.column_stack([uv, axial])

    return tip


def _path_workspace(sweep, shrink):
    """Centre, radius (lateral direction units) and surface of a path task, the neutral tip and the rate.

    The centre is the mean of the rays' end directions, the radius
    ``shrink`` times the distance from it to the nearest edge of their
    polygon; a clear error for a sweep of one motor, whose tips lie in a plane.
    """
    q, tips, rate = _sweep_arrays(sweep)
    if q.shape[1] < 2:
        raise ValueError(
            "a path task needs a sweep that bends the tip in every direction (an instrument "
            f"of two or three motors); this sweep has {q.shape[1]} motor(s) and its tips lie in a plane."
        )
    u = tips[:, :2] / np.linalg.norm(tips, axis=1)[:, None]
    vertices = _ray_ends(q, u)
    center = vertices.mean(axis=0)
    return center, shrink * _inradius(center, vertices), _surface(tips), _neutral_tip(q, tips), rate


def _constant_speed(points, speed_mm_s, rate_hz):
    """Targets along a dense polyline of tips (mm) at a constant speed (mm/s)."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], speed_mm_s / rate_hz)
    return np.column_stack([np.interp(s, arc, points[:, j]) for j in range(3)])


_SHRINK = Interval(Real, 0, 1, closed="right")
_SPEED = Interval(Real, 0, None, closed="neither")
#: Parameter constraints of the path tasks.
_PATH_CONSTRAINTS = {
    "sweep": ["array-like"],
    "speed_mm_s": [_SPEED],
    "shrink": [_SHRINK],
    "n_laps": [Interval(Real, 0, None, closed="neither")],
}


@validate_params(
    {
        "sweep": ["array-like"],
        "n_targets": [Interval(Integral, 1, None, closed="left")],
        "hold_s": [Interval(Real, 0, None, closed="neither")],
        "shrink": [_SHRINK],
        "random_state": ["random_state"],
    },
    prefer_skip_nested_validation=True,
)
def reach_task(sweep, *, n_targets=6, hold_s=5.0, shrink=0.7, random_state=None):
    """Reach and hold targets that the sweep reached, each for ``hold_s`` seconds.

    The targets are tracked tips of sweep samples drawn at random among
    those whose motor angles are within ``shrink`` of the sweep's largest
    (as a vector norm), so that every target lies on the tip's reachable
    surface, well inside its edge.

    Parameters
    ----------
    sweep : pandas.DataFrame
        The sweep's rows of the run (``SimulatedCatheter.reset``'s return).
    n_targets : int, default=6
        Number of targets.
    hold_s : float, default=5.0
        Time on each target (s).
    shrink : float in (0, 1], default=0.7
        Largest motor-angle magnitude of the drawn samples, relative to the sweep's.
    random_state : int, RandomState instance or None, default=None
        Draw of the targets.

    Returns
    -------
    task : Task
        Named ``"reach"``; ``changes`` holds the first sample of each target.
    """
    q, tips, rate = _sweep_arrays(sweep)
    magnitude = np.linalg.norm(q, axis=1)
    inside = np.flatnonzero(magnitude <= shrink * magnitude.max())
    rng = check_random_state(random_state)
    picked = tips[rng.choice(inside, size=n_targets, replace=len(inside) < n_targets)]
    n_hold = max(1, int(round(hold_s * rate)))
    target = np.repeat(picked, n_hold, axis=0)
    changes = tuple(range(0, len(target), n_hold))
    return Task("reach", target, rate, changes, np.ones(len(target), dtype=bool))


@validate_params(_PATH_CONSTRAINTS, prefer_skip_nested_validation=True)
def circle_task(sweep, *, speed_mm_s=5.0, shrink=0.7, n_laps=2):
    """Follow a circle on the reachable surface at a constant tip speed.

    The reachable surface is the tip's distance from the base as a
    polynomial of its direction, fitted to the swept tips (its residual is
    close to the tracker's noise). The circle is drawn in the tip's
    direction: centred on the mean of the directions at the ends of the
    sweep's rays, of radius ``shrink`` times the distance from that centre
    to the nearest edge of their polygon, so it stays inside the swept
    workspace. A straight lead-in from the neutral tip to the circle, at the
    same speed, comes first and is not scored.

    Parameters
    ----------
    sweep : pandas.DataFrame
        The sweep's rows of the run, of an instrument of two or three motors.
    speed_mm_s : float, default=5.0
        Tip speed along the path (mm/s).
    shrink : float in (0, 1], default=0.7
        Radius relative to the distance from the centre to the polygon of the rays' ends.
    n_laps : float, default=2
        Laps of the circle.

    Returns
    -------
    task : Task
        Named ``"circle"``.
    """
    center, radius, surface, neutral, rate = _path_workspace(sweep, shrink)
    angle = np.linspace(0.0, 2.0 * np.pi * n_laps, int(2000 * n_laps) + 1)
    directions = center + radius * np.column_stack([np.cos(angle), np.sin(angle)])
    return _path_task("circle", neutral, surface(directions), speed_mm_s, rate)


def _path_task(name, neutral, points, speed_mm_s, rate):
    """A path task: a straight lead-in from the neutral tip to the path's start (not scored), then the path."""
    lead = _constant_speed(np.linspace(neutral, points[0], 200), speed_mm_s, rate)
    target = np.vstack([lead, _constant_speed(points, speed_mm_s, rate)])
    scored = np.arange(len(target)) >= len(lead)
    return Task(name, target, rate, (), scored)


@validate_params(_PATH_CONSTRAINTS, prefer_skip_nested_validation=True)
def figure_eight_task(sweep, *, speed_mm_s=5.0, shrink=0.7, n_laps=1):
    """Follow a figure-eight on the reachable surface at a constant tip speed.

    A lemniscate of Gerono, ``(a sin s, (a / 2) sin 2s)`` in the tip's
    direction about the centre of :func:`circle_task`, with ``a`` ``shrink``
    times the radius there, on the same surface. A straight lead-in from the
    neutral tip to its start (the centre), at the same speed, comes first
    and is not scored.

    Parameters
    ----------
    sweep : pandas.DataFrame
        The sweep's rows of the run, of an instrument of two or three motors.
    speed_mm_s : float, default=5.0
        Tip speed along the path (mm/s).
    shrink : float in (0, 1], default=0.7
        Half-width of the eight relative to the distance from the centre to the polygon of the rays' ends.
    n_laps : float, default=1
        Laps of the eight.

    Returns
    -------
    task : Task
        Named ``"figure_eight"``.
    """
    center, a, surface, neutral, rate = _path_workspace(sweep, shrink)
    s = np.linspace(0.0, 2.0 * np.pi * n_laps, int(4000 * n_laps) + 1)
    directions = center + a * np.column_stack([np.sin(s), 0.5 * np.sin(2.0 * s)])
    return _path_task("figure_eight", neutral, surface(directions), speed_mm_s, rate)


def standard_tasks(sweep, *, speed_mm_s=5.0, random_state=None):
    """The three tasks with their defaults: reach (6 targets, 5 s each), circle, figure-eight.

    Parameters
    ----------
    sweep : pandas.DataFrame
        The sweep's rows of the run.
    speed_mm_s : float, default=5.0
        Tip speed of the circle and the figure-eight (mm/s).
    random_state : int, RandomState instance or None, default=None
        Draw of the reach targets.

    Returns
    -------
    tasks : list of Task
        Only the reach task for a sweep of one motor (its tip bends in a plane).
    """
    tasks = [reach_task(sweep, random_state=random_state)]
    q, _, _ = _sweep_arrays(sweep)
    if q.shape[1] >= 2:
        tasks += [circle_task(sweep, speed_mm_s=speed_mm_s),
                  figure_eight_task(sweep, speed_mm_s=speed_mm_s)]
    return tasks


def _known_until(task):
    """Per sample, the end (exclusive) of the targets known then: a reach target's successor is not."""
    n = len(task.target)
    ends = np.full(n, n)
    bounds = [*task.changes[1:], n] if task.changes else [n]
    starts = list(task.changes) if task.changes else [0]
    for a, b in zip(starts, bounds):
        ends[a:b] = b
    return ends


def run_task(rig, controller, task, *, preview=0):
    """Drive a rig with a controller along a task.

    Resets the rig (its sweep), calls ``controller.start(sweep)``, holds the
    motors at their last sweep angles for one sample, then, for each target,
    ``command = controller.step(target, obs)`` and ``obs = rig.step(command)``;
    with ``preview > 0``, ``controller.step(target, obs, upcoming=...)``
    with the targets of the next samples that are known.
    The rig's timing (:class:`~skcath.datasets.SimulatedCatheter`) makes a
    command the motor angle one sample after the record ``obs`` it answers
    comes back; the target given with a command is the tip wanted at the
    sample the command takes effect, and that sample's true tip is scored
    against it.

    Parameters
    ----------
    rig : SimulatedCatheter
        The rig (or any object with its ``reset()``, ``step(command)``,
        ``tip_``, ``t_``, ``rate_hz`` and ``n_motors``).
    controller : object
        With ``start(sweep)`` and ``step(target, obs)``.
    task : Task
        At the rig's sample rate.
    preview : int, default=0
        How many of the next samples' targets the controller is given as
        ``upcoming`` (shape (k, 3), mm), ``k <= preview``: those of a path
        up to its end; of a reach task, those of the present target only
        (its successor is not known before it starts), so that a held
        target is previewed as held. 0: ``step(target, obs)`` only.

    Returns
    -------
    result : sklearn.utils.Bunch
        ``t`` (n,) time of each scored sample (s), ``target`` (n, 3),
        ``tip`` (n, 3) the true tip there (mm, base frame), ``error`` (n,)
        their distance (mm), ``command`` (n, n_motors) (deg), ``estimate``
        (n, 3) the controller's ``estimate_`` after each step (the tip of
        the record it was given; None for a controller without one),
        ``n_clipped`` (commands the rig clipped) and ``task``.
    """
    if not np.isclose(float(rig.rate_hz), task.rate_hz, rtol=1e-6):
        raise ValueError(
            f"task {task.name!r} is at {task.rate_hz:g} Hz but the rig samples at "
            f"rig.rate_hz={rig.rate_hz!r}; build the task from this rig's sweep."
        )
    if isinstance(preview, bool) or not isinstance(preview, Integral) or preview < 0:
        raise ValueError(f"preview must be a number of samples, an int >= 0; got {preview!r}.")
    sweep = rig.reset()
    controller.start(sweep)
    motors = list(fmt.motor_names(rig.n_motors))
    hold = sweep[motors].to_numpy(dtype=float)[-1]
    obs = rig.step(hold)
    n = len(task.target)
    commands, tips, times = np.empty((n, len(motors))), np.empty((n + 1, 3)), np.empty(n + 1)
    estimates = []
    known = _known_until(task)
    for i in range(n):
        if preview:
            upcoming = task.target[i + 1:min(i + 1 + preview, known[i])].copy()
            command = controller.step(task.target[i].copy(), obs, upcoming=upcoming)
        else:
            command = controller.step(task.target[i].copy(), obs)
        commands[i] = np.asarray(command, dtype=float)
        estimate = getattr(controller, "estimate_", None)
        estimates.append(None if estimate is None else np.asarray(estimate, dtype=float))
        obs = rig.step(commands[i])
        tips[i], times[i] = rig.tip_, rig.t_
    rig.step(commands[-1])  # the tip where the last command takes effect
    tips[n], times[n] = rig.tip_, rig.t_
    has_estimate = all(e is not None for e in estimates)
    return Bunch(
        t=times[1:], target=task.target, tip=tips[1:],
        error=np.linalg.norm(tips[1:] - task.target, axis=1), command=commands,
        estimate=np.array(estimates) if has_estimate else None,
        n_clipped=int(getattr(rig, "n_clipped_", 0)), task=task,
    )


def task_scores(result, *, settle_mm=SETTLE_MM):
    """RMS and 95th percentile of the true tip error, and the settling time of a reach task.

    Parameters
    ----------
    result : Bunch
        Output of :func:`run_task`.
    settle_mm : float, default=2.0
        Error below which a reach target is held (mm).

    Returns
    -------
    scores : dict
        ``rms_mm`` and ``p95_mm`` over the scored samples; for a reach task,
        ``settling_s``: the median over targets of the time from a target's
        first sample until the error stays below ``settle_mm`` up to the
        next target (inf for a target never held so), and ``settled``, the
        fraction of targets held; NaN for a path.
    """
    task, error = result.task, np.asarray(result.error, dtype=float)
    scored = error[task.scored]
    scores = {
        "rms_mm": float(np.sqrt(np.mean(scored**2))),
        "p95_mm": float(np.percentile(scored, 95)),
        "settling_s": np.nan,
        "settled": np.nan,
    }
    if task.changes:
        bounds = [*task.changes, len(error)]
        times = [_settling(error[a:b], settle_mm) / task.rate_hz for a, b in zip(bounds[:-1], bounds[1:])]
        scores["settling_s"] = float(np.median(times))
        scores["settled"] = float(np.mean(np.isfinite(times)))
    return scores


def _settling(error, threshold):
    """Samples until ``error`` stays below ``threshold`` to its end (inf if its last sample is not)."""
    above = np.flatnonzero(error >= threshold)
    if not above.size:
        return 0.0
    if above[-1] == len(error) - 1:
        return np.inf
    return float(above[-1] + 1)
