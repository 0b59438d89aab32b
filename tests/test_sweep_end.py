"""Finding where the sweep ends from the motor angles (skcath.sweep.find_sweep_end)."""

import numpy as np
import pandas as pd
import pytest

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.datasets._protocol import random_walk_trajectory, sweep_trajectory
from skcath.io import read_recording, read_recordings
from skcath.sweep import SweepEnd, find_sweep_end

_TARGET = ["p_x", "p_y", "p_z"]


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    return tmp_path_factory.mktemp("skcath_data")


@pytest.fixture(scope="module")
def bench(home):
    return make_benchmark(n_catheters=1, n_runs=1, data_home=home)


def _runs(X, k=4):
    """The first ``k`` runs of ``X``: (run id, its rows, true sweep length)."""
    out = []
    for run in pd.unique(X["run"])[:k]:
        rows = X[X["run"] == run]
        out.append((run, rows, int((rows["phase"] == "sweep").sum())))
    return out


def _export(rows, y, path, phase=False):
    """Write one run as a rig exports it: channels and tracked tip, no ids or references."""
    keep = ["t", *(["phase"] if phase else []), *[c for c in rows.columns if c[0] in "q" or
                                                  c.startswith("tau")]]
    table = rows[keep].copy()
    table[_TARGET] = y
    table.to_csv(path, index=False)
    return path


@pytest.mark.parametrize(
    ("n_motors", "rate_hz", "n_rays"),
    [(2, 10.0, 8), (2, 40.0, 8), (1, 10.0, 2), (3, 10.0, 6)],
)
def test_detected_end_within_a_second(home, n_motors, rate_hz, n_rays):
    data = make_benchmark(n_catheters=1, n_runs=1, n_motors=n_motors, rate_hz=rate_hz,
                          data_home=home)
    for run, rows, true in _runs(data.X):
        end = find_sweep_end(rows.drop(columns="phase"))
        assert isinstance(end, SweepEnd)
        assert abs(end.n_sweep - true) / rate_hz <= 1.0, run
        assert end.n_rays == n_rays
        assert end.directions.shape == (n_rays, n_motors)
        assert np.allclose(np.linalg.norm(end.directions, axis=1), 1.0)
        assert np.all(np.abs(end.amplitudes - end.amplitude) < 0.2 * end.amplitude)
        assert end.time_s == pytest.approx(rows["t"].iloc[end.n_sweep - 1])
        # the rays lie in the sweep, one after the other
        assert np.all(np.diff(end.bounds.ravel()) > 0) and end.bounds[-1, 1] <= end.n_sweep


def test_directions_of_a_two_motor_sweep(bench):
    run, rows, _ = _runs(bench.X, 1)[0]
    end = find_sweep_end(rows[["q1", "q2"]].to_numpy(), rate_hz=10.0, run=run)
    # the benchmark sweeps 0, 45, ..., 315 degrees in that order
    expected = (np.arange(8) * 45.0 + 180.0) % 360.0 - 180.0
    assert np.allclose(end.directions_deg, expected, atol=1.0)
    assert np.allclose(end.amplitudes, 60.0, atol=1.0)
    assert np.allclose(end.q_neutral, 0.0, atol=0.05)
    assert "excursion" in end.ended_by


def test_noisy_sweep_off_neutral_at_any_rate():
    rng = np.random.default_rng(0)
    for rate in (7.0, 25.0):
        sweep = sweep_trajectory(rate_hz=rate, first_direction_deg=20.0, n_rays=6)
        walk = random_walk_trajectory(rng, 100, n_steps=20) * 0.8  # one sample per step's tenth
        walk = np.repeat(walk, int(rate // 4) + 1, axis=0)
        q = np.concatenate([sweep, walk]) + np.array([12.0, -7.0])
        q = q + rng.normal(0.0, 0.05, size=q.shape)
        end = find_sweep_end(q, rate_hz=rate)
        assert abs(end.n_sweep - len(sweep)) <= rate  # within a second
        assert end.n_rays == 6
        assert np.allclose(end.q_neutral, [12.0, -7.0], atol=0.1)
        assert np.allclose(np.sort(end.directions_deg % 360.0), 20.0 + 60.0 * np.arange(6),
                           atol=2.0)


def test_whole_recording_a_sweep():
    q = sweep_trajectory()
    end = find_sweep_end(q, rate_hz=10.0)
    assert end.n_sweep == len(q)
    assert end.ended_by == "the end of the recording"


def test_start_not_a_sweep_raises(bench):
    run, rows, true = _runs(bench.X, 1)[0]
    motion = rows.iloc[true:]
    with pytest.raises(ValueError, match=rf"The start of run '{run}' is not a calibration "
                                         r"sweep: the excursion of samples \d+-\d+"):
        find_sweep_end(motion)
    # one ray, then the motion: fewer rays than min_rays
    one_ray = pd.concat([rows.iloc[: 30 + 2 * 250 + 25], motion])
    with pytest.raises(ValueError, match=r"found 1 ray\(s\) before the excursion"):
        find_sweep_end(one_ray.assign(t=np.arange(len(one_ray)) / 10.0))


def test_start_not_a_sweep_names_the_file(bench, tmp_path):
    run, rows, true = _runs(bench.X, 1)[0]
    y = bench.y[(bench.X["run"] == run).to_numpy()]
    path = _export(rows.iloc[true:], y[true:], tmp_path / "walk_only.csv")
    with pytest.raises(ValueError, match=r"walk_only\.csv: n_sweep='auto': The start of run "
                                         r"'walk_only' is not a calibration sweep"):
        read_recording(path, n_sweep="auto", catheter="A", setting="s")


def test_bad_arguments(bench):
    run, rows, _ = _runs(bench.X, 1)[0]
    q = rows[["q1", "q2"]].to_numpy()
    with pytest.raises(ValueError, match="exactly one of them"):
        find_sweep_end(q)
    with pytest.raises(ValueError, match="got both"):
        find_sweep_end(q, rows["t"], rate_hz=10.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        find_sweep_end(q, rows["t"].to_numpy()[::-1])
    with pytest.raises(ValueError, match=r"holds 2 runs"):
        find_sweep_end(bench.X[bench.X["run"].isin(pd.unique(bench.X["run"])[:2])])
    with pytest.raises(ValueError, match="motors do not move"):
        find_sweep_end(np.zeros((100, 2)), rate_hz=10.0)
    before = q.copy()
    find_sweep_end(q, rate_hz=10.0)
    assert np.array_equal(q, before)


def test_read_recording_auto_equals_phase_column(bench, tmp_path):
    for run, rows, true in _runs(bench.X, 3):
        y = bench.y[(bench.X["run"] == run).to_numpy()]
        marked = _export(rows, y, tmp_path / "marked.csv", phase=True)
        plain = _export(rows, y, tmp_path / "plain.csv")
        X_phase, y_phase = read_recording(marked, catheter="A", setting="s", run="r")
        X_auto, y_auto = read_recording(plain, n_sweep="auto", catheter="A", setting="s",
                                        run="r")
        assert find_sweep_end(rows.drop(columns="phase")).n_sweep == true, run
        pd.testing.assert_frame_equal(X_auto, X_phase)
        assert np.array_equal(y_auto, y_phase, equal_nan=True)
        assert "n_sweep" not in X_auto.attrs


def test_read_recordings_manifest_mixes_auto_and_numbers(bench, tmp_path):
    paths, truths = [], []
    for k, (run, rows, true) in enumerate(_runs(bench.X, 2)):
        y = bench.y[(bench.X["run"] == run).to_numpy()]
        paths.append(str(_export(rows, y, tmp_path / f"r{k}.csv")))
        truths.append(true)
    manifest = tmp_path / "manifest.csv"
    pd.DataFrame({"path": paths, "n_sweep": ["auto", str(truths[1])]}).to_csv(manifest,
                                                                              index=False)
    X, _ = read_recordings(manifest=manifest, catheter="A", setting="s", progress=False)
    sizes = X[X["phase"] == "sweep"].groupby("run", sort=False).size()
    assert sizes.tolist() == truths
    assert X.attrs["n_sweep"] == {"r1": truths[1]}  # only the number given


@pytest.mark.parametrize("n_sweep", [3000, 5000])
def test_wrong_n_sweep_names_it_and_the_detected_end(bench, tmp_path, n_sweep):
    run, rows, true = _runs(bench.X, 1)[0]
    y = bench.y[(bench.X["run"] == run).to_numpy()]
    path = _export(rows, y, tmp_path / "rig.csv")
    X, y = read_recording(path, n_sweep=n_sweep, catheter="A", setting="s")
    assert X.attrs["n_sweep"] == {"rig": n_sweep}
    with pytest.raises(ValueError) as info:
        PDLBackbone().fit(X, y).predict(X)
    message = str(info.value)
    assert f"read with n_sweep={n_sweep}" in message
    assert f"ends after {true} samples" in message
    assert f"n_sweep={true}" in message
    assert "KFold" not in message  # the hint about cut runs does not apply


def test_wrong_n_sweep_of_a_sweep_alone_says_where_to_find_the_end(bench, tmp_path):
    # Only the rows read as the sweep reach OnlineEstimator.start: they cannot
    # tell where the sweep really ends, so no end is proposed from them.
    from sklearn.pipeline import Pipeline

    from skcath.online import OnlineEstimator

    run, rows, true = _runs(bench.X, 1)[0]
    y = bench.y[(bench.X["run"] == run).to_numpy()]
    X, y = read_recording(_export(rows, y, tmp_path / "rig.csv"), n_sweep=3000,
                          catheter="A", setting="s")
    pipe = Pipeline([("backbone", PDLBackbone())]).fit(X, y)
    with pytest.raises(ValueError) as info:
        OnlineEstimator(pipe).start(X[X["phase"] == "sweep"])
    message = str(info.value)
    assert "read with n_sweep=3000" in message and "only those rows are here" in message
    assert "n_sweep='auto'" in message and "ends after" not in message
    assert "KFold" not in message


def test_wrong_n_sweep_of_a_resweep_names_it(bench, tmp_path):
    # A motor-only re-sweep read with a wrong n_sweep: the error of its rays names
    # n_sweep as start's does, not a cut run, and the estimator stays as it was.
    from sklearn.pipeline import Pipeline

    from skcath.online import OnlineEstimator

    run, rows, true = _runs(bench.X, 1)[0]
    path = _export(rows, bench.y[(bench.X["run"] == run).to_numpy()], tmp_path / "rig.csv")
    X, y = read_recording(path, n_sweep=true, catheter="A", setting="s")
    est = OnlineEstimator(Pipeline([("backbone", PDLBackbone())]).fit(X, y))
    est.start(X[X["phase"] == "sweep"])
    q_neutral = est.q_neutral_.copy()
    cut, _ = read_recording(path, n_sweep=true - 600, catheter="A", setting="s")
    with pytest.raises(ValueError, match=r"expected n_rays=8 .*The run was read with "
                       rf"n_sweep={true - 600} \(its first {true - 600} samples are the sweep\), "
                       r"and only those rows are here") as info:
        est.resweep(cut[cut["phase"] == "sweep"].drop(columns=["ref_x", "ref_y", "ref_z"]))
    assert "n_sweep='auto'" in str(info.value) and "KFold" not in str(info.value)
    np.testing.assert_array_equal(est.q_neutral_, q_neutral)


def test_other_sweep_errors_keep_their_message(bench, tmp_path):
    run, rows, true = _runs(bench.X, 1)[0]
    y = bench.y[(bench.X["run"] == run).to_numpy()].copy()
    y[: true // 2] = np.nan  # the tracker lost the first rays: not an n_sweep problem
    path = _export(rows, y, tmp_path / "lost.csv")
    X, y = read_recording(path, n_sweep=true, catheter="A", setting="s")
    with pytest.raises(ValueError, match="Too few finite reference tip positions") as info:
        PDLBackbone().fit(X, y).predict(X)
    assert "n_sweep" not in str(info.value)


def test_too_few_samples_and_non_finite_angles():
    with pytest.raises(ValueError, match="have 2 sample"):
        find_sweep_end(np.zeros((2, 2)), rate_hz=10.0)
    q = sweep_trajectory()
    q[5, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite values, first at sample 5"):
        find_sweep_end(q, rate_hz=10.0, run="r")


def test_a_circle_around_neutral_is_not_a_ray():
    # out along psi = 0, around neutral on a circle of 60 deg, back: not a ray
    t = np.linspace(0.0, 2.0 * np.pi, 400)
    out = np.column_stack([np.linspace(0.0, 60.0, 100), np.zeros(100)])
    circle = 60.0 * np.column_stack([np.cos(t), np.sin(t)])
    q = np.concatenate([np.zeros((30, 2)), out, circle, out[::-1], np.zeros((30, 2))])
    with pytest.raises(ValueError, match=r"is not a calibration sweep: .* which turns by"):
        find_sweep_end(q, rate_hz=10.0)
