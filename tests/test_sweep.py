"""Tests of skcath.sweep: rays of the calibration sweep from the motor angles."""


import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_array_equal
from sklearn.utils._param_validation import InvalidParameterError

from skcath.datasets import simulate_run
from skcath.datasets._protocol import min_jerk, sweep_trajectory
from skcath.sweep import SweepRays, check_sweep_references, find_rays

EIGHT = np.arange(8) * 45.0


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def make_sweep(
    directions_deg=EIGHT,
    *,
    amplitude=60.0,
    neutral=(0.0, 0.0),
    noise=0.0,
    n_move=250,
    dwell_out=15,
    dwell_in=25,
    rest=30,
    seed=0,
):
    """Out-and-back sweep along ``directions_deg`` (in that order), degrees.

    Minimum-jerk moves of ``n_move`` samples from ``neutral`` to
    ``amplitude`` along each direction and back, with dwells; Gaussian
    encoder noise of standard deviation ``noise`` (deg).
    """
    s = min_jerk(n_move)[:, None]
    parts = [np.zeros((rest, 2))]
    for psi in np.deg2rad(np.asarray(directions_deg, dtype=float)):
        end = amplitude * np.array([np.cos(psi), np.sin(psi)])
        parts += [end * s, np.repeat(end[None], dwell_out, axis=0)]
        parts += [end * (1.0 - s), np.zeros((dwell_in, 2))]
    q = np.concatenate(parts) + np.asarray(neutral, dtype=float)
    if noise > 0:
        q = q + np.random.default_rng(seed).normal(0.0, noise, q.shape)
    return q


def fake_reference(q, neutral=(0.0, 0.0)):
    """Smooth reference tip positions (mm) for hand-made sweeps."""
    d = np.asarray(q, dtype=float) - np.asarray(neutral, dtype=float)
    rho = np.hypot(d[:, 0], d[:, 1])
    return np.column_stack([0.5 * d[:, 0], 0.5 * d[:, 1], 60.0 - 0.004 * rho**2])


def angle_diff_deg(a, b):
    """Signed difference a - b of angles in degrees, wrapped into [-180, 180)."""
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def assert_directions(rays, commanded_deg, atol=0.5):
    """Found directions match the commanded ones (any order, any wrap)."""
    found = np.sort(np.rad2deg(rays.directions) % 360.0)
    expected = np.sort(np.asarray(commanded_deg, dtype=float) % 360.0)
    assert found.size == expected.size
    # match each commanded direction to its nearest found one
    diff = np.abs(angle_diff_deg(expected[:, None], found[None, :])).min(axis=1)
    assert diff.max() < atol, (found, expected)


def assert_consistent(rays, q, *, atol_deg=2.0, min_rho=None):
    """Structure of a SweepRays and agreement of the labels with the geometry."""
    n = len(q)
    k = rays.directions.size
    assert rays.labels.shape == (n,) and rays.neutral.shape == (n,)
    assert rays.amplitudes.shape == (k,) and rays.q_neutral.shape == (2,)
    assert np.all(np.diff(rays.directions) > 0)
    assert np.all(rays.directions >= -np.pi) and np.all(rays.directions < np.pi)
    rho, psi = rays.polar(q)
    # -1 exactly at neutral; every sample above the threshold has a ray
    np.testing.assert_array_equal(rays.labels == -1, rays.neutral)
    assert np.all(rays.labels[rho > rays.neutral_threshold] >= 0)
    assert np.all(rho[rays.neutral] <= rays.neutral_threshold)
    assert set(np.unique(rays.labels[rays.labels >= 0])) == set(range(k))
    np.testing.assert_allclose(rays.q_neutral, q[rays.neutral].mean(axis=0), atol=1e-2)
    # samples of a ray lie around its direction once away from neutral
    min_rho = 0.2 * rays.amplitude if min_rho is None else min_rho
    far = (rho > min_rho) & (rays.labels >= 0)
    dev = angle_diff_deg(np.rad2deg(psi[far]), np.rad2deg(rays.directions[rays.labels[far]]))
    assert np.abs(dev).max() < atol_deg
    # amplitudes are the largest rho of each ray
    for j in range(k):
        assert rays.amplitudes[j] == pytest.approx(rho[rays.labels == j].max())
    assert rays.amplitude == pytest.approx(np.median(rays.amplitudes))


# ---------------------------------------------------------------------------
# the protocol and hand-made sweeps
# ---------------------------------------------------------------------------
def test_protocol_sweep():
    q = sweep_trajectory()
    q_before = q.copy()
    rays = find_rays(q, run="R1")
    np.testing.assert_array_equal(q, q_before)
    assert isinstance(rays, SweepRays)
    assert rays.n_rays == 8
    assert_directions(rays, EIGHT)
    assert_consistent(rays, q, atol_deg=0.5)
    np.testing.assert_allclose(rays.amplitudes, 60.0, atol=0.1)
    assert rays.amplitude == pytest.approx(60.0, abs=0.1)
    np.testing.assert_allclose(rays.q_neutral, 0.0, atol=1e-6)
    # labels index the sorted directions: [-180, -135, ..., 135]
    np.testing.assert_allclose(rays.directions_deg, np.arange(-180.0, 180.0, 45.0), atol=0.5)


def test_labels_follow_excursions_in_time():
    q = sweep_trajectory()
    rays = find_rays(q)
    # each ray is one contiguous block of labels (one excursion per ray)
    for j in range(8):
        idx = np.flatnonzero(rays.labels == j)
        assert np.all(np.diff(idx) == 1)
    # the first ray commanded is 0 deg, i.e. index 4 of the sorted directions
    first = rays.labels[rays.labels >= 0][0]
    assert rays.directions_deg[first] == pytest.approx(0.0, abs=0.5)


@pytest.mark.parametrize(
    "case",
    ["shifted_neutral", "noise", "start_22_5", "uneven", "order", "all", "amplitude_25"],
)
def test_robust_to_rig_variations(case):
    rng = np.random.default_rng(3)
    directions = EIGHT.copy()
    kwargs = {}
    neutral = (0.0, 0.0)
    if case in ("shifted_neutral", "all"):
        neutral = (3.0, -2.0)
    if case in ("noise", "all"):
        kwargs["noise"] = 0.05
    if case in ("start_22_5", "all"):
        directions = directions + 22.5
    if case in ("uneven", "all"):
        directions = directions + rng.uniform(-5.0, 5.0, size=8)
    commanded = directions.copy()
    if case in ("order", "all"):
        directions = directions[[0, 4, 2, 6, 1, 5, 3, 7]]  # 0, 180, 90, 270, ...
    if case == "amplitude_25":
        kwargs["amplitude"] = 25.0
    q = make_sweep(directions, neutral=neutral, **kwargs)
    rays = find_rays(q, run="R1")
    assert_directions(rays, commanded)
    assert_consistent(rays, q)
    np.testing.assert_allclose(rays.q_neutral, neutral, atol=0.05)
    np.testing.assert_allclose(rays.amplitudes, kwargs.get("amplitude", 60.0), atol=0.3)
    check_sweep_references(fake_reference(q, neutral), rays, run="R1")


def test_shifted_neutral_protocol_sweep():
    q = sweep_trajectory(first_direction_deg=22.5) + np.array([3.0, -2.0])
    rays = find_rays(q)
    assert_directions(rays, EIGHT + 22.5)
    np.testing.assert_allclose(rays.q_neutral, [3.0, -2.0], atol=1e-6)
    assert_consistent(rays, q, atol_deg=0.5)


def test_repeated_excursions_merge_into_one_ray():
    directions = np.r_[EIGHT, 0.0, 90.0]  # rays 0 and 90 swept twice
    q = make_sweep(directions, noise=0.05)
    rays = find_rays(q)
    assert_directions(rays, EIGHT)
    assert_consistent(rays, q)
    rho, _ = rays.polar(q)
    for direction, repeats in ((0.0, 2), (90.0, 2), (45.0, 1)):
        j = int(np.argmin(np.abs(angle_diff_deg(rays.directions_deg, direction))))
        far = (rays.labels == j) & (rho > 30.0)
        starts = np.flatnonzero(np.diff(far.astype(int)) == 1)
        assert starts.size == repeats  # separate excursions, one ray


def test_excursion_without_return_to_neutral_is_split():
    # ray 45 starts from rho = 4 deg on ray 0, without passing through neutral
    n_move, amp = 250, 60.0
    s = min_jerk(n_move)[:, None]
    u0, u45 = np.array([1.0, 0.0]), np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
    halfway = 4.0 * u0
    first = [
        np.zeros((30, 2)),
        amp * u0 * s,
        np.repeat(amp * u0[None], 15, axis=0),
        amp * u0 + (halfway - amp * u0) * s,
        halfway + (amp * u45 - halfway) * s,
        np.repeat(amp * u45[None], 15, axis=0),
        amp * u45 * (1.0 - s),
        np.zeros((25, 2)),
    ]
    q = np.concatenate([*first, make_sweep(EIGHT[2:], rest=0)])
    rays = find_rays(q)
    assert_directions(rays, EIGHT, atol=1.5)
    assert_consistent(rays, q, atol_deg=8.0, min_rho=30.0)
    # the two rays of the first excursion follow each other with no neutral between
    lab = rays.labels[30 + n_move : 30 + 3 * n_move + 15]  # dwell, in to 4 deg, out, dwell
    assert np.all(lab >= 0)
    assert np.unique(lab).size == 2


def test_flicker_around_the_neutral_threshold_is_labelled():
    q = make_sweep(noise=0.3, seed=5)  # noise comparable to the 1.8 deg threshold
    rays = find_rays(q)
    assert_directions(rays, EIGHT)
    assert_consistent(rays, q, atol_deg=3.0)


def test_simulated_runs():
    for seed in (0, 1):
        bunch = simulate_run(random_state=seed, run=f"sim-{seed}", dropout_rate=0.02)
        X = bunch.X[bunch.X["phase"] == "sweep"]
        q = X[["q1", "q2"]].to_numpy()
        rays = find_rays(q, run=f"sim-{seed}")
        assert_directions(rays, EIGHT)
        assert_consistent(rays, q, atol_deg=0.5)
        np.testing.assert_allclose(rays.amplitudes, 60.0, atol=0.5)
        ref = X[["ref_x", "ref_y", "ref_z"]].to_numpy()
        ref_before = ref.copy()
        check_sweep_references(ref, rays, run=f"sim-{seed}")
        np.testing.assert_array_equal(ref, ref_before)


def test_repeated_calls_give_the_same_rays():
    # its speed (at most 5 ms per call on such a sweep) is measured by
    # benchmarks/bench_functions.py, not here: the test machines are noisy
    q = make_sweep(noise=0.05)
    assert 4000 < len(q) < 4500
    first, again = find_rays(q), find_rays(q)
    np.testing.assert_array_equal(first.labels, again.labels)
    np.testing.assert_array_equal(first.directions, again.directions)


# ---------------------------------------------------------------------------
# errors of find_rays
# ---------------------------------------------------------------------------
def test_too_short():
    q = sweep_trajectory()[:50]
    with pytest.raises(ValueError, match=r"sweep of run 'R1' has 50 samples; expected at least 80"):
        find_rays(q, run="R1")
    with pytest.raises(ValueError, match=r"has 50 samples; expected at least 60"):
        find_rays(q, run="R1", min_samples=60)


def test_no_motion():
    q = np.random.default_rng(0).normal(0.0, 0.05, size=(500, 2)) + [2.0, 1.0]
    with pytest.raises(
        ValueError,
        match=r"motors do not move during the sweep of run 'R1'"
        r".*min_amplitude_deg=5",
    ):
        find_rays(q, run="R1")


@pytest.mark.parametrize("column", ["q1", "q2"])
def test_stuck_motor(column):
    q = make_sweep(noise=0.05)
    j = 0 if column == "q1" else 1
    q[:, j] = 0.3 + np.random.default_rng(1).normal(0.0, 0.05, len(q))
    with pytest.raises(
        ValueError,
        match=rf"Motor column '{column}' does not move during the sweep of run 'R1'",
    ):
        find_rays(q, run="R1")


def test_seven_of_eight_rays():
    q = make_sweep(EIGHT[:7], noise=0.05)
    with pytest.raises(
        ValueError,
        match=r"Rays missing in the sweep of run 'R1': found 7 distinct ray\(s\) at directions "
        r"\[[^]]*\b135\.\d, 180\.\d, [^]]*\] deg.*expected n_rays=8",
    ):
        find_rays(q, run="R1")


def test_gap_between_rays():
    directions = [0.0, 30.0, 60.0, 90.0, 135.0, 180.0, 225.0, 270.0]  # 270 -> 360 gap of 90
    q = make_sweep(directions)
    with pytest.raises(
        ValueError,
        match=r"Rays missing in the sweep of run 'R1': a gap of (89\.9|90\.0) deg"
        r" between the rays at 270\.0 and (359\.9|0\.0) deg",
    ):
        find_rays(q, run="R1")


def test_more_rays_than_expected():
    q = make_sweep(np.arange(9) * 40.0)
    with pytest.raises(
        ValueError,
        match=r"Too many rays in the sweep of run 'R1': found 9 .*expected n_rays=8",
    ):
        find_rays(q, run="R1")
    rays = find_rays(q, n_rays=9)
    assert_directions(rays, np.arange(9) * 40.0)


def test_non_finite_motor_angles():
    q = sweep_trajectory()
    q[100, 1] = np.nan
    with pytest.raises(
        ValueError,
        match=r"of run 'R1' contain 1 non-finite value\(s\) in column\(s\) \['q2'\];"
        r" first at sweep sample 100",
    ):
        find_rays(q, run="R1")


def test_bad_shape():
    with pytest.raises(
        ValueError,
        match=r"run 'R1' must have shape \(n, 2\).*got shape \(100,"
        r" 3\)",
    ):
        find_rays(np.zeros((100, 3)), run="R1")


def test_move_along_the_rim_is_refused():
    # from the end of ray 0 straight to the end of ray 90 without coming back
    s = min_jerk(250)[:, None]
    a, b = np.array([60.0, 0.0]), np.array([0.0, 60.0])
    rim = np.concatenate(
        [np.zeros((30, 2)), a * s, a + (b - a) * s, b * (1.0 - s), np.zeros((25, 2))]
    )
    q = np.concatenate([rim, make_sweep(EIGHT[3:], rest=0)])
    with pytest.raises(ValueError, match=r"sweep of run 'R1' changes direction far from neutral"):
        find_rays(q, run="R1")


def test_circles_instead_of_rays_are_refused():
    t = np.linspace(0.0, 4.0 * np.pi, 800)
    q = 60.0 * np.column_stack([np.cos(t), np.sin(t)])  # never at neutral
    with pytest.raises(ValueError, match=r"sweep of run 'R1' changes direction far from neutral"):
        find_rays(q, run="R1")


def test_result_is_read_only():
    rays = find_rays(sweep_trajectory())
    with pytest.raises(ValueError, match="read-only"):
        rays.labels[0] = 3
    with pytest.raises(AttributeError):
        rays.amplitude = 1.0


def test_run_is_optional_in_messages():
    with pytest.raises(ValueError, match=r"^The sweep has 50 samples"):
        find_rays(sweep_trajectory()[:50])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_rays": 1},
        {"n_rays": 8.0},
        {"neutral_fraction": 0.0},
        {"neutral_fraction": 0.5},
        {"min_amplitude_deg": 0.0},
        {"min_samples": 0},
        {"min_samples": 80.0},
    ],
)
def test_bad_arguments_are_rejected_by_name(kwargs):
    (name,) = kwargs
    with pytest.raises(InvalidParameterError, match=rf"'{name}' parameter of find_rays"):
        find_rays(sweep_trajectory(), **kwargs)


# ---------------------------------------------------------------------------
# check_sweep_references
# ---------------------------------------------------------------------------
@pytest.fixture
def sweep():
    q = make_sweep(noise=0.05)
    return q, find_rays(q), fake_reference(q)


def test_references_ok_with_dropouts(sweep):
    q, rays, ref = sweep
    ref = ref.copy()
    ref[np.random.default_rng(0).random(len(ref)) < 0.3] = np.nan
    before = ref.copy()
    assert check_sweep_references(ref, rays, run="R1") is None
    assert_array_equal(ref, before)  # NaN where they were, nothing filled in
    # the dropouts are counted: about 70 % of each ray is left, below a bound of 80 %
    with pytest.raises(ValueError, match=r"Too few finite reference tip positions in run 'R1'"):
        check_sweep_references(ref, rays, run="R1", min_fraction=0.8)


def test_references_missing_on_a_whole_ray(sweep):
    q, rays, ref = sweep
    ref = ref.copy()
    ref[rays.labels == 3] = np.nan
    deg = rays.directions_deg[3] % 360.0
    with pytest.raises(
        ValueError,
        match=rf"Too few finite reference tip positions in run 'R1' on 1 ray\(s\)"
        rf".*ray 3 at {deg:.1f} deg: 0 of",
    ):
        check_sweep_references(ref, rays, run="R1")


def test_references_missing_on_most_of_a_ray(sweep):
    q, rays, ref = sweep
    ref = ref.copy()
    idx = np.flatnonzero(rays.labels == 5)
    ref[idx[: int(0.6 * idx.size)], 1] = np.nan  # one coordinate is enough
    with pytest.raises(ValueError, match=r"run 'R1'.*ray 5 at .* \(40 %\)"):
        check_sweep_references(ref, rays, run="R1")
    check_sweep_references(ref, rays, run="R1", min_fraction=0.3)


def test_references_missing_at_neutral(sweep):
    q, rays, ref = sweep
    ref = ref.copy()
    ref[rays.neutral] = np.nan
    with pytest.raises(
        ValueError,
        match=r"No neutral sample of the sweep of run 'R1' has a finite"
        r" reference",
    ):
        check_sweep_references(ref, rays, run="R1")


def test_references_constant(sweep):
    q, rays, ref = sweep
    ref = np.tile([1.0, 2.0, 60.0], (len(q), 1))
    with pytest.raises(
        ValueError,
        match=r"reference tip positions in run 'R1' do not move during the"
        r" sweep",
    ):
        check_sweep_references(ref, rays, run="R1")


def test_references_bad_shape(sweep):
    q, rays, ref = sweep
    with pytest.raises(
        ValueError,
        match=rf"of run 'R1' must have shape \({len(q)}, 3\)"
        rf".*got shape \({len(q) - 1}, 3\)",
    ):
        check_sweep_references(ref[1:], rays, run="R1")
    with pytest.raises(TypeError, match="SweepRays"):
        check_sweep_references(ref, None, run="R1")


# ---------------------------------------------------------------------------
# property test
# ---------------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(
    start=st.floats(0.0, 360.0, exclude_max=True),
    amplitude=st.floats(20.0, 80.0),
    noise=st.sampled_from([0.0, 0.02, 0.05, 0.1, 0.2]),
    order=st.permutations(range(8)),
    jitter=st.lists(st.floats(-5.0, 5.0), min_size=8, max_size=8),
    neutral=st.tuples(st.floats(-5.0, 5.0), st.floats(-5.0, 5.0)),
    seed=st.integers(0, 2**16),
)
def test_property_directions_found(start, amplitude, noise, order, jitter, neutral, seed):
    commanded = start + EIGHT + np.asarray(jitter)
    q = make_sweep(
        commanded[list(order)],
        amplitude=amplitude,
        neutral=neutral,
        noise=noise,
        n_move=int(round(amplitude / 2.4 * 10)),
        seed=seed,
    )
    rays = find_rays(q, run="P")
    assert_directions(rays, commanded)
    assert_consistent(rays, q, atol_deg=2.0 + 40.0 * noise)
    np.testing.assert_allclose(rays.amplitudes, amplitude, atol=0.2 + 5 * noise)


@pytest.mark.parametrize("min_fraction", [-0.1, 1.5, "half"])
def test_references_bad_min_fraction(sweep, min_fraction):
    q, rays, ref = sweep
    with pytest.raises(InvalidParameterError, match="'min_fraction' parameter"):
        check_sweep_references(ref, rays, min_fraction=min_fraction)
