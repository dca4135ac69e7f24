"""Attitude laws: the rotation from a body's frame to the GCRS at any time.

* :class:`NadirPointing` - body +z towards the Earth's centre, +x along the velocity
  (the local-vertical, local-horizontal frame of an Earth-pointing satellite).
* :class:`Spin` - uniform rotation at ``rate`` about a body axis held fixed in inertial
  space (a spin-stabilised or flat-spinning body; rate 0 is an inertially fixed body).
* :class:`Tumble` - torque-free rotation of a rigid body with principal moments of
  inertia ``I1, I2, I3`` (Euler's equations, e.g. Landau & Lifshitz, *Mechanics*, Sec. 36):
  ``I w' = (I w) x w`` in the body frame and ``q' = q (0, w) / 2`` for the attitude
  quaternion, integrated with an 8th-order Runge-Kutta (DOP853, relative tolerance
  1e-11) over fixed 60 s segments from t = 0, so a value never depends on how the run is
  cut into windows. The angular momentum is fixed in inertial space and, with the
  kinetic energy, conserved (tested to 1e-9); a symmetric top follows the analytic free
  precession.

The initial attitude of spin and tumble is set by where the spin axis (Spin) or the
angular momentum (Tumble) points in the GCRS, and by a phase: the body is first turned
by the smallest rotation that takes its axis there, then by ``phase`` about that axis.

All matrices are ``[n, 3, 3]`` with ``v_gcrs = M @ v_body``.
"""

from __future__ import annotations

import math

import numpy as np

from .geometry import NS_PER_S, unit

TUMBLE_SEGMENT_S = 60.0


def direction_of_radec(ra_deg: float, dec_deg: float) -> np.ndarray:
    """GCRS unit vector of a right ascension and declination [deg]."""
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


def rotation_about(axis: np.ndarray, angle_rad) -> np.ndarray:
    """Rodrigues' rotation matrices ``[n, 3, 3]`` by ``angle_rad`` (``[n]`` or scalar) about a unit ``axis``."""
    angle = np.atleast_1d(np.asarray(angle_rad, dtype=np.float64))
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def aligning_rotation(from_unit: np.ndarray, to_unit: np.ndarray) -> np.ndarray:
    """The smallest rotation ``[3, 3]`` taking unit vector ``from_unit`` to ``to_unit``."""
    axis = np.cross(from_unit, to_unit)
    sin_a, cos_a = np.linalg.norm(axis), float(np.dot(from_unit, to_unit))
    if sin_a < 1e-12:
        if cos_a > 0:
            return np.eye(3)
        perpendicular = np.cross(from_unit, [1.0, 0.0, 0.0] if abs(from_unit[0]) < 0.9 else [0.0, 1.0, 0.0])
        return rotation_about(unit(perpendicular), math.pi)[0]
    return rotation_about(axis / sin_a, math.atan2(sin_a, cos_a))[0]


class NadirPointing:
    """Body +z to nadir, +x along the velocity's horizontal part, +y completing the right-handed frame."""

    def matrices(self, t_ns, r_sat: np.ndarray, v_sat: np.ndarray) -> np.ndarray:
        z = -unit(r_sat)
        x = unit(v_sat - np.einsum("ij,ij->i", v_sat, z)[:, None] * z)
        return np.stack([x, np.cross(z, x), z], axis=-1)


class Spin:
    """Uniform rotation at ``rate_rad_s`` about ``axis_body``, which points at ``axis_gcrs`` throughout."""

    def __init__(self, axis_gcrs: np.ndarray, axis_body: np.ndarray, rate_rad_s: float, phase_rad: float = 0.0):
        self.axis = unit(np.asarray(axis_gcrs, dtype=np.float64))
        self.initial = aligning_rotation(unit(np.asarray(axis_body, dtype=np.float64)), self.axis)
        self.rate_rad_s, self.phase_rad = rate_rad_s, phase_rad

    def matrices(self, t_ns, r_sat=None, v_sat=None) -> np.ndarray:
        t_s = np.atleast_1d(np.asarray(t_ns, dtype=np.float64)) / NS_PER_S
        return rotation_about(self.axis, self.phase_rad + self.rate_rad_s * t_s) @ self.initial


def _quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[n, 3, 3]`` of unit quaternions ``[n, 4]`` (scalar first)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)], axis=1)


def _quaternion_of_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (scalar first) of a rotation matrix (Shepperd's method)."""
    trace = np.trace(m)
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    i = int(np.argmax(candidates))
    if i == 0:
        w = math.sqrt(1.0 + trace) / 2.0
        q = [w, (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)]
    else:
        a, b, c = {1: (0, 1, 2), 2: (1, 2, 0), 3: (2, 0, 1)}[i]
        s = math.sqrt(1.0 + m[a, a] - m[b, b] - m[c, c]) * 2.0
        v = [0.0, 0.0, 0.0]
        v[a], v[b], v[c] = s / 4.0, (m[b, a] + m[a, b]) / s, (m[c, a] + m[a, c]) / s
        q = [(m[c, b] - m[b, c]) / s, *v]
    return np.array(q) / np.linalg.norm(q)


class Tumble:
    """Torque-free rigid-body rotation from principal moments ``inertia`` and body rates ``omega_body`` at t = 0."""

    def __init__(self, inertia: np.ndarray, omega_body_rad_s: np.ndarray, momentum_gcrs: np.ndarray,
                 phase_rad: float = 0.0):
        self.inertia = np.asarray(inertia, dtype=np.float64)
        omega = np.asarray(omega_body_rad_s, dtype=np.float64)
        momentum_body = self.inertia * omega
        axis = unit(np.asarray(momentum_gcrs, dtype=np.float64))
        if np.linalg.norm(momentum_body) == 0.0:        # not rotating: the body frame is the phase-turned GCRS
            initial = rotation_about(axis, phase_rad)[0]
        else:
            initial = rotation_about(axis, phase_rad)[0] @ aligning_rotation(unit(momentum_body), axis)
        self._start = np.concatenate([_quaternion_of_matrix(initial), omega])
        self._segments: dict[int, object] = {}

    def _derivative(self, _t, y):
        q, w = y[:4], y[4:]
        i1, i2, i3 = self.inertia
        dw = np.array([(i2 - i3) * w[1] * w[2] / i1, (i3 - i1) * w[2] * w[0] / i2, (i1 - i2) * w[0] * w[1] / i3])
        qw, qx, qy, qz = q
        dq = 0.5 * np.array([-qx * w[0] - qy * w[1] - qz * w[2], qw * w[0] + qy * w[2] - qz * w[1],
                             qw * w[1] - qx * w[2] + qz * w[0], qw * w[2] + qx * w[1] - qy * w[0]])
        return np.concatenate([dq, dw])

    def _segment(self, index: int):
        """Dense solution over ``[index, index + 1) * 60 s``, made outwards from t = 0 segment by segment.

        Segment k >= 0 starts from the end of segment k - 1, segment k < 0 (times before the
        run's start, e.g. light emitted before t = 0) integrates backwards from segment k + 1.
        """
        step = 1 if index >= 0 else -1
        k = 0 if index >= 0 else -1
        while k != index + step:
            if k not in self._segments:
                from scipy.integrate import solve_ivp   # here: scipy.integrate costs 0.4-1 s to import; only tumbling needs it
                if k in (0, -1):
                    start = self._start
                else:
                    y = self._segments[k - step](max(k, k - step) * TUMBLE_SEGMENT_S)
                    start = np.concatenate([y[:4] / np.linalg.norm(y[:4]), y[4:]])
                t0 = (k if step > 0 else k + 1) * TUMBLE_SEGMENT_S
                self._segments[k] = solve_ivp(self._derivative, (t0, t0 + step * TUMBLE_SEGMENT_S), start,
                                              method="DOP853", rtol=1e-11, atol=1e-12, dense_output=True).sol
            k += step
        return self._segments[index]

    def state(self, t_ns) -> tuple[np.ndarray, np.ndarray]:
        """Attitude quaternions ``[n, 4]`` and body angular velocities ``[n, 3]`` [rad/s] at ``t_ns``."""
        t_s = np.atleast_1d(np.asarray(t_ns, dtype=np.float64)) / NS_PER_S
        index = np.floor(t_s / TUMBLE_SEGMENT_S).astype(np.int64)
        out = np.empty((len(t_s), 7))
        for k in np.unique(index):
            chosen = index == k
            out[chosen] = self._segment(int(k))(t_s[chosen]).T
        return out[:, :4] / np.linalg.norm(out[:, :4], axis=1, keepdims=True), out[:, 4:]

    def matrices(self, t_ns, r_sat=None, v_sat=None) -> np.ndarray:
        quaternions, _ = self.state(t_ns)
        return _quaternion_matrices(quaternions)
