"""Gnomonic (tangent-plane) projection of sky directions onto the focal plane, and back.

An ideal distortion-free camera of focal length ``f`` images the direction at angle
``theta`` from the boresight at ``f tan(theta)`` from the optical axis: that is the
gnomonic projection (Calabretta & Greisen 2002, A&A 395, 1077, Sec. 5.1.1, "TAN").
With the sensor frame ``(b, r, u)`` — boresight, image right, image up — a direction
``s`` has tangent-plane coordinates ``xi = (s.r)/(s.b)``, ``eta = (s.u)/(s.b)`` and pixel
coordinates ``x = cx + xi f/p``, ``y = cy - eta f/p`` (pitch ``p``; rows grow downwards;
``(cx, cy)`` is the focal-plane centre, see :mod:`evsda.blocks.ports.core`). Working
with vectors avoids the azimuth wrap at 0/360 deg and the singularity at the zenith
that comparing azimuth/elevation boxes suffers.
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.ports import FocalPlane


def centre(focal_plane: FocalPlane) -> tuple[float, float]:
    """Pixel coordinates ``(cx, cy)`` of the boresight."""
    return (focal_plane.width_px - 1) / 2.0, (focal_plane.height_px - 1) / 2.0


def tangent_plane(sb, sr, su) -> tuple[np.ndarray, np.ndarray]:
    """Gnomonic coordinates ``(xi, eta)`` [rad-equivalent] from the direction's dot products.

    ``NaN`` for directions in the back hemisphere (``s.b <= 0``), which the projection
    cannot image.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        front = sb > 0
        xi = np.where(front, sr / sb, np.nan)
        eta = np.where(front, su / sb, np.nan)
    return xi, eta


def to_pixels(xi, eta, focal_plane: FocalPlane) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates ``(x, y)`` of tangent-plane coordinates."""
    cx, cy = centre(focal_plane)
    scale = 1.0 / focal_plane.pixel_scale_rad
    return cx + xi * scale, cy - eta * scale


def from_pixels(x, y, focal_plane: FocalPlane) -> tuple[np.ndarray, np.ndarray]:
    """Tangent-plane coordinates ``(xi, eta)`` of pixel coordinates (inverse of :func:`to_pixels`)."""
    cx, cy = centre(focal_plane)
    scale = focal_plane.pixel_scale_rad
    return (np.asarray(x) - cx) * scale, (cy - np.asarray(y)) * scale


def project(directions: np.ndarray, b: np.ndarray, r: np.ndarray, u: np.ndarray,
            focal_plane: FocalPlane) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of one direction per sample (all arrays ``[n, 3]``)."""
    dots = [np.einsum("ij,ij->i", directions, axis) for axis in (b, r, u)]
    return to_pixels(*tangent_plane(*dots), focal_plane)


def deproject(x, y, b: np.ndarray, r: np.ndarray, u: np.ndarray, focal_plane: FocalPlane) -> np.ndarray:
    """Unit direction vectors of pixel coordinates (inverse gnomonic projection)."""
    xi, eta = from_pixels(x, y, focal_plane)
    v = b + np.asarray(xi)[..., None] * r + np.asarray(eta)[..., None] * u
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def inside(x, y, focal_plane: FocalPlane) -> np.ndarray:
    """Whether pixel coordinates fall on the detector (pixel ``c`` covers ``[c - 0.5, c + 0.5)``)."""
    with np.errstate(invalid="ignore"):
        return (x >= -0.5) & (x < focal_plane.width_px - 0.5) & (y >= -0.5) & (y < focal_plane.height_px - 0.5)


def half_extent_rad(focal_plane: FocalPlane) -> tuple[float, float]:
    """Tangent-plane half-width and half-height of the detector (edges of the outer pixels)."""
    scale = focal_plane.pixel_scale_rad
    return focal_plane.width_px / 2.0 * scale, focal_plane.height_px / 2.0 * scale


def radius_rad(focal_plane: FocalPlane) -> float:
    """Angle from the boresight to a detector corner [rad]."""
    half_w, half_h = half_extent_rad(focal_plane)
    return float(np.arctan(np.hypot(half_w, half_h)))


def angle_outside(xi, eta, sb, focal_plane: FocalPlane, b, r, u, s) -> np.ndarray:
    """Angle [rad] from direction ``s`` to the nearest point of the detector's field (0 inside).

    In the front hemisphere the nearest point is found on the tangent-plane rectangle;
    behind the sensor it is the angle to the boresight minus the field's corner radius.
    """
    half_w, half_h = half_extent_rad(focal_plane)
    front = np.isfinite(xi)
    xi_c = np.clip(np.where(front, xi, 0.0), -half_w, half_w)
    eta_c = np.clip(np.where(front, eta, 0.0), -half_h, half_h)
    nearest = b + xi_c[..., None] * r + eta_c[..., None] * u
    nearest /= np.linalg.norm(nearest, axis=-1, keepdims=True)
    to_edge = np.arccos(np.clip(np.sum(nearest * s, axis=-1), -1.0, 1.0))
    behind = np.arccos(np.clip(sb, -1.0, 1.0)) - radius_rad(focal_plane)
    return np.where(front, to_edge, np.maximum(behind, 0.0))
