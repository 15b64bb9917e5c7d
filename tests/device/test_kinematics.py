import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from device.geometry import DEFAULT_GEOMETRY, Geometry
from device.kinematics import Kinematics, KinematicsError, solve6

KIN = Kinematics()
HOME = DEFAULT_GEOMETRY.home_pose

offsets = st.tuples(
    st.floats(-0.02, 0.02),
    st.floats(-0.02, 0.02),
    st.floats(-0.02, 0.02),
    st.floats(-0.25, 0.25),
    st.floats(-0.3, 0.3),
    st.floats(-0.2, 0.2),
)


def test_home_is_mid_stroke_on_every_leg() -> None:
    L = KIN.inverse(HOME)
    assert np.allclose(L, DEFAULT_GEOMETRY.home_length)
    assert DEFAULT_GEOMETRY.max_length - DEFAULT_GEOMETRY.min_length == pytest.approx(0.1)


def test_pure_pitch_changes_front_and_back_legs_oppositely() -> None:
    L = KIN.inverse(HOME + np.array([0, 0, 0, 0, 0.2, 0])) - DEFAULT_GEOMETRY.home_length
    assert L.max() > 0.01 and L.min() < -0.005


@given(offsets)
def test_forward_inverts_inverse(off: tuple[float, ...]) -> None:
    pose = HOME + np.array(off)
    found = KIN.forward(KIN.inverse(pose))
    assert np.allclose(found, pose, atol=1e-9)


@given(offsets)
def test_pose_jacobian_matches_finite_differences(off: tuple[float, ...]) -> None:
    pose = HOME + np.array(off)
    Jq = KIN.pose_jacobian(pose)
    h = 1e-7
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        fd = (KIN.inverse(pose + d) - KIN.inverse(pose - d)) / (2 * h)
        assert np.allclose(Jq[:, k], fd, atol=1e-6)


@given(offsets, st.lists(st.floats(-300, 300), min_size=6, max_size=6))
def test_wrench_and_leg_forces_are_dual(off: tuple[float, ...], forces: list[float]) -> None:
    pose = HOME + np.array(off)
    f = np.array(forces)
    W = KIN.leg_forces_to_wrench(pose, f)
    assert np.allclose(KIN.wrench_to_leg_forces(pose, W), f, atol=1e-6)
    # Virtual work: leg power equals platform power for any twist.
    twist = np.array([0.01, -0.02, 0.03, 0.4, -0.1, 0.2])
    assert f @ (KIN.jacobian(pose) @ twist) == pytest.approx(W @ twist, rel=1e-9, abs=1e-9)


def test_forward_fails_clearly_when_it_cannot_converge() -> None:
    far = KIN.inverse(HOME + np.array([0, 0, 0, 0, 0.4, 0]))
    with pytest.raises(KinematicsError, match="did not converge"):
        KIN.forward(far, max_iterations=1)
    with pytest.raises(KinematicsError, match="finite"):
        KIN.forward(np.array([np.nan] * 6))


def test_solve6_agrees_with_numpy_and_refuses_singular() -> None:
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    b = rng.normal(size=6)
    x = np.zeros(6)
    assert solve6(A, b, x)
    assert np.allclose(x, np.linalg.solve(A, b))
    A[5] = A[4]
    assert not solve6(A, b, x)


def test_geometry_rejects_nonsense() -> None:
    with pytest.raises(ValueError, match="stroke"):
        Geometry(stroke=0.0)
