"""Tests of skcath.frames: tip position in the base frame from two sensor poses."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from skcath.frames import quaternion_to_rotation, sweep_frame, tip_in_base_frame

IDENTITY_WXYZ = np.array([[1.0, 0.0, 0.0, 0.0]])


def _xyzw_to_wxyz(q):
    return np.asarray(q)[..., [3, 0, 1, 2]]


def _random_poses(rng, n):
    """Random base poses (wxyz) and a base-frame tip put into the tracker frame."""
    r_wb = Rotation.random(n, random_state=rng)
    p_wb = rng.uniform(-300.0, 300.0, size=(n, 3))
    p_b = rng.uniform(-90.0, 90.0, size=(n, 3))
    p_wt = p_wb + r_wb.apply(p_b)
    return p_wt, p_wb, _xyzw_to_wxyz(r_wb.as_quat()), p_b


def test_identity_base_gives_difference():
    tip = np.array([[1.0, 2.0, 3.0], [10.0, -5.0, 80.0]])
    base = np.array([[0.5, 0.5, 0.5], [-1.0, 0.0, 2.0]])
    q = np.repeat(IDENTITY_WXYZ, 2, axis=0)
    assert_allclose(tip_in_base_frame(tip, base, q), tip - base)


def test_rotation_90_deg_about_z_by_hand():
    # R_WB maps base x to world y; so a tip at world +y from the base is at base +x,
    # and a tip at world -x is at base +y.
    c = np.cos(np.pi / 4)
    q = np.array([[c, 0.0, 0.0, c], [c, 0.0, 0.0, c]])
    base = np.array([[5.0, 5.0, 5.0], [5.0, 5.0, 5.0]])
    tip = base + np.array([[0.0, 80.0, 0.0], [-20.0, 0.0, 3.0]])
    expected = np.array([[80.0, 0.0, 0.0], [0.0, 20.0, 3.0]])
    assert_allclose(tip_in_base_frame(tip, base, q), expected, atol=1e-12)


def test_round_trip_random_poses():
    rng = np.random.default_rng(0)
    p_wt, p_wb, q_wb, p_b = _random_poses(rng, 200)
    assert_allclose(tip_in_base_frame(p_wt, p_wb, q_wb), p_b, atol=1e-9)


def test_quat_orders_agree_when_columns_permuted():
    rng = np.random.default_rng(1)
    p_wt, p_wb, q_wxyz, _ = _random_poses(rng, 50)
    q_xyzw = q_wxyz[:, [1, 2, 3, 0]]
    a = tip_in_base_frame(p_wt, p_wb, q_wxyz, quat_order="wxyz")
    b = tip_in_base_frame(p_wt, p_wb, q_xyzw, quat_order="xyzw")
    assert_allclose(a, b, atol=1e-12)
    # and the wrong order gives a different answer
    c = tip_in_base_frame(p_wt, p_wb, q_xyzw, quat_order="wxyz")
    assert np.abs(c - a).max() > 1.0


def test_non_unit_quaternions_are_normalised():
    rng = np.random.default_rng(2)
    p_wt, p_wb, q, p_b = _random_poses(rng, 20)
    scaled = q * rng.uniform(0.2, 5.0, size=(20, 1))
    assert_allclose(tip_in_base_frame(p_wt, p_wb, scaled), p_b, atol=1e-9)


@pytest.mark.parametrize("which", ["tip", "base", "quat"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_row_gives_nan_row_only(which, bad):
    rng = np.random.default_rng(3)
    p_wt, p_wb, q, p_b = _random_poses(rng, 6)
    array = {"tip": p_wt, "base": p_wb, "quat": q}[which]
    array[2, 0] = bad
    out = tip_in_base_frame(p_wt, p_wb, q)
    assert np.isnan(out[2]).all()
    keep = np.arange(6) != 2
    assert_allclose(out[keep], p_b[keep], atol=1e-9)


def test_all_rows_missing():
    out = tip_in_base_frame(np.full((3, 3), np.nan), np.zeros((3, 3)), np.full((3, 4), np.nan))
    assert out.shape == (3, 3)
    assert np.isnan(out).all()


def test_empty_input():
    out = tip_in_base_frame(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)))
    assert out.shape == (0, 3)


def test_zero_quaternion_raises_with_argument_and_row():
    q = np.repeat(IDENTITY_WXYZ, 4, axis=0)
    q[3] = 0.0
    with pytest.raises(ValueError, match=r"base_orientation.*row 3"):
        tip_in_base_frame(np.zeros((4, 3)), np.zeros((4, 3)), q)


def test_zero_quaternion_on_missing_row_is_not_an_error():
    q = np.repeat(IDENTITY_WXYZ, 2, axis=0)
    q[1] = 0.0
    tip = np.array([[1.0, 2.0, 3.0], [np.nan, 0.0, 0.0]])
    out = tip_in_base_frame(tip, np.zeros((2, 3)), q)
    assert_allclose(out[0], [1.0, 2.0, 3.0])
    assert np.isnan(out[1]).all()


def test_zero_tip_quaternion_raises_with_argument_and_row():
    q = np.repeat(IDENTITY_WXYZ, 3, axis=0)
    q_tip = q.copy()
    q_tip[1] = 0.0
    with pytest.raises(ValueError, match=r"tip_orientation.*row 1"):
        tip_in_base_frame(
            np.zeros((3, 3)), np.zeros((3, 3)), q, tip_offset=[0, 0, 1], tip_orientation=q_tip
        )


def test_tip_offset_in_tip_sensor_frame():
    rng = np.random.default_rng(4)
    n = 30
    p_wt, p_wb, q_wb, p_b = _random_poses(rng, n)
    r_ws = Rotation.random(n, random_state=rng)
    offset = np.array([0.0, 0.0, 12.5])
    out = tip_in_base_frame(
        p_wt, p_wb, q_wb, tip_offset=offset, tip_orientation=_xyzw_to_wxyz(r_ws.as_quat())
    )
    r_wb = Rotation.from_quat(q_wb[:, [1, 2, 3, 0]])
    expected = p_b + r_wb.inv().apply(r_ws.apply(offset))
    assert_allclose(out, expected, atol=1e-9)
    # the offset point is 12.5 mm from the sensor, whatever the orientations
    assert_allclose(np.linalg.norm(out - p_b, axis=1), 12.5)


def test_tip_offset_with_identity_orientations_by_hand():
    q = np.repeat(IDENTITY_WXYZ, 1, axis=0)
    c = np.cos(np.pi / 4)
    q_tip = np.array([[c, c, 0.0, 0.0]])  # 90 deg about x: tip z axis -> world -y
    out = tip_in_base_frame(
        [[0.0, 0.0, 80.0]], [[0.0, 0.0, 0.0]], q, tip_offset=[0, 0, 10], tip_orientation=q_tip
    )
    assert_allclose(out, [[0.0, -10.0, 80.0]], atol=1e-12)


def test_tip_offset_requires_tip_orientation():
    with pytest.raises(ValueError, match="tip_orientation"):
        tip_in_base_frame(np.zeros((1, 3)), np.zeros((1, 3)), IDENTITY_WXYZ, tip_offset=[0, 0, 1])


@pytest.mark.parametrize("offset", [[0, 1], [0, 0, np.nan], "abc", [[0, 0, 1]]])
def test_bad_tip_offset(offset):
    with pytest.raises(ValueError, match="tip_offset"):
        tip_in_base_frame(
            np.zeros((1, 3)),
            np.zeros((1, 3)),
            IDENTITY_WXYZ,
            tip_offset=offset,
            tip_orientation=IDENTITY_WXYZ,
        )


def test_tip_orientation_ignored_without_offset():
    q_tip = np.array([[np.nan, 0.0, 0.0, 0.0]])
    out = tip_in_base_frame(
        [[1.0, 2.0, 3.0]], np.zeros((1, 3)), IDENTITY_WXYZ, tip_orientation=q_tip
    )
    assert_allclose(out, [[1.0, 2.0, 3.0]])


def test_inputs_not_modified():
    rng = np.random.default_rng(5)
    p_wt, p_wb, q, _ = _random_poses(rng, 10)
    q = q * 3.0  # non-unit: would be normalised in place by a careless implementation
    p_wt[4, 1] = np.nan
    q_tip = _xyzw_to_wxyz(Rotation.random(10, random_state=rng).as_quat()) * 2.0
    copies = [a.copy() for a in (p_wt, p_wb, q, q_tip)]
    offset = np.array([1.0, 2.0, 3.0])
    offset_copy = offset.copy()
    tip_in_base_frame(p_wt, p_wb, q, tip_offset=offset, tip_orientation=q_tip)
    for original, copy in zip((p_wt, p_wb, q, q_tip), copies):
        np.testing.assert_array_equal(original, copy)
    np.testing.assert_array_equal(offset, offset_copy)


def test_accepts_lists_and_returns_float_array():
    out = tip_in_base_frame([[1, 2, 3]], [[0, 0, 0]], [[1, 0, 0, 0]])
    assert isinstance(out, np.ndarray)
    assert out.dtype == np.float64
    assert out.shape == (1, 3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"tip_position": np.zeros(3)}, r"tip_position.*\(n, 3\)"),
        ({"tip_position": np.zeros((2, 4))}, r"tip_position.*\(n, 3\)"),
        ({"base_position": np.zeros((2, 2))}, r"base_position.*\(n, 3\)"),
        ({"base_orientation": np.zeros((2, 3))}, r"base_orientation.*\(n, 4\)"),
        ({"base_position": np.zeros((3, 3))}, r"base_position has 3 rows.*2"),
        ({"base_orientation": np.tile([1.0, 0, 0, 0], (5, 1))}, r"base_orientation has 5 rows"),
        ({"tip_position": [["a", "b", "c"], ["d", "e", "f"]]}, r"tip_position.*numeric"),
        ({"quat_order": "xyz"}, r"quat_order.*'wxyz'.*'xyzw'"),
        ({"quat_order": None}, r"quat_order"),
    ],
)
def test_invalid_inputs_raise(kwargs, match):
    args = {
        "tip_position": np.zeros((2, 3)),
        "base_position": np.zeros((2, 3)),
        "base_orientation": np.tile([1.0, 0, 0, 0], (2, 1)),
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        tip = args.pop("tip_position")
        base = args.pop("base_position")
        tip_in_base_frame(tip, base, args.pop("base_orientation"), **args)


def test_tip_orientation_row_count_checked():
    with pytest.raises(ValueError, match="tip_orientation has 1 rows"):
        tip_in_base_frame(
            np.zeros((2, 3)),
            np.zeros((2, 3)),
            np.tile([1.0, 0, 0, 0], (2, 1)),
            tip_offset=[0, 0, 1],
            tip_orientation=IDENTITY_WXYZ,
        )


def test_quaternion_to_rotation_orders():
    r = Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    xyzw = r.as_quat()
    assert quaternion_to_rotation(xyzw, "xyzw").approx_equal(r)
    assert quaternion_to_rotation(_xyzw_to_wxyz(xyzw) * 2.0, "wxyz").approx_equal(r)
    stack = quaternion_to_rotation(np.vstack([xyzw, xyzw]), "xyzw")
    assert len(stack) == 2


@pytest.mark.parametrize(
    ("q", "match"),
    [
        ([0.0, 0.0, 0.0, 0.0], r"zero-norm.*row 0"),
        ([[1.0, 0, 0, 0], [np.nan, 0, 0, 0]], r"non-finite.*row 1"),
        ([1.0, 0.0, 0.0], r"shape \(4,\) or \(n, 4\)"),
        (np.zeros((2, 2, 4)), r"shape \(4,\) or \(n, 4\)"),
    ],
)
def test_quaternion_to_rotation_errors(q, match):
    with pytest.raises(ValueError, match=match):
        quaternion_to_rotation(q)


_finite = st.floats(-500.0, 500.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(
    quat=st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4).filter(
        lambda q: np.linalg.norm(q) > 0.1
    ),
    base=st.lists(_finite, min_size=3, max_size=3),
    p_b=st.lists(st.floats(-150.0, 150.0, allow_nan=False), min_size=3, max_size=3),
    scalar_first=st.booleans(),
)
def test_round_trip_property(quat, base, p_b, scalar_first):
    order = "wxyz" if scalar_first else "xyzw"
    q = np.asarray(quat)
    r_wb = Rotation.from_quat(q[[1, 2, 3, 0]] if scalar_first else q)  # scipy: scalar last
    tip = np.asarray(base) + r_wb.apply(np.asarray(p_b))
    out = tip_in_base_frame(tip[None, :], [base], q[None, :], quat_order=order)
    assert_allclose(out[0], p_b, atol=1e-9)


# ---------------------------------------------------------------------------
# sweep_frame
# ---------------------------------------------------------------------------
def _sweep(rng, n=400):
    """Motor angles of an 8-ray sweep and a bending section's tip (mm, sensor frame).

    The section bends towards +x for q1 and +y for q2 (constant curvature,
    42 mm), seen from a base sensor that is rolled by 70 degrees and tilted
    by 30 degrees; positions carry 0.2 mm of noise.
    """
    psi = np.repeat(np.deg2rad(np.arange(8) * 45.0), n // 8)
    rho = np.tile(np.r_[np.linspace(0, 60, n // 16), np.linspace(60, 0, n // 16)], 8)
    q = np.c_[rho * np.cos(psi), rho * np.sin(psi)]
    theta = np.deg2rad(np.hypot(*q.T) * 2.0)
    delta = np.arctan2(q[:, 1], q[:, 0])
    L = 42.0
    k = np.maximum(theta, 1e-9) / L
    tip = np.c_[
        np.cos(delta) * (1 - np.cos(theta)) / k, np.sin(delta) * (1 - np.cos(theta)) / k, np.sin(theta) / k
    ]
    mount = Rotation.from_euler("zx", [70.0, 30.0], degrees=True)
    return q, mount.inv().apply(tip) + rng.normal(0.0, 0.2, tip.shape), mount


def test_sweep_frame_recovers_the_bending_axes():
    rng = np.random.default_rng(0)
    q, p, mount = _sweep(rng)
    R = sweep_frame(q, p)
    assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # the base sensor's mount is undone: S is the bending section's own frame
    assert_allclose(R, mount.as_matrix(), atol=0.02)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_vectors_in_the_sweep_frame_do_not_depend_on_the_mount(seed):
    rng = np.random.default_rng(seed)
    q, p, _ = _sweep(rng, n=160)
    G = Rotation.random(random_state=rng).as_matrix()
    R = sweep_frame(q, p)
    R_rotated = sweep_frame(q, p @ G.T)
    assert_allclose(R_rotated, R @ G.T, atol=1e-9)


def test_sweep_frame_skips_non_finite_rows_and_leaves_inputs_alone():
    rng = np.random.default_rng(1)
    q, p, _ = _sweep(rng)
    p_gaps = p.copy()
    p_gaps[::7] = np.nan
    q_copy, p_copy = q.copy(), p_gaps.copy()
    R = sweep_frame(q, p_gaps)
    assert_allclose(R, sweep_frame(q[~np.isnan(p_gaps[:, 0])], p[~np.isnan(p_gaps[:, 0])]))
    assert_allclose(q, q_copy)
    assert_allclose(p_gaps, p_copy)


def test_sweep_frame_errors():
    rng = np.random.default_rng(2)
    q, p, _ = _sweep(rng)
    with pytest.raises(ValueError, match=r"q must have shape \(n, 2\)"):
        sweep_frame(q[:, :1], p)
    with pytest.raises(ValueError, match=r"p must have shape \(n, 3\)"):
        sweep_frame(q, p[:, :2])
    with pytest.raises(ValueError, match="same number of rows of run 'R7'"):
        sweep_frame(q, p[:-1], run="R7")
    with pytest.raises(ValueError, match="at least 6 sweep samples"):
        sweep_frame(q[:5], p[:5])
    one_motor = q.copy()
    one_motor[:, 1] = 0.0
    with pytest.raises(ValueError, match="rank deficient"):
        sweep_frame(one_motor, p)
    still = np.tile(p[:1], (len(p), 1))
    with pytest.raises(ValueError, match="does not move when the first motor turns"):
        sweep_frame(q, still)
