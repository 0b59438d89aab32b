"""The default benchmark: 4 catheters x 17 shaft settings x 3 runs, cached on disk."""

import hashlib
import json
import logging
import os
import re
import shutil
import time
from numbers import Integral, Real
from pathlib import Path

import numpy as np
from sklearn.utils._param_validation import Interval, StrOptions, validate_params

from ._cache import SUFFIX, as_json_value, read_bunch, read_key, write_bunch
from ._catheter import UNIT_SPREAD, Catheter, sample_catheter, shaft_settings
from ._hysteresis import MECHANISMS
from ._mixed import MIXED, simulate_mixed, unit_mechanisms
from ._sensors import DistortionField
from ._tendons import MotorCount, tendon_layout
from ._simulator import (
    MAX_RATE_HZ,
    RATE_HZ,
    RunSpec,
    ShaftChange,
    check_run_variation,
    simulate_runs,
)

__all__ = [
    "SIMULATOR_VERSION",
    "benchmark_catheter",
    "clear_data_home",
    "get_data_home",
    "make_benchmark",
]

logger = logging.getLogger(__name__)

#: Bumped whenever the simulator's output changes, so stale caches are not reused.
SIMULATOR_VERSION = "6"


class _Count(Interval):
    """Integers from ``left`` on, booleans excluded (Python counts ``True`` as an int)."""

    def __init__(self, left):
        super().__init__(Integral, left, None, closed="left")

    def is_satisfied_by(self, val):
        return not isinstance(val, (bool, np.bool_)) and super().is_satisfied_by(val)


@validate_params(
    {"data_home": [str, os.PathLike, None]}, prefer_skip_nested_validation=True
)
def get_data_home(data_home=None):
    """Folder where skcath caches generated benchmarks.

    Parameters
    ----------
    data_home : str or path-like, optional
        Folder to use. Defaults to the ``SKCATH_DATA`` environment variable,
        else ``~/skcath_data``. Created if missing.

    Returns
    -------
    path : pathlib.Path
    """
    if data_home is None:
        data_home = os.environ.get("SKCATH_DATA", Path("~") / "skcath_data")
    path = Path(data_home).expanduser()
    path.mkdir(parents=True, exist_ok=True)
    return path


@validate_params(
    {"data_home": [str, os.PathLike, None]}, prefer_skip_nested_validation=True
)
def clear_data_home(data_home=None):
    """Delete the cache folder and everything in it.

    Parameters
    ----------
    data_home : str or path-like, optional
        Folder to delete; see :func:`get_data_home`.
    """
    shutil.rmtree(get_data_home(data_home))


#: Range of the time of a shaft change after the first motion sample (s):
#: the motion phase lasts at least 164 s, so at least 74 s follow the change.
CHANGE_AFTER_S = (30.0, 90.0)


def _draw_change(entropy, setting, settings, resweep=False):
    """Shaft change of one run: another setting and a time, from their own seed.

    The change draws from a child of the run's seed sequence, so the run's
    own draws, and the run up to the change, are those of the unchanged run.
    ``resweep`` does not change the draws.
    """
    draw_seed, pose_seed = np.random.SeedSequence(entropy, spawn_key=(1,)).spawn(2)
    rng = np.random.default_rng(draw_seed)
    others = [s for s in settings if s.name != setting.name]
    after = others[int(rng.integers(len(others)))]
    return ShaftChange(after, float(rng.uniform(*CHANGE_AFTER_S)), pose_seed, resweep)


@validate_params(
    {
        "number": [_Count(1)],
        "random_state": [_Count(0)],
        "unit_spread": [Interval(Real, 0, 1, closed="both")],
        "n_motors": [MotorCount()],
    },
    prefer_skip_nested_validation=True,
)
def benchmark_catheter(number, random_state=0, *, unit_spread=UNIT_SPREAD, n_motors=2):
    """Catheter unit ``C<number>`` of the benchmark drawn with ``random_state``.

    The unit that :func:`make_benchmark` simulates as ``C<number>`` (with the
    same ``random_state`` and ``unit_spread``): its draw depends on these
    three values only, so every benchmark with at least ``number`` catheters
    holds this unit.

    Parameters
    ----------
    number : int
        Number of the unit, from 1 (``"C1"``).
    random_state : int, default=0
        Seed of the benchmark.
    unit_spread : float in [0, 1], default=0.35
        See :func:`sample_catheter`.
    n_motors : {1, 2, 3}, default=2
        Motors of the instrument; see :func:`sample_catheter`.

    Returns
    -------
    catheter : Catheter
        Named ``"C<number>"``.
    """
    seed = np.random.SeedSequence([random_state, number - 1])
    return sample_catheter(seed, f"C{number}", unit_spread=unit_spread, n_motors=n_motors)


def _unit_number(catheter):
    """The number ``k`` of a unit named ``"Ck"``, which selects the runs it is given."""
    match = re.fullmatch(r"C([1-9][0-9]*)", catheter.name)
    if match is None:
        raise ValueError(
            f"catheters: every unit must be named 'C1', 'C2', ... (the unit named 'Ck' "
            f"runs the benchmark's runs of its k-th unit); got {catheter.name!r}."
        )
    return int(match.group(1))


def benchmark_specs(catheters, n_runs=3, random_state=0, shaft_change=False, resweep=False):
    """Run specifications of the benchmark, in catheter, setting, repeat order.

    The unit named ``"Ck"`` (see :func:`benchmark_catheter`) and each of its
    runs draw from seeds derived from ``(random_state, k - 1)`` and
    ``(random_state, k - 1, setting, repeat)``, so a smaller benchmark is a
    subset of a larger one with the same seed, and a modified unit runs the
    same runs as the unit it was made from. With ``shaft_change``, every run
    also gets a :class:`ShaftChange` drawn from its own seed (see
    :func:`make_benchmark`), with a re-sweep after it when ``resweep``.
    """
    specs = []
    settings = shaft_settings()
    for cat in catheters:
        k = _unit_number(cat) - 1
        for s_idx, setting in enumerate(settings):
            for r in range(n_runs):
                entropy = [random_state, k, s_idx, r]
                seed = np.random.SeedSequence(entropy)
                change = _draw_change(entropy, setting, settings, resweep) if shaft_change else None
                specs.append(
                    RunSpec(f"{cat.name}-{setting.name}-R{r + 1}", cat, setting, r + 1, seed, change)
                )
    return specs


def _benchmark_field(random_state=0):
    """The tracker's field distortion of the benchmark drawn with ``random_state``.

    Its seed differs from those of the catheters and runs
    (:func:`benchmark_specs`) and depends on ``random_state`` only, so every
    benchmark of one ``random_state`` shares the field, whatever its numbers
    of catheters and runs.
    """
    return DistortionField(np.random.SeedSequence([random_state, 10**6]))


@validate_params(
    {
        "n_catheters": [_Count(1)],
        "n_runs": [_Count(1)],
        "mechanism": [StrOptions({*MECHANISMS, MIXED}), list, tuple],
        "random_state": [_Count(0)],
        "shaft_change": ["boolean"],
        "resweep": ["boolean"],
        "unit_spread": [Interval(Real, 0, 1, closed="both")],
        "run_variation": [dict, None],
        "catheters": [list, tuple, None],
        "rate_hz": [Interval(Real, 1, MAX_RATE_HZ, closed="both")],
        "n_motors": [MotorCount()],
        "data_home": [str, os.PathLike, None],
        "cache": ["boolean"],
        "verbose": ["boolean"],
    },
    prefer_skip_nested_validation=True,
)
def make_benchmark(
    n_catheters=4,
    n_runs=3,
    *,
    mechanism="play",
    random_state=0,
    shaft_change=False,
    resweep=False,
    unit_spread=UNIT_SPREAD,
    run_variation=None,
    catheters=None,
    rate_hz=RATE_HZ,
    n_motors=2,
    data_home=None,
    cache=True,
    verbose=False,
):
    """Simulated recordings with the paper's protocol (the default skcath data).

    ``n_catheters`` catheter units of one family, each in 17 shaft settings
    (straight, then 8 bend directions at a low and a high bend level), each
    recorded ``n_runs`` times. A run is an 8-ray outward-and-return sweep from
    neutral followed by a 100-step random walk of both motors inside
    ``|q| <= 60`` degrees; 6000-6300 samples at 10 Hz. The tip position in the
    bending-section base frame is computed from two noisy 6-DOF EM sensors
    (paper eq. 1), as on the bench. ``docs/studies/simulator.rst`` describes the
    physics.

    Parameters
    ----------
    n_catheters : int, default=4
        Number of catheter units (``C1``, ``C2``, ...; unit ``Ck`` is
        :func:`benchmark_catheter` ``(k, random_state)``). Unused when
        ``catheters`` is given.
    n_runs : int, default=3
        Repeats per shaft setting.
    mechanism : {"play", "bouc_wen", "dahl_creep", "mixed"} or sequence of str, default="play"
        Hysteresis mechanism of the tendon transmission: load-dependent play
        (Coulomb friction and elastic tendon), asymmetric Bouc-Wen, or
        rate-dependent Dahl friction with tendon creep. ``"mixed"``: units
        that differ in kind, unit ``Ck`` with the mechanism
        ``MECHANISMS[(k - 1) % 3]`` (C1 play, C2 bouc_wen, C3 dahl_creep, C4
        play, ...); a list or tuple names the mechanism of every unit, in
        order (one per unit). Each unit's runs are those of its mechanism
        (``docs/simulated_benchmark.rst``, *Units that differ in kind*).
        Cached separately when the units' mechanisms differ.
    random_state : int, default=0
        Seed of everything random. Same seed, same data.
    shaft_change : bool, default=False
        Reposition the shaft in the middle of every run's motion phase: at
        a time drawn uniformly 30-90 s after the first motion sample, the
        shaft moves to another of the 17 settings, drawn uniformly; from
        there on the run continues with that setting's transmission (wrap,
        offsets, dead zone, gains, routing, friction) and base pose. The
        motor trajectory, the noise and everything before the change are
        those of the run without a change (same seed). ``runs`` gets the
        columns ``setting_after`` and ``change_time_s`` (time ``t`` of the
        first sample in the new setting, s). Cached separately.
    resweep : bool, default=False
        With ``shaft_change``: at the change, every run performs its sweep
        again in the new setting, then goes on with the rest of its motion
        (``docs/studies/simulator.rst``, *A shaft change and a re-sweep*). The part
        after the change is recorded as a run of its own, ``"<run>/after"``
        (setting: the new one; its sweep rows hold the tracked reference),
        so that every run still is a sweep followed by motion; the part
        before it is the ``shaft_change`` run up to the change, sample for
        sample. ``runs`` gets the column ``before_run`` (the run an
        ``"<run>/after"`` run continues; None for the others). Cached
        separately.
    unit_spread : float in [0, 1], default=0.35
        Unit-to-unit spread of the drawn catheter units (see
        :func:`sample_catheter`); 1 draws the units of simulator version 5.
        Cached separately when not the default.
    run_variation : dict or None, default=None
        Per-run variation replacing some of the simulator's standard
        deviations and time constants, by key: ``gain_jitter``,
        ``offset_jitter_deg``, ``offset_drift_deg``, ``offset_drift_tau_s``,
        ``gain_drift``, ``gain_drift_tau_s``, ``base_position_mm``,
        ``base_rotation_deg`` (``docs/studies/simulator.rst``, *Runs*); e.g.
        ``{"gain_drift": 0.0}`` switches the gain drift off. The runs keep
        their random numbers, so only the changed variation differs. Cached
        separately when given.
    catheters : list of Catheter, default=None
        Catheter units to simulate instead of ``n_catheters`` drawn units.
        Each must be named ``"Ck"`` and runs the runs of the benchmark's unit
        ``Ck`` (same protocols, per-run variation and noise): a unit changed
        with ``dataclasses.replace(benchmark_catheter(k), ...)`` is recorded
        in exactly the runs of the original, and ``[benchmark_catheter(k)]``
        gives the rows of ``Ck`` alone. Cached separately.
    rate_hz : float, default=10.0
        Sample rate of the recordings (Hz), from 1 to 1000. The runs are the
        same at every rate (catheters, settings, motor trajectories, drifts,
        base poses: the protocol is drawn at 10 Hz), sampled at ``rate_hz``
        with fresh per-sample noise of the same standard deviation
        (``docs/studies/simulator.rst``, *Sample rate*). Cached separately when not
        the default.
    n_motors : {1, 2, 3}, default=2
        Motors of the simulated instrument (``docs/studies/simulator.rst``,
        *Instruments of one and three motors*): 1, one tendon pair bending in
        one plane, with a sweep out and back along its axis to both signs
        and a walk in an interval; 2, the benchmark's two pairs; 3, three
        single tendons at 120 degrees with a 6-ray sweep. ``X`` has the
        columns ``q1 .. qN`` and ``tau1 .. tauN``, and ``runs`` the drift
        columns of every motor. The units, runs and seeds are those of the
        two-motor benchmark; the tendons of each unit are its own. Given
        ``catheters`` must have this number of motors. ``resweep`` is
        simulated for two motors only. Cached separately when not 2.
    data_home : str or path-like, optional
        Cache folder; see :func:`get_data_home`.
    cache : bool, default=True
        Load from / save to the cache folder. The cache file holds no
        pickle and is read with ``numpy.load(..., allow_pickle=False)``; it
        is used only when the key stored in it (``bunch.key``) matches
        (``docs/studies/simulator.rst``, *The cache*).
    verbose : bool, default=False
        Log generation progress at INFO level.

    Returns
    -------
    bunch : sklearn.utils.Bunch
        X : pandas.DataFrame
            Long format (``docs/data_format.rst``): ``catheter``, ``setting``,
            ``run`` (categorical), ``t`` (s), ``phase``, ``q1``, ``q2``
            (deg), ``tau1``, ``tau2`` (N mm; ``q1 .. qN`` and ``tau1 ..
            tauN`` for ``n_motors=N``), ``ref_x``, ``ref_y``, ``ref_z`` (mm,
            sweep rows only).
        y : ndarray of shape (n_samples, 3)
            Measured tip position in the base frame (mm).
        y_true : ndarray of shape (n_samples, 3)
            Noise-free tip position in the base frame (mm).
        sensors : pandas.DataFrame
            Raw EM poses of the tip and base sensors in the tracker frame
            (mm; quaternions scalar first), aligned with ``X``.
        runs : pandas.DataFrame
            One row per run: ids, repeat, bend level and direction, shaft
            wrap (deg), sample counts, the run's noise floor (mm), and the
            simulator's truth of the run's own variation at its first motion
            sample, which no column of ``X`` shows: ``offset_drift1_deg``,
            ``offset_drift2_deg`` (the motor offsets less the setting's, deg)
            and ``gain_drift1``, ``gain_drift2`` (the relative tendon gains
            less 1; one of each per motor), each the run's jitter plus its
            slow drift until then.
        catheters : dict
            Physical parameters of each catheter unit.
        noise_floor : float
            Sensor-noise floor: RMS tip error (mm) of the measured against
            the noise-free tip over motion rows, averaged over runs with
            equal weights. No estimator can be expected to go below it.
        mechanism : str
            The hysteresis mechanism used; ``"mixed"`` when the units'
            mechanisms differ.
        mechanisms : dict
            With ``"mixed"`` only: the mechanism of each unit, by name;
            ``runs`` then has the column ``mechanism``.
        DESCR : str
            A short description of the data set.

    Examples
    --------
    >>> from skcath.datasets import make_benchmark
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> data.X.groupby("run", observed=True).size().between(6000, 6300).all()  # doctest: +SKIP
    True
    """
    check_run_variation(run_variation)  # a bad key fails before any work
    if resweep and not shaft_change:
        raise ValueError(
            "resweep=True sweeps again after the shaft change; it needs shaft_change=True."
        )
    if resweep and n_motors != 2:
        raise ValueError(
            f"resweep=True is simulated for two motors only; got n_motors={n_motors}."
        )
    given = catheters is not None
    if given:
        catheters = _check_catheters(catheters, n_motors)
    else:
        catheters = [
            benchmark_catheter(k, random_state, unit_spread=unit_spread, n_motors=n_motors)
            for k in range(1, int(n_catheters) + 1)
        ]
    mechanisms = unit_mechanisms(mechanism, [_unit_number(c) for c in catheters])
    if mechanisms is None and not isinstance(mechanism, str):
        mechanism = mechanism[0]  # the same mechanism for every unit: that benchmark
    key = _cache_key(
        len(catheters), int(n_runs), MIXED if mechanisms else mechanism, int(random_state), shaft_change,
        resweep=resweep, unit_spread=unit_spread, run_variation=run_variation,
        catheters=catheters if given else None, rate_hz=float(rate_hz), n_motors=n_motors,
        mechanisms=mechanisms,
    )
    path = _cache_path(key, data_home) if cache else None
    bunch = None if path is None else _load_cached(path, key)
    if bunch is not None:
        return bunch

    start = time.perf_counter()
    specs = benchmark_specs(
        catheters, int(n_runs), int(random_state), bool(shaft_change), bool(resweep)
    )
    simulation = {"field": _benchmark_field(int(random_state)), "run_variation": run_variation,
                  "rate_hz": float(rate_hz)}
    if mechanisms is None:
        bunch = simulate_runs(specs, mechanism=mechanism, **simulation)
    else:
        bunch = simulate_mixed(specs, mechanisms, [c.name for c in catheters], **simulation)
    # as the cache gives them back: plain floats and lists
    bunch.catheters = as_json_value({c.name: c.to_dict() for c in catheters})
    bunch.key = key
    bunch.DESCR = _describe(bunch, len(catheters), int(n_runs), float(rate_hz), n_motors)
    if verbose:
        logger.info("generated %d runs in %.1f s", len(specs), time.perf_counter() - start)
    if path is not None:
        _write_cached(path, bunch)
    return bunch


def _check_catheters(catheters, n_motors=2):
    """The given catheter units as a list; each a ``Catheter`` named ``"Ck"`` of ``n_motors`` motors, names unique."""
    catheters = list(catheters)
    if not catheters:
        raise ValueError("catheters must hold at least one Catheter; got an empty sequence.")
    for cat in catheters:
        if not isinstance(cat, Catheter):
            raise TypeError(
                f"catheters must hold Catheter units (see benchmark_catheter and "
                f"sample_catheter); got {type(cat).__name__}."
            )
        _unit_number(cat)
        if cat.n_motors != n_motors:
            raise ValueError(
                f"catheters: unit {cat.name!r} has {cat.n_motors} motor(s), but "
                f"n_motors={n_motors}; pass n_motors={cat.n_motors} or units of {n_motors}."
            )
    names = [cat.name for cat in catheters]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"catheters: every unit needs its own name; {repeated} repeat.")
    return catheters


def _cache_key(n_catheters, n_runs, mechanism, random_state, shaft_change, *,
               resweep=False, unit_spread, run_variation, catheters, rate_hz=RATE_HZ,
               n_motors=2, mechanisms=None):
    """What identifies a generated benchmark; the default benchmark keeps its first key."""
    key = {
        "version": SIMULATOR_VERSION,
        "n_catheters": n_catheters,
        "n_runs": n_runs,
        "mechanism": mechanism,
        "random_state": random_state,
    }
    if shaft_change:
        key["shaft_change"] = True
    if resweep:
        key["resweep"] = True
    if unit_spread != UNIT_SPREAD:
        key["unit_spread"] = float(unit_spread)
    if run_variation:
        key["run_variation"] = {k: float(v) for k, v in sorted(run_variation.items())}
    if catheters is not None:
        key["catheters"] = [cat.to_dict() for cat in catheters]
    if rate_hz != RATE_HZ:
        key["rate_hz"] = float(rate_hz)
    if n_motors != 2:
        key["n_motors"] = int(n_motors)
    if mechanisms is not None:
        key["mechanisms"] = list(mechanisms)
    return as_json_value(key)


def _cache_path(key, data_home):
    """File of the benchmark with ``key`` in the cache folder.

    The file name holds a digest of the key; its suffix is that of the
    pickle-free cache format (:mod:`skcath.datasets._cache`), so that the
    pickled ``.joblib`` files of earlier skcath versions are never opened.
    """
    digest = hashlib.sha1(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
    return get_data_home(data_home) / f"benchmark-{key['mechanism']}-{digest}{SUFFIX}"


def _load_cached(path, key):
    """The cached benchmark at ``path`` if it was generated with ``key``, else None.

    The file is read without unpickling anything, so whatever sits at the
    predictable path runs no code.
    """
    if not path.exists():
        return None
    try:
        if read_key(path) != key:
            return None
        return read_bunch(path)
    except Exception as exc:  # a truncated or foreign file: regenerate
        logger.warning("ignoring unreadable cache file %s (%s)", path, exc)
        return None


def _write_cached(path, bunch):
    """Write ``bunch`` to ``path`` through a temporary file, so a reader never sees half a file."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as file:
            write_bunch(file, bunch, bunch.key)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


_INSTRUMENTS = {
    1: "Instrument: one motor, one tendon pair bending in one plane.\n",
    2: "",
    3: "Instrument: three motors, one tendon each, at 120 degrees.\n",
}
_WALKERS = {1: "the motor", 2: "both motors", 3: "the three motors"}


def _mechanism_text(bunch):
    """The mechanism, or that of every unit (``C1 play, C2 bouc_wen, ...``)."""
    if "mechanisms" not in bunch:
        return bunch.mechanism
    return ", ".join(f"{name} {m}" for name, m in bunch.mechanisms.items())


def _describe(bunch, n_catheters, n_runs, rate_hz=RATE_HZ, n_motors=2):
    runs = bunch.runs
    rays = tendon_layout(n_motors).sweep_rays
    return (
        "skcath simulated catheter benchmark\n"
        + _INSTRUMENTS[n_motors]
        + f"{n_catheters} catheters x 17 shaft settings x {n_runs} runs = {len(runs)} runs, "
        f"{len(bunch.X)} samples at {rate_hz:g} Hz; hysteresis mechanism: {_mechanism_text(bunch)}.\n"
        f"Each run: {rays}-ray outward-and-return sweep, then a 100-step random walk of "
        f"{_WALKERS[n_motors]}.\n"
        + (
            "The shaft is repositioned to another setting during each run's motion "
            "(runs: setting_after, change_time_s).\n"
            if "change_time_s" in runs
            else ""
        )
        + (
            "At the change the run sweeps again; the part after it is a run of its own, "
            "'<run>/after' (runs: before_run).\n"
            if "before_run" in runs
            else ""
        )
        + f"Sensor-noise floor: {bunch.noise_floor:.2f} mm RMS."
    )
