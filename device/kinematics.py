"""Stewart-platform kinematics: closed-form inverse, Newton forward, Jacobians, statics.

The compiled functions work on preallocated arrays so that the 7 kHz tick loop allocates
nothing; :class:`Kinematics` wraps them for Python callers. Small 3-vectors and 3x3 matrices
that only live inside one computation are tuples (:data:`Vec3`, :data:`Mat3` and the ``v3``
and ``m3`` functions): numba keeps tuples in registers, whereas every small ``np.empty`` is
a heap allocation plus reference counting, which used to cost the plant step more than its
physics. Each tuple function sums in the same order as its array twin, so the two give
bit-identical results.

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


Vec3 = tuple[float, float, float]
"""A 3-vector held by value (see the module docstring)."""
Mat3 = tuple[Vec3, Vec3, Vec3]
"""A 3x3 matrix held by value, as its three rows."""


@njit
def m3_rotation_sincos(cr: float, sr: float, cp: float, sp: float, cy: float, sy: float) -> Mat3:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` from the cosines and sines of the three angles."""
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


@njit
def m3_rotation(roll: float, pitch: float, yaw: float) -> Mat3:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    return m3_rotation_sincos(
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )


@njit
def m3_store(M: Mat3, out: NDArray[np.float64]) -> None:
    """Write ``M`` into the 3x3 array ``out``."""
    for r in range(3):
        for c in range(3):
            out[r, c] = M[r][c]


@njit
def rotation(roll: float, pitch: float, yaw: float, R: NDArray[np.float64]) -> None:
    """Write ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` into ``R`` (3x3)."""
    m3_store(m3_rotation(roll, pitch, yaw), R)


@njit
def m3_euler_rate(pitch: float, yaw: float) -> Mat3:
    """``E`` with ``w = E @ (roll_rate, pitch_rate, yaw_rate)``."""
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return ((cy * cp, -sy, 0.0), (sy * cp, cy, 0.0), (-sp, 0.0, 1.0))


@njit
def euler_rate_matrix(pitch: float, yaw: float, E: NDArray[np.float64]) -> None:
    """Write ``E`` with ``w = E @ (roll_rate, pitch_rate, yaw_rate)`` (3x3)."""
    m3_store(m3_euler_rate(pitch, yaw), E)


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
    position = v3(pose, 0)
    R = m3_rotation(pose[3], pose[4], pose[5])
    for i in range(6):
        n, u, a = leg_vector(position, R, row3(base, i), row3(plat, i))
        lengths[i] = n
        for r in range(3):
            units[i, r] = u[r]
            arms[i, r] = a[r]


@njit
def leg_vector(
    position: Vec3, R: Mat3, base_joint: Vec3, plat_joint: Vec3
) -> tuple[float, Vec3, Vec3]:
    """Length, unit vector and arm of one leg (a row of :func:`leg_vectors`) for the platform
    at ``position`` rotated by ``R``, by value so that the plant step can use it without
    arrays (see the module docstring)."""
    a = m3_vec(R, plat_joint)
    d0 = position[0] + a[0] - base_joint[0]
    d1 = position[1] + a[1] - base_joint[1]
    d2 = position[2] + a[2] - base_joint[2]
    n = math.sqrt(d0**2 + d1**2 + d2**2)
    return n, (d0 / n, d1 / n, d2 / n), a


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
def pose_jacobian(
    pose: NDArray[np.float64], J: NDArray[np.float64], Jq: NDArray[np.float64]
) -> None:
    """Write ``Jq = dL/dpose`` (6x6) from the twist Jacobian ``J`` at ``pose``."""
    E = m3_euler_rate(pose[4], pose[5])
    for i in range(6):
        Jq[i, 0] = J[i, 0]
        Jq[i, 1] = J[i, 1]
        Jq[i, 2] = J[i, 2]
        for c in range(3):
            Jq[i, 3 + c] = J[i, 3] * E[0][c] + J[i, 4] * E[1][c] + J[i, 5] * E[2][c]


@njit
def solve6(A: NDArray[np.float64], b: NDArray[np.float64], x: NDArray[np.float64]) -> bool:
    """Solve ``A x = b`` (6x6) by Gaussian elimination with partial pivoting.

    Hand-written because numba's ``np.linalg.solve`` needs SciPy's LAPACK and allocates; a
    6x6 system in the tick loop wants neither. Returns False (x untouched) if ``A`` is
    numerically singular. ``A`` and ``b`` are left as they were: this copies them into the
    augmented matrix that :func:`solve6_augmented` works on.
    """
    M = np.empty((6, 7))
    for r in range(6):
        for c in range(6):
            M[r, c] = A[r, c]
        M[r, 6] = b[r]
    return solve6_augmented(M, x)


@njit
def solve6_augmented(M: NDArray[np.float64], x: NDArray[np.float64]) -> bool:
    """:func:`solve6` on the augmented matrix ``M = [A | b]`` (6x7), which it overwrites.

    For callers that build the system in a scratch buffer anyway (the plant step), so that
    nothing is copied or allocated. Returns False (x untouched) if ``A`` is singular.
    """
    scale = 0.0
    for r in range(6):
        for c in range(6):
            scale = max(scale, abs(M[r, c]))
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
        # Column c below the pivot would become zero and is never read again, so only the
        # columns to its right are updated.
        for r in range(c + 1, 6):
            f = M[r, c] / M[c, c]
            if f != 0.0:
                for k in range(c + 1, 7):
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
    M = np.empty((6, 7))  # [J.T | wrench]
    for k in range(6):
        for i in range(6):
            M[k, i] = J[i, k]
        M[k, 6] = wrench[k]
    return solve6_augmented(M, forces)


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


# -- 3-vectors and 3x3 matrices by value (see the module docstring) ---------------------

Vec3Like = Vec3 | NDArray[np.float64]
"""A tuple, or an array of at least three numbers of which the first three are used."""


@njit
def v3(a: NDArray[np.float64], start: int) -> Vec3:
    """``a[start:start + 3]`` as a tuple."""
    return (a[start], a[start + 1], a[start + 2])


@njit
def row3(a: NDArray[np.float64], i: int) -> Vec3:
    """Row ``i`` of an (n, 3) array as a tuple."""
    return (a[i, 0], a[i, 1], a[i, 2])


@njit
def m3(a: NDArray[np.float64]) -> Mat3:
    """A 3x3 array as a tuple."""
    return ((a[0, 0], a[0, 1], a[0, 2]), (a[1, 0], a[1, 1], a[1, 2]), (a[2, 0], a[2, 1], a[2, 2]))


@njit
def v3_dot(a: Vec3Like, b: Vec3Like) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit
def v3_cross(a: Vec3Like, b: Vec3Like) -> Vec3:
    """``a x b`` (as :func:`cross3`)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit
def v3_add(a: Vec3Like, b: Vec3Like) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit
def v3_sub(a: Vec3Like, b: Vec3Like) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit
def v3_scale(k: float, a: Vec3Like) -> Vec3:
    return (k * a[0], k * a[1], k * a[2])


@njit
def m3_transpose(M: Mat3) -> Mat3:
    return ((M[0][0], M[1][0], M[2][0]), (M[0][1], M[1][1], M[2][1]), (M[0][2], M[1][2], M[2][2]))


@njit
def m3_vec(M: Mat3, v: Vec3Like) -> Vec3:
    """``M @ v`` (as :func:`mat3_vec`)."""
    return (v3_dot(M[0], v), v3_dot(M[1], v), v3_dot(M[2], v))


@njit
def m3_t_vec(M: Mat3, v: Vec3Like) -> Vec3:
    """``M.T @ v`` (as :func:`mat3_t_vec`)."""
    return m3_vec(m3_transpose(M), v)


@njit
def m3_rotate_inertia(R: Mat3, I: Mat3) -> Mat3:
    """``R @ I @ R.T`` (as :func:`rotate_inertia`: row a of ``R @ I`` first, then its dot
    products with the rows of ``R``)."""
    IT = m3_transpose(I)
    return (m3_vec(R, m3_vec(IT, R[0])), m3_vec(R, m3_vec(IT, R[1])), m3_vec(R, m3_vec(IT, R[2])))
