"""The default benchmark: 4 catheters x 17 shaft settings x 3 runs, cached on disk."""

import hashlib
import json
import logging
import os
import shutil
import time
from pathlib import Path

import joblib
import numpy as np

from ._catheter import sample_catheter, shaft_settings
from ._hysteresis import MECHANISMS
from ._sensors import DistortionField
from ._simulator import RunSpec, ShaftChange, simulate_runs

__all__ = ["get_data_home", "clear_data_home", "make_benchmark", "SIMULATOR_VERSION"]

logger = logging.getLogger(__name__)

#: Bumped whenever the simulator's output changes, so stale caches are not reused.
SIMULATOR_VERSION = "6"


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


def clear_data_home(data_home=None):
    """Delete the cache folder and everything in it."""
    shutil.rmtree(get_data_home(data_home))


def _check_int(name, value, low):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an int >= {low}; got {value!r}.")
    return int(value)


#: Range of the time of a shaft change after the first motion sample (s):
#: the motion phase lasts at least 164 s, so at least 74 s follow the change.
CHANGE_AFTER_S = (30.0, 90.0)


def _draw_change(entropy, setting, settings):
    """Shaft change of one run: another setting and a time, from their own seed.

    The change draws from a child of the run's seed sequence, so the run's
    own draws, and the run up to the change, are those of the unchanged run.
    """
    draw_seed, pose_seed = np.random.SeedSequence(entropy, spawn_key=(1,)).spawn(2)
    rng = np.random.default_rng(draw_seed)
    others = [s for s in settings if s.name != setting.name]
    after = others[int(rng.integers(len(others)))]
    return ShaftChange(after, float(rng.uniform(*CHANGE_AFTER_S)), pose_seed)


def benchmark_specs(n_catheters=4, n_runs=3, random_state=0, shaft_change=False):
    """Run specifications of the benchmark, in catheter, setting, repeat order.

    Catheter ``k`` and each run draw from seeds derived from
    ``(random_state, k)`` and ``(random_state, k, setting, repeat)``, so a
    smaller benchmark is a subset of a larger one with the same seed. With
    ``shaft_change``, every run also gets a :class:`ShaftChange` drawn from
    its own seed (see :func:`make_benchmark`).
    """
    specs = []
    settings = shaft_settings()
    for k in range(n_catheters):
        cat = sample_catheter(np.random.SeedSequence([random_state, k]), f"C{k + 1}")
        for s_idx, setting in enumerate(settings):
            for r in range(n_runs):
                entropy = [random_state, k, s_idx, r]
                seed = np.random.SeedSequence(entropy)
                change = _draw_change(entropy, setting, settings) if shaft_change else None
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


def make_benchmark(
    n_catheters=4,
    n_runs=3,
    *,
    mechanism="play",
    random_state=0,
    shaft_change=False,
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
    (paper eq. 1), as on the bench. ``docs/simulator.rst`` describes the
    physics.

    Parameters
    ----------
    n_catheters : int, default=4
        Number of catheter units (``C1``, ``C2``, ...).
    n_runs : int, default=3
        Repeats per shaft setting.
    mechanism : {"play", "bouc_wen", "dahl_creep"}, default="play"
        Hysteresis mechanism of the tendon transmission: load-dependent play
        (Coulomb friction and elastic tendon), asymmetric Bouc-Wen, or
        rate-dependent Dahl friction with tendon creep.
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
    data_home : str or path-like, optional
        Cache folder; see :func:`get_data_home`.
    cache : bool, default=True
        Load from / save to the cache folder.
    verbose : bool, default=False
        Log generation progress at INFO level.

    Returns
    -------
    bunch : sklearn.utils.Bunch
        X : pandas.DataFrame
            Long format (``docs/data_format.rst``): ``catheter``, ``setting``,
            ``run`` (categorical), ``t`` (s), ``phase``, ``q1``, ``q2``
            (deg), ``tau1``, ``tau2`` (N mm), ``ref_x``, ``ref_y``, ``ref_z``
            (mm, sweep rows only).
        y : ndarray of shape (n_samples, 3)
            Measured tip position in the base frame (mm).
        y_true : ndarray of shape (n_samples, 3)
            Noise-free tip position in the base frame (mm).
        sensors : pandas.DataFrame
            Raw EM poses of the tip and base sensors in the tracker frame
            (mm; quaternions scalar first), aligned with ``X``.
        runs : pandas.DataFrame
            One row per run: ids, repeat, bend level and direction, shaft
            wrap (deg), sample counts and the run's noise floor (mm).
        catheters : dict
            Physical parameters of each catheter unit.
        noise_floor : float
            Sensor-noise floor: RMS tip error (mm) of the measured against
            the noise-free tip over motion rows, averaged over runs with
            equal weights. No estimator can be expected to go below it.
        mechanism : str
            The hysteresis mechanism used.
        DESCR : str
            A short description of the data set.

    Examples
    --------
    >>> from skcath.datasets import make_benchmark
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> data.X.groupby("run", observed=True).size().between(6000, 6300).all()  # doctest: +SKIP
    True
    """
    n_catheters = _check_int("n_catheters", n_catheters, 1)
    n_runs = _check_int("n_runs", n_runs, 1)
    random_state = _check_int("random_state", random_state, 0)
    if mechanism not in MECHANISMS:
        raise ValueError(f"mechanism must be one of {MECHANISMS}; got {mechanism!r}.")
    key = {
        "version": SIMULATOR_VERSION,
        "n_catheters": n_catheters,
        "n_runs": n_runs,
        "mechanism": mechanism,
        "random_state": random_state,
    }
    if not isinstance(shaft_change, (bool, np.bool_)):
        raise ValueError(f"shaft_change must be a bool; got {shaft_change!r}.")
    if shaft_change:  # the default benchmark keeps its key, and its cache file
        key["shaft_change"] = True
    digest = hashlib.sha1(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
    path = None
    if cache:
        path = get_data_home(data_home) / f"benchmark-{mechanism}-{digest}.joblib"
        if path.exists():
            try:
                bunch = joblib.load(path)
                if bunch.get("key") == key:
                    return bunch
            except Exception as exc:  # a truncated or foreign file: regenerate
                logger.warning("ignoring unreadable cache file %s (%s)", path, exc)

    start = time.perf_counter()
    specs = benchmark_specs(n_catheters, n_runs, random_state, bool(shaft_change))
    bunch = simulate_runs(specs, mechanism=mechanism, field=_benchmark_field(random_state))
    cats = {s.catheter.name: s.catheter for s in specs}
    bunch.catheters = {name: c.to_dict() for name, c in cats.items()}
    bunch.key = key
    bunch.DESCR = _describe(bunch, n_catheters, n_runs)
    if verbose:
        logger.info("generated %d runs in %.1f s", len(specs), time.perf_counter() - start)
    if cache:
        tmp = path.with_suffix(".tmp")
        joblib.dump(bunch, tmp)
        tmp.replace(path)
    return bunch


def _describe(bunch, n_catheters, n_runs):
    runs = bunch.runs
    return (
        "skcath simulated catheter benchmark\n"
        f"{n_catheters} catheters x 17 shaft settings x {n_runs} runs = {len(runs)} runs, "
        f"{len(bunch.X)} samples at 10 Hz; hysteresis mechanism: {bunch.mechanism}.\n"
        "Each run: 8-ray outward-and-return sweep, then a 100-step random walk of both motors.\n"
        + (
            "The shaft is repositioned to another setting during each run's motion "
            "(runs: setting_after, change_time_s).\n"
            if "change_time_s" in runs
            else ""
        )
        + f"Sensor-noise floor: {bunch.noise_floor:.2f} mm RMS."
    )
