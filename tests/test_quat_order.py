"""The quaternion order checked against the data (skcath.frames.fit_quat_order, the readers)."""

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from skcath.frames import MIN_SPREAD_RATIO, fit_quat_order, neutral_rows, tip_in_base_frame
from skcath.io import read_recordings

N_NEUTRAL, N_SWEEP, N_MOTION = 8, 30, 20
BASE_COLUMNS = ["b0", "b1", "b2", "b3"]


def _run_frame(rng, catheter, setting, run, base_turn, direction):
    """One run: sweep (neutral first, then q1 and q2 out), motion; raw sensor poses.

    The tip in the base frame is ``direction`` (scaled to 60 mm, with 0.3 mm
    noise) at neutral and moves with the motors elsewhere; the base sensor has
    the orientation ``base_turn`` (with 0.05 degree jitter) and a random position.
    """
    n = N_SWEEP + N_MOTION
    q = np.zeros((n, 2))
    q[N_NEUTRAL:N_SWEEP, 0] = np.linspace(5, 40, N_SWEEP - N_NEUTRAL)
    q[N_NEUTRAL:N_SWEEP, 1] = np.linspace(-30, 30, N_SWEEP - N_NEUTRAL)
    q[N_SWEEP:] = rng.uniform(-40, 40, size=(N_MOTION, 2))
    p_b = 60.0 * direction + rng.normal(scale=0.3, size=(n, 3))
    p_b += np.c_[q[:, 0], -q[:, 1], 0.1 * q[:, 0]] * 0.5
    jitter = Rotation.from_rotvec(rng.normal(scale=np.deg2rad(0.05), size=(n, 3)))
    r_wb = base_turn * jitter
    p_wb = rng.uniform(-100, 100, size=3) + rng.normal(scale=0.1, size=(n, 3))
    p_wt = p_wb + r_wb.apply(p_b)
    frame = pd.DataFrame({
        "catheter": catheter, "setting": setting, "run": run, "t": np.arange(n) * 0.1,
        "phase": ["sweep"] * N_SWEEP + ["motion"] * N_MOTION, "q1": q[:, 0], "q2": q[:, 1],
        "tau1": 0.01 * q[:, 0], "tau2": 0.01 * q[:, 1],
    })
    for j, axis in enumerate("xyz"):
        frame[f"tip_p{axis}"] = p_wt[:, j]
        frame[f"base_p{axis}"] = p_wb[:, j]
    quats = r_wb.as_quat()[:, [3, 0, 1, 2]]  # w, x, y, z
    return frame, quats


def _write_runs(tmp_path, layout, *, n_catheters=2, n_runs=4, turn=True, seed=0):
    """Write runs to CSV with the base quaternion in ``layout`` in the columns b0 .. b3."""
    rng = np.random.default_rng(seed)
    still = Rotation.random(random_state=seed)
    for c in range(n_catheters):
        direction = np.array([0.2 * c, 0.1, 1.0]) / np.linalg.norm([0.2 * c, 0.1, 1.0])
        for r in range(n_runs):
            base_turn = Rotation.random(random_state=rng.integers(1 << 30)) if turn else still
            frame, quats = _run_frame(rng, f"C{c}", f"S{r}", f"C{c}-S{r}", base_turn, direction)
            for j, component in enumerate(layout):
                frame[BASE_COLUMNS[j]] = quats[:, "wxyz".index(component)]
            frame.to_csv(tmp_path / f"C{c}-S{r}.csv", index=False)
    return tmp_path


def _read(folder, quat_order, **kwargs):
    return read_recordings(
        folder, progress=False, columns={"base_orientation": BASE_COLUMNS},
        quat_order=quat_order, **kwargs,
    )


@pytest.mark.parametrize("layout", ["wxyz", "xyzw"])
def test_right_order_is_not_flagged(tmp_path, layout):
    X, y = _read(_write_runs(tmp_path, layout), layout)
    assert len(X) == 2 * 4 * (N_SWEEP + N_MOTION)
    # the targets are the tip in the base frame: 60 mm from the base at neutral
    neutral = neutral_rows(X)
    assert neutral.sum() == 2 * 4 * N_NEUTRAL
    assert np.abs(np.linalg.norm(y[neutral], axis=1) - 60.0).max() < 2.0
    # the check changes nothing in what is read
    X_unchecked, y_unchecked = _read(tmp_path, layout, quat_check=False)
    pd.testing.assert_frame_equal(X, X_unchecked)
    np.testing.assert_array_equal(y, y_unchecked)


@pytest.mark.parametrize(("layout", "declared"), [("xyzw", "wxyz"), ("wxyz", "xyzw")])
def test_wrong_order_raises_naming_the_order_that_fits(tmp_path, layout, declared):
    folder = _write_runs(tmp_path, layout)
    with pytest.raises(ValueError) as info:
        _read(folder, declared)
    message = str(info.value)
    assert f"quat_order={declared!r}" in message
    assert f"pass quat_order={layout!r}" in message
    assert "['b0', 'b1', 'b2', 'b3']" in message
    assert "quat_check=False" in message


def test_wrong_order_read_by_name_names_the_mapping(tmp_path):
    # the file's base_qw .. base_qz columns hold x, y, z, w
    folder = _write_runs(tmp_path, "xyzw")
    for path in folder.glob("*.csv"):
        frame = pd.read_csv(path)
        frame.rename(columns=dict(zip(BASE_COLUMNS, ["base_qw", "base_qx", "base_qy", "base_qz"])))\
            .to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"base_qw.*hold x, y, z, w.*quat_order='xyzw'"):
        read_recordings(folder, progress=False)


def test_opt_out_reads_the_wrong_order(tmp_path):
    folder = _write_runs(tmp_path, "xyzw")
    X, y = _read(folder, "wxyz", quat_check=False)
    X_right, y_right = _read(folder, "xyzw")
    pd.testing.assert_frame_equal(X.drop(columns=["ref_x", "ref_y", "ref_z"]),
                                  X_right.drop(columns=["ref_x", "ref_y", "ref_z"]))
    assert np.abs(y - y_right).max() > 10.0  # the wrong reading, as asked


@pytest.mark.parametrize("case", ["one run per catheter", "base does not turn"])
def test_cannot_tell_passes(tmp_path, case):
    kwargs = {"n_runs": 1} if case == "one run per catheter" else {"turn": False}
    folder = _write_runs(tmp_path, "xyzw", **kwargs)
    X, y = _read(folder, "wxyz")  # wrong, but the data cannot tell
    assert len(X) > 0


def test_fit_reports_spreads_ratio_and_catheters(tmp_path):
    folder = _write_runs(tmp_path, "wxyz", n_catheters=3)
    X, _ = _read(folder, "wxyz")
    raw = pd.concat([pd.read_csv(p) for p in sorted(folder.glob("*.csv"))], ignore_index=True)
    raw = raw.set_index("run").loc[X["run"].unique()].reset_index()  # X's row order
    tip = raw[["tip_px", "tip_py", "tip_pz"]]
    base = raw[["base_px", "base_py", "base_pz"]]
    fit = fit_quat_order(X, tip, base, raw[BASE_COLUMNS])
    assert fit.fitting == "wxyz"
    assert fit.n_runs == 12
    assert fit.spread["wxyz"] < 1.0  # degrees: the 0.3 mm noise at 60 mm
    assert fit.spread["xyzw"] > MIN_SPREAD_RATIO * fit.spread["wxyz"]
    assert fit.ratio == pytest.approx(fit.spread["xyzw"] / fit.spread["wxyz"])
    assert list(fit.catheters["catheter"]) == ["C0", "C1", "C2"]
    assert (fit.catheters["n_runs"] == 4).all()
    # the spread is the angle of the neutral tip directions, read in each order
    p = tip_in_base_frame(tip, base, raw[BASE_COLUMNS], quat_order="wxyz")
    assert np.abs(np.linalg.norm(p[neutral_rows(X)], axis=1) - 60.0).max() < 2.0
    # the inputs are not modified
    pd.testing.assert_frame_equal(X, _read(folder, "wxyz")[0])


def test_fit_cannot_tell_without_a_turning_base(tmp_path):
    folder = _write_runs(tmp_path, "wxyz", turn=False)
    X, _ = _read(folder, "wxyz")
    raw = pd.concat([pd.read_csv(p) for p in sorted(folder.glob("*.csv"))], ignore_index=True)
    fit = fit_quat_order(X, raw[["tip_px", "tip_py", "tip_pz"]],
                         raw[["base_px", "base_py", "base_pz"]], raw[BASE_COLUMNS])
    assert fit.fitting is None
    assert fit.ratio < MIN_SPREAD_RATIO


def test_fit_bad_shapes_name_the_argument(tmp_path):
    X, _ = _read(_write_runs(tmp_path, "wxyz", n_catheters=1, n_runs=2), "wxyz")
    good = np.zeros((len(X), 3))
    with pytest.raises(ValueError, match=r"base_orientation must have shape \(100, 4\)"):
        fit_quat_order(X, good, good, np.zeros((len(X), 3)))
    with pytest.raises(ValueError, match=r"needs the column\(s\) \['phase'\]"):
        fit_quat_order(X.drop(columns="phase"), good, good, np.zeros((len(X), 4)))


def test_single_file_of_several_runs_is_checked(tmp_path):
    from skcath.io import read_recording

    folder = _write_runs(tmp_path, "xyzw", n_catheters=1, n_runs=4)
    one = pd.concat([pd.read_csv(p) for p in sorted(folder.glob("C0-*.csv"))], ignore_index=True)
    path = tmp_path / "all" / "runs.csv"
    path.parent.mkdir()
    one.to_csv(path, index=False)
    kwargs = {"columns": {"base_orientation": BASE_COLUMNS}}
    with pytest.raises(ValueError, match=r"quat_order='wxyz'.*pass quat_order='xyzw'"):
        read_recording(path, quat_order="wxyz", **kwargs)
    X, _ = read_recording(path, quat_order="xyzw", **kwargs)
    assert X["run"].nunique() == 4
    read_recording(path, quat_order="wxyz", quat_check=False, **kwargs)
    # a file of one run cannot tell: the wrong order passes
    read_recording(folder / "C0-S0.csv", quat_order="wxyz", **kwargs)


def test_files_are_checked_by_the_order_declared_for_them(tmp_path):
    # a manifest declares the right order for C0's files and the wrong one for C1's
    folder = _write_runs(tmp_path, "xyzw")
    paths = sorted(p.name for p in folder.glob("*.csv"))
    manifest = pd.DataFrame({
        "path": paths, "quat_order": ["xyzw" if p.startswith("C0") else "wxyz" for p in paths],
    })
    manifest.to_csv(folder / "manifest.txt", index=False)
    columns = {"base_orientation": BASE_COLUMNS}
    with pytest.raises(ValueError, match=r"quat_order='wxyz'.*over 4 runs.*pass quat_order='xyzw'"):
        read_recordings(manifest=folder / "manifest.txt", columns=columns, progress=False)
    manifest["quat_order"] = "xyzw"
    manifest.to_csv(folder / "manifest.txt", index=False)
    X, _ = read_recordings(manifest=folder / "manifest.txt", columns=columns, progress=False)
    assert X["run"].nunique() == 8


def test_streams_of_several_runs_are_checked_as_a_file(tmp_path):
    """read_streams checks the order as read_recording does, with the same message."""
    from skcath.io import read_recording, read_streams

    folder = _write_runs(tmp_path, "xyzw", n_catheters=1, n_runs=4)
    one = pd.concat([pd.read_csv(p) for p in sorted(folder.glob("C0-*.csv"))], ignore_index=True)
    one["t"] = np.arange(len(one)) * 0.1  # one clock for the two logs
    pose = [c for c in one.columns if c.startswith(("tip_p", "base_p")) or c in BASE_COLUMNS]
    motors, tracker = one.drop(columns=pose), one[["t", *pose]]
    path = tmp_path / "all" / "runs.csv"
    path.parent.mkdir()
    one.to_csv(path, index=False)
    kwargs = {"columns": {"base_orientation": BASE_COLUMNS}, "quat_order": "wxyz"}
    with pytest.raises(ValueError) as from_file:
        read_recording(path, **kwargs)
    with pytest.raises(ValueError, match=r"quat_order='wxyz'.*pass quat_order='xyzw'") as info:
        read_streams(motors, tracker, tolerance=0.01, **kwargs)
    assert str(info.value) == str(from_file.value)
    X, y, _ = read_streams(motors, tracker, tolerance=0.01, **{**kwargs, "quat_order": "xyzw"})
    assert X["run"].nunique() == 4
    X_file, y_file = read_recording(path, **{**kwargs, "quat_order": "xyzw"})
    pd.testing.assert_frame_equal(X, X_file)
    np.testing.assert_allclose(y, y_file)
    read_streams(motors, tracker, tolerance=0.01, quat_check=False, **kwargs)
