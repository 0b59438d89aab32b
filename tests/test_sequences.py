"""Tests of skcath.sequences: long format <-> padded per-run arrays."""

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skcath.sequences import PaddedRuns, from_padded, to_padded

FEATURES = ["q1", "q2", "tau1"]


def make_recordings(lengths=((3, 4), (2, 5), (4, 1)), seed=0):
    """Valid long-format recordings, runs ``r0, r1, ...`` stored one after another.

    ``lengths`` holds ``(n_sweep, n_motion)`` per run. Row labels start at 100.
    """
    rng = np.random.default_rng(seed)
    frames = []
    for k, (n_sweep, n_motion) in enumerate(lengths):
        n = n_sweep + n_motion
        sweep = np.arange(n) < n_sweep
        ref = rng.normal(size=(n, 3))
        ref[~sweep] = np.nan
        frames.append(
            pd.DataFrame(
                {
                    "catheter": f"c{k % 2}",
                    "setting": f"s{k}",
                    "run": f"r{k}",
                    "t": 0.01 * np.arange(n),
                    "phase": np.where(sweep, "sweep", "motion"),
                    "q1": rng.normal(size=n),
                    "q2": rng.normal(size=n),
                    "tau1": rng.normal(size=n),
                    "tau2": rng.normal(size=n),
                    "ref_x": ref[:, 0],
                    "ref_y": ref[:, 1],
                    "ref_z": ref[:, 2],
                }
            )
        )
    X = pd.concat(frames, ignore_index=True)
    X.index = pd.RangeIndex(100, 100 + len(X))
    y = rng.normal(size=(len(X), 3))
    return X, y


def interleave(X, y, seed):
    """Randomly interleave the runs of ``X`` while keeping each run's row order."""
    rng = np.random.default_rng(seed)
    slots = rng.permutation(X["run"].to_numpy())  # run of every output row
    # the k-th slot of a run receives the k-th row of that run
    source = np.empty(len(X), dtype=np.intp)
    for run in pd.unique(slots):
        source[np.flatnonzero(slots == run)] = np.flatnonzero(X["run"].to_numpy() == run)
    return X.iloc[source], y[source]


def selected_mask(X, phase):
    if phase is None:
        return np.ones(len(X), dtype=bool)
    return (X["phase"] == phase).to_numpy()


# ---------------------------------------------------------------------------
# structure
# ---------------------------------------------------------------------------
def test_shapes_mask_and_padding():
    X, y = make_recordings()
    padded = to_padded(X, FEATURES, y=y)
    assert isinstance(padded, PaddedRuns)
    assert padded.values.shape == (3, 7, 3) and padded.values.dtype == np.float32
    assert padded.target.shape == (3, 7, 3) and padded.target.dtype == np.float32
    np.testing.assert_array_equal(padded.lengths, [7, 7, 5])
    assert list(padded.runs) == ["r0", "r1", "r2"]
    assert padded.columns == tuple(FEATURES)
    assert padded.n_rows == len(X) and padded.n_runs == 3 and padded.max_length == 7
    assert padded.positions.dtype == np.int64 and padded.mask.dtype == bool
    np.testing.assert_array_equal(padded.mask.sum(axis=1), padded.lengths)
    np.testing.assert_array_equal(padded.mask, padded.positions >= 0)
    assert (padded.values[~padded.mask] == 0).all()
    assert (padded.target[~padded.mask] == 0).all()
    np.testing.assert_array_equal(padded.target_mask, padded.mask)
    # real steps are a prefix of each padded row
    for k, length in enumerate(padded.lengths):
        assert padded.mask[k, :length].all() and not padded.mask[k, length:].any()
    assert "n_runs=3" in repr(padded)


def test_values_follow_rows_of_x():
    X, _ = make_recordings()
    padded = to_padded(X, FEATURES, dtype=np.float64)
    expected = X[FEATURES].to_numpy()
    np.testing.assert_array_equal(
        padded.values[padded.mask], expected[padded.positions[padded.mask]]
    )


@pytest.mark.parametrize("phase", [None, "sweep", "motion"])
def test_runs_are_never_mixed_and_steps_are_in_time_order(phase):
    X, y = make_recordings()
    X, y = interleave(X, y, seed=3)
    padded = to_padded(X, FEATURES, y=y, phase=phase)
    runs = X["run"].to_numpy()
    times = X["t"].to_numpy()
    phases = X["phase"].to_numpy()
    for k in range(padded.n_runs):
        rows = padded.positions[k, padded.mask[k]]
        assert (runs[rows] == padded.runs[k]).all()
        assert (np.diff(rows) > 0).all() and (np.diff(times[rows]) > 0).all()
        if phase is not None:
            assert (phases[rows] == phase).all()
    # every selected row appears exactly once
    covered = np.sort(padded.positions[padded.mask])
    np.testing.assert_array_equal(covered, np.flatnonzero(selected_mask(X, phase)))


@pytest.mark.parametrize("phase", [None, "sweep", "motion"])
def test_round_trip(phase):
    X, y = make_recordings()
    X, y = interleave(X, y, seed=1)
    padded = to_padded(X, FEATURES, phase=phase, dtype=np.float64)
    back = from_padded(padded.values, padded)
    selected = selected_mask(X, phase)
    assert back.shape == (len(X), len(FEATURES)) and back.dtype == np.float64
    np.testing.assert_array_equal(back[selected], X[FEATURES].to_numpy()[selected])
    assert np.isnan(back[~selected]).all()


def test_from_padded_ignores_padding_and_keeps_trailing_shape():
    X, _ = make_recordings()
    padded = to_padded(X, FEATURES)
    garbage = np.where(padded.mask, 1.0, 999.0)  # (n_runs, T_max)
    back = from_padded(garbage, padded)
    assert back.shape == (len(X),)
    np.testing.assert_array_equal(back, 1.0)


def test_nan_targets_are_masked_and_zeroed():
    X, y = make_recordings()
    y[[1, 8]] = np.nan
    y[12, 2] = np.nan  # one coordinate missing is a dropout too
    padded = to_padded(X, FEATURES, y=y)
    assert np.isfinite(padded.target).all()
    dropped = np.zeros(len(X), dtype=bool)
    dropped[[1, 8, 12]] = True
    rows = padded.positions[padded.mask]
    np.testing.assert_array_equal(padded.target_mask[padded.mask], ~dropped[rows])
    assert not (padded.target_mask & ~padded.mask).any()
    assert (padded.target[~padded.target_mask] == 0).all()
    ok = padded.target_mask
    np.testing.assert_allclose(
        padded.target[ok], y[padded.positions[ok]].astype(np.float32), rtol=1e-6
    )


def test_target_dataframe_is_accepted_and_not_modified():
    X, y = make_recordings()
    y_frame = pd.DataFrame(y, columns=["p_x", "p_y", "p_z"])
    before = y_frame.copy()
    X_before = X.copy()
    padded = to_padded(X, FEATURES, y=y_frame, phase="motion")
    pd.testing.assert_frame_equal(y_frame, before)
    pd.testing.assert_frame_equal(X, X_before)
    assert padded.target.shape == (3, 5, 3)


def test_run_without_selected_rows_is_kept_with_length_zero():
    X, _ = make_recordings(lengths=((3, 4), (2, 0), (4, 1)))
    padded = to_padded(X, FEATURES, phase="motion")
    assert list(padded.runs) == ["r0", "r1", "r2"]
    np.testing.assert_array_equal(padded.lengths, [4, 0, 1])
    assert not padded.mask[1].any()
    assert (padded.positions[1] == -1).all()


def test_no_selected_rows_at_all():
    X, _ = make_recordings(lengths=((3, 0), (2, 0)))
    padded = to_padded(X, FEATURES, phase="motion")
    assert padded.values.shape == (2, 0, 3)
    back = from_padded(padded.values, padded)
    assert back.shape == (len(X), 3) and np.isnan(back).all()


def test_single_column_name_and_integer_columns():
    X, _ = make_recordings()
    X["q1"] = np.arange(len(X))
    padded = to_padded(X, "q1", dtype=np.float64)
    assert padded.columns == ("q1",) and padded.values.shape[-1] == 1
    np.testing.assert_array_equal(from_padded(padded.values, padded)[:, 0], np.arange(len(X)))


# ---------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------
def test_unknown_column():
    X, _ = make_recordings()
    with pytest.raises(ValueError, match=r"missing the column\(s\) \['nope'\]"):
        to_padded(X, ["q1", "nope"])


def test_non_numeric_column():
    X, _ = make_recordings()
    with pytest.raises(ValueError, match=r"'catheter' must be numeric.*run 'r0'"):
        to_padded(X, ["catheter"])


@pytest.mark.parametrize("phase", ["Sweep", "calibration", 1])
def test_bad_phase(phase):
    X, _ = make_recordings()
    with pytest.raises(ValueError, match=r"phase must be None or one of \['sweep', 'motion'\]"):
        to_padded(X, FEATURES, phase=phase)


def test_not_a_dataframe():
    X, _ = make_recordings()
    with pytest.raises(TypeError, match="DataFrame"):
        to_padded(X[FEATURES].to_numpy(), FEATURES)


def test_non_float_dtype():
    X, _ = make_recordings()
    with pytest.raises(ValueError, match="floating dtype"):
        to_padded(X, FEATURES, dtype=np.int32)


def test_time_out_of_order_is_rejected():
    X, _ = make_recordings()
    X = X.iloc[[1, 0, *range(2, len(X))]]
    with pytest.raises(ValueError, match=r"run 'r0'"):
        to_padded(X, FEATURES)


def test_target_length_mismatch():
    X, y = make_recordings()
    with pytest.raises(ValueError, match="y has"):
        to_padded(X, FEATURES, y=y[:-2])


def test_from_padded_wrong_shape_names_expected_and_got():
    X, _ = make_recordings()
    padded = to_padded(X, FEATURES)
    with pytest.raises(ValueError, match=r"\(3, 7, \.\.\.\).*got shape \(3, 6, 2\)"):
        from_padded(np.zeros((3, 6, 2)), padded)
    with pytest.raises(ValueError, match=r"got shape \(3,\)"):
        from_padded(np.zeros(3), padded)


def test_from_padded_rejects_tensors_and_foreign_objects():
    X, _ = make_recordings()
    padded = to_padded(X, FEATURES)

    class FakeTensor:
        def detach(self):
            return self

    with pytest.raises(TypeError, match=r"detach\(\)\.cpu\(\)\.numpy\(\)"):
        from_padded(FakeTensor(), padded)
    with pytest.raises(TypeError, match="PaddedRuns"):
        from_padded(padded.values, {"positions": padded.positions})
    with pytest.raises(ValueError, match="real numbers"):
        from_padded(np.full(padded.positions.shape, "a"), padded)


# ---------------------------------------------------------------------------
# property: interleaving never changes the per-run result
# ---------------------------------------------------------------------------
run_lengths = st.lists(
    st.tuples(st.integers(1, 4), st.integers(0, 6)), min_size=1, max_size=5
)


@settings(max_examples=60, deadline=None)
@given(
    lengths=run_lengths,
    seed=st.integers(0, 2**32 - 1),
    phase=st.sampled_from([None, "sweep", "motion"]),
)
def test_interleaving_does_not_change_runs(lengths, seed, phase):
    X, y = make_recordings(lengths, seed=seed % 1000)
    y[np.random.default_rng(seed).random(len(X)) < 0.2] = np.nan
    X_mixed, y_mixed = interleave(X, y, seed)

    ref = to_padded(X, FEATURES, y=y, phase=phase)
    mixed = to_padded(X_mixed, FEATURES, y=y_mixed, phase=phase)

    # runs are ordered by first appearance, so match them by id
    index = {run: k for k, run in enumerate(mixed.runs)}
    assert sorted(index) == sorted(ref.runs)
    perm = [index[run] for run in ref.runs]
    np.testing.assert_array_equal(mixed.lengths[perm], ref.lengths)
    np.testing.assert_array_equal(mixed.mask[perm], ref.mask)
    np.testing.assert_array_equal(mixed.values[perm], ref.values)
    np.testing.assert_array_equal(mixed.target[perm], ref.target)
    np.testing.assert_array_equal(mixed.target_mask[perm], ref.target_mask)
    # positions point to the same rows (by label) in both frames
    for k_ref, k_mixed in enumerate(perm):
        labels_ref = X.index[ref.positions[k_ref, ref.mask[k_ref]]]
        labels_mixed = X_mixed.index[mixed.positions[k_mixed, mixed.mask[k_mixed]]]
        assert labels_ref.equals(labels_mixed)

    # round trip in each frame's own row order
    selected = selected_mask(X_mixed, phase)
    back = from_padded(mixed.values, mixed)
    np.testing.assert_array_equal(
        back[selected], X_mixed[FEATURES].to_numpy(dtype=np.float32)[selected]
    )
    assert np.isnan(back[~selected]).all()
