"""Stewart-platform kinematics: closed-form inverse, Newton forward, Jacobians, statics.

The compiled functions work on preallocated arrays so that the 7 kHz tick loop allocates
nothing; :class:`Kinematics` wraps them for Python callers.

Conventions are those of :mod:`device.geometry`. ``J`` (the twist Jacobian) maps the
platform twist ``(v, w)`` (task-origin velocity and angular velocity, base frame) to leg
rates; its transpose maps leg forces (positive pushing the platform away from the base) to
the wrench ``(force, moment about the task origin)`` they exert on the platform.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from device._jit import njit
from device.geometry import DEFAULT_GEOMETRY, Geometry

FK_MAX_ITERATIONS = 20
"""Newton iterations before forward kinematics gives up (warm starts need 2-4)."""
FK_TOLERANCE = 1e-10
"""Largest leg-length residual accepted by forward kinematics (m)."""


class KinematicsError(ValueError):
    """A kinematic computation has no valid answer (no convergence, singular pose)."""


@njit
def rotation(roll: float, pitch: float, yaw: float, R: NDArray[np.float64]) -> None:
    """Write ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` into ``R`` (3x3)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    R[0, 0] = cy * cp
    R[0, 1] = cy * sp * sr - sy * cr
    R[0, 2] = cy * sp * cr + sy * sr
    R[1, 0] = sy * cp
    R[1, 1] = sy * sp * sr + cy * cr
    R[1, 2] = sy * sp * cr - cy * sr
    R[2, 0] = -sp
    R[2, 1] = cp * sr
    R[2, 2] = cp * cr


@njit
def euler_rate_matrix(pitch: float, yaw: float, E: NDArray[np.float64]) -> None:
    """Write ``E`` with ``w = E @ (roll_rate, pitch_rate, yaw_rate)`` (3x3)."""
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    E[0, 0] = cy * cp
    E[1, 0] = sy * cp
    E[2, 0] = -sp
    E[0, 1] = -sy
    E[1, 1] = cy
    E[2, 1] = 0.0
    E[0, 2] = 0.0
    E[1, 2] = 0.0
    E[2, 2] = 1.0


@njit
def leg_vectors(
    pose: NDArray[np.float64],
    base: NDArray[np.float64],
    plat: NDArray[np.float64],
    lengths: NDArray[np.float64],
    units: NDArray[np.float64],
    arms: NDArray[np.float64],
) -> None:
    """Closed-form inverse kinematics.

    Writes leg ``lengths`` (6), unit vectors ``units`` (6x3, base to platform) and ``arms``
    (6x3, platform joint relative to the task origin, base frame).
    """
    R = np.empty((3, 3))
    rotation(pose[3], pose[4], pose[5], R)
    for i in range(6):
        for r in range(3):
            a = R[r, 0] * plat[i, 0] + R[r, 1] * plat[i, 1] + R[r, 2] * plat[i, 2]
            arms[i, r] = a
            units[i, r] = pose[r] + a - base[i, r]
        n = math.sqrt(units[i, 0] ** 2 + units[i, 1] ** 2 + units[i, 2] ** 2)
        lengths[i] = n
        for r in range(3):
            units[i, r] /= n


@njit
def twist_jacobian(
    units: NDArray[np.float64], arms: NDArray[np.float64], J: NDArray[np.float64]
) -> None:
    """Write the 6x6 twist Jacobian: row i is ``(u_i, arm_i x u_i)``."""
    for i in range(6):
        u0, u1, u2 = units[i, 0], units[i, 1], units[i, 2]
        a0, a1, a2 = arms[i, 0], arms[i, 1], arms[i, 2]
        J[i, 0] = u0
        J[i, 1] = u1
        J[i, 2] = u2
        J[i, 3] = a1 * u2 - a2 * u1
        J[i, 4] = a2 * u0 - a0 * u2
        J[i, 5] = a0 * u1 - a1 * u0


@njit
def pose_jacobian(pose: NDArray[np.float64], J: NDArray[np.float64], Jq: NDArray[np.float64]) -> None:
    """Write ``Jq = dL/dpose`` (6x6) from the twist Jacobian ``J`` at ``pose``."""
    E = np.empty((3, 3))
    euler_rate_matrix(pose[4], pose[5], E)
    for i in range(6):
        Jq[i, 0] = J[i, 0]
        Jq[i, 1] = J[i, 1]
        Jq[i, 2] = J[i, 2]
        for c in range(3):
            Jq[i, 3 + c] = J[i, 3] * E[0, c] + J[i, 4] * E[1, c] + J[i, 5] * E[2, c]


@njit
def solve6(A: NDArray[np.float64], b: NDArray[np.float64], x: NDArray[np.float64]) -> bool:
    """Solve ``A x = b`` (6x6) by Gaussian elimination with partial pivoting.

    Hand-written because numba's ``np.linalg.solve`` needs SciPy's LAPACK and allocates; a
    6x6 system in the tick loop wants neither. Returns False (x untouched) if ``A`` is
    numerically singular.
    """
    M = np.empty((6, 7))
    scale = 0.0
    for r in range(6):
        for c in range(6):
            M[r, c] = A[r, c]
            scale = max(scale, abs(A[r, c]))
        M[r, 6] = b[r]
    if not scale > 0.0:
        return False
    for c in range(6):
        p = c
        for r in range(c + 1, 6):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if not abs(M[p, c]) > 1e-12 * scale:
            return False
        if p != c:
            for k in range(c, 7):
                M[c, k], M[p, k] = M[p, k], M[c, k]
        for r in range(c + 1, 6):
            f = M[r, c] / M[c, c]
            if f != 0.0:
                for k in range(c, 7):
                    M[r, k] -= f * M[c, k]
    for r in range(5, -1, -1):
        s = M[r, 6]
        for k in range(r + 1, 6):
            s -= M[r, k] * x[k]
        x[r] = s / M[r, r]
    return True


@njit
def forward_kinematics(
    lengths: NDArray[np.float64],
    base: NDArray[np.float64],
    plat: NDArray[np.float64],
    pose: NDArray[np.float64],
    max_iterations: int,
    tolerance: float,
) -> int:
    """Newton's method from the pose in ``pose`` (the warm start), updated in place.

    Returns the number of iterations used, or -1 if it did not converge within
    ``max_iterations`` or met a singular Jacobian; ``pose`` is then left at the warm start.
    """
    start = pose.copy()
    L = np.empty(6)
    U = np.empty((6, 3))
    A = np.empty((6, 3))
    J = np.empty((6, 6))
    Jq = np.empty((6, 6))
    r = np.empty(6)
    dq = np.empty(6)
    for it in range(max_iterations + 1):
        leg_vectors(pose, base, plat, L, U, A)
        worst = 0.0
        for i in range(6):
            r[i] = lengths[i] - L[i]
            worst = max(worst, abs(r[i]))
        if worst <= tolerance:
            return it
        if it == max_iterations or not math.isfinite(worst):
            break
        twist_jacobian(U, A, J)
        pose_jacobian(pose, J, Jq)
        if not solve6(Jq, r, dq):
            break
        for k in range(6):
            pose[k] += dq[k]
    for k in range(6):
        pose[k] = start[k]
    return -1


@njit
def leg_forces_for_wrench(
    J: NDArray[np.float64], wrench: NDArray[np.float64], forces: NDArray[np.float64]
) -> bool:
    """Leg forces ``f`` with ``J.T @ f = wrench``; False if the pose is singular."""
    JT = np.empty((6, 6))
    for i in range(6):
        for k in range(6):
            JT[k, i] = J[i, k]
    return solve6(JT, wrench, forces)


class Kinematics:
    """Python-side kinematics of one geometry (allocates; not for the tick loop)."""

    def __init__(self, geometry: Geometry = DEFAULT_GEOMETRY) -> None:
        self.geometry = geometry
        self._base = np.ascontiguousarray(geometry.base_joints)
        self._plat = np.ascontiguousarray(geometry.platform_joints)

    def _legs(
        self, pose: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        q = np.asarray(pose, dtype=np.float64)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise KinematicsError(f"pose must be 6 finite numbers, got {pose!r}")
        L, U, A = np.empty(6), np.empty((6, 3)), np.empty((6, 3))
        leg_vectors(q, self._base, self._plat, L, U, A)
        return L, U, A

    def inverse(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """Leg lengths (m) at ``pose``."""
        return self._legs(pose)[0]

    def jacobian(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """Twist Jacobian (6x6) at ``pose``."""
        _, U, A = self._legs(pose)
        J = np.empty((6, 6))
        twist_jacobian(U, A, J)
        return J

    def pose_jacobian(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """``dL/dpose`` (6x6) at ``pose``."""
        J = self.jacobian(pose)
        Jq = np.empty((6, 6))
        pose_jacobian(np.asarray(pose, dtype=np.float64), J, Jq)
        return Jq

    def forward(
        self,
        lengths: NDArray[np.float64],
        guess: NDArray[np.float64] | None = None,
        max_iterations: int = FK_MAX_ITERATIONS,
        tolerance: float = FK_TOLERANCE,
    ) -> NDArray[np.float64]:
        """Pose with the given leg lengths, by Newton's method from ``guess`` (default home).

        Raises :class:`KinematicsError` when it does not converge.
        """
        L = np.asarray(lengths, dtype=np.float64)
        if L.shape != (6,) or not np.all(np.isfinite(L)):
            raise KinematicsError(f"lengths must be 6 finite numbers, got {lengths!r}")
        pose = np.array(self.geometry.home_pose if guess is None else guess, dtype=np.float64)
        n = forward_kinematics(L, self._base, self._plat, pose, max_iterations, tolerance)
        if n < 0:
            raise KinematicsError(
                f"forward kinematics did not converge in {max_iterations} iterations "
                f"from {np.round(pose, 4).tolist()} (lengths {np.round(L, 5).tolist()})"
            )
        return pose

    def wrench_to_leg_forces(
        self, pose: NDArray[np.float64], wrench: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Leg forces (N) that balance ``wrench`` (N, N m about the task origin)."""
        J = self.jacobian(pose)
        f = np.empty(6)
        if not leg_forces_for_wrench(J, np.asarray(wrench, dtype=np.float64), f):
            raise KinematicsError(f"singular pose {np.asarray(pose).tolist()}")
        return f

    def leg_forces_to_wrench(
        self, pose: NDArray[np.float64], forces: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Wrench (N, N m about the task origin) that leg forces exert on the platform."""
        return self.jacobian(pose).T @ np.asarray(forces, dtype=np.float64)


@njit
def mat3_vec(R: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R @ v`` for 3x3 by 3 (numba's ``@`` needs SciPy's BLAS)."""
    out = np.empty(3)
    for r in range(3):
        out[r] = R[r, 0] * v[0] + R[r, 1] * v[1] + R[r, 2] * v[2]
    return out


@njit
def mat3_t_vec(R: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R.T @ v`` for 3x3 by 3."""
    out = np.empty(3)
    for r in range(3):
        out[r] = R[0, r] * v[0] + R[1, r] * v[1] + R[2, r] * v[2]
    return out


@njit
def rotate_inertia(R: NDArray[np.float64], I: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R @ I @ R.T`` for 3x3."""
    T = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            T[a, b] = R[a, 0] * I[0, b] + R[a, 1] * I[1, b] + R[a, 2] * I[2, b]
    out = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            out[a, b] = T[a, 0] * R[b, 0] + T[a, 1] * R[b, 1] + T[a, 2] * R[b, 2]
    return out


@njit
def cross3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a x b`` for 3-vectors."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out
