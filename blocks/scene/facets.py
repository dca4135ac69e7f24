"""Facet models: a satellite or rocket body as flat facets, each with its own BRDF (diffuse + specular).

A model is a body (a cylinder with end caps, or a box) plus any number of flat plates,
all in the body frame. Sunlight reflected towards the observer is the sum over the
facets that face both the Sun and the observer (:mod:`.brdf`)::

    R = sum_i A_i f_i(s, o) (n_i.s)(n_i.o)        [m^2 sr^-1]

so that the intensity is ``E_sun R`` and the photon flux at range ``d`` is
``N_sun R / d^2`` (``R`` replaces ``rho A F`` of a sphere or plate, paper Eq. 1-2).
Shadowing and occlusion of one part by another are not modelled: exact for a lone
convex body (a cylinder with its caps, a box), an approximation once plates stick out.

A cylinder's curved side is ``n_sides`` facets of equal area ``2 pi r L / n_sides``; by
default ``n_sides`` follows the sharpest specular lobe on it (the facets' normals are
then closer than the lobe's width, so a smooth cylinder stays smooth) and is at least
72, which puts a diffuse cylinder within 0.1 % of the exact integral (tested).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from . import brdf

MIN_CYLINDER_SIDES = 72
MAX_CYLINDER_SIDES = 20_000


class _Spec(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class BrdfSpec(_Spec):
    """How a surface reflects: a diffuse albedo and a specular lobe (see :mod:`evsda.blocks.scene.brdf`)."""

    model: Literal["lambert", "phong", "ashikhmin_shirley"] = Field(
        "phong", description="BRDF: Lambertian, energy-conserving modified Phong, or Ashikhmin-Shirley [-]")
    diffuse_albedo: float = Field(0.2, ge=0, le=1, description="Diffuse reflectance rho_d (Phong), R_d "
                                  "(Ashikhmin-Shirley) or the Lambertian albedo [1]")
    specular_albedo: float = Field(0.0, ge=0, le=1, description="Specular reflectance rho_s (Phong) or the "
                                   "normal-incidence Fresnel reflectance R_s (Ashikhmin-Shirley) [1]")
    specular_exponent: float = Field(100.0, ge=0, le=1e7, description="Lobe exponent m: lobe width about "
                                     "1/sqrt(m) rad (blurred by the Sun's disc above ~2e5) [1]")

    @model_validator(mode="after")
    def _conserves_energy(self):
        if self.model == "phong" and self.diffuse_albedo + self.specular_albedo > 1.0 + 1e-12:
            raise ValueError(f"a Phong surface reflecting more than it receives: diffuse_albedo + specular_albedo "
                             f"= {self.diffuse_albedo + self.specular_albedo:g} > 1")
        if self.model == "lambert" and self.specular_albedo > 0:
            raise ValueError("a Lambertian surface has no specular term; use model phong or ashikhmin_shirley")
        return self


def _unit_vector(value: tuple[float, float, float]) -> tuple[float, float, float]:
    length = math.sqrt(sum(v * v for v in value))
    if not all(math.isfinite(v) for v in value) or abs(length - 1.0) > 1e-3:
        usable = math.isfinite(length) and length > 0
        hint = f"; did you mean {[round(v / length, 4) for v in value]}?" if usable else ""
        raise ValueError(f"a facet normal must be a unit vector in the body frame (got {list(value)}, length "
                         f"{length:.4g}){hint}")
    return tuple(v / length for v in value)


class PlateSpec(_Spec):
    """A flat, one-sided plate (e.g. a solar panel's front; add a second plate for its back)."""

    area_m2: float = Field(gt=0, le=1e5, description="Plate area [m^2]")
    normal: tuple[float, float, float] = Field(description="Unit normal of the reflecting side, body frame [1]")
    brdf: BrdfSpec = Field(default_factory=BrdfSpec, description="Surface reflectance [-]")

    _normal_is_unit = field_validator("normal")(_unit_vector)


class CylinderSpec(_Spec):
    """A cylinder along the body z axis (e.g. a rocket stage), centred on the body origin."""

    radius_m: float = Field(gt=0, le=100, description="Radius [m]")
    length_m: float = Field(gt=0, le=500, description="Length along body z [m]")
    brdf: BrdfSpec = Field(default_factory=BrdfSpec, description="Curved side's reflectance [-]")
    top_brdf: BrdfSpec | None = Field(None, description="Reflectance of the +z end cap (default: the side's) [-]")
    bottom_brdf: BrdfSpec | None = Field(None, description="Reflectance of the -z end cap (default: the side's) [-]")
    end_caps: bool = Field(True, description="Close the ends with flat discs [-]")
    n_sides: int | None = Field(None, ge=8, le=MAX_CYLINDER_SIDES, description="Facets around the side "
                                "(default: from the sharpest specular lobe, at least 72) [1]")


class BoxSpec(_Spec):
    """A rectangular box along the body axes (e.g. a satellite bus), centred on the body origin."""

    size_m: tuple[float, float, float] = Field(description="Edge lengths along body x, y, z [m]")
    brdf: BrdfSpec = Field(default_factory=BrdfSpec, description="Surface reflectance of all six faces [-]")

    @field_validator("size_m")
    @classmethod
    def _positive(cls, value):
        if not all(math.isfinite(v) and 0 < v <= 500 for v in value):
            raise ValueError(f"box edges must be positive lengths up to 500 m (got {list(value)})")
        return value


class FacetModelSpec(_Spec):
    """A body (cylinder or box, optional) plus flat plates, in the body frame."""

    cylinder: CylinderSpec | None = Field(None, description="A cylindrical body along body z [-]")
    box: BoxSpec | None = Field(None, description="A box-shaped body [-]")
    plates: list[PlateSpec] = Field(default_factory=list, description="Flat plates [-]")

    @model_validator(mode="after")
    def _has_a_surface(self):
        if self.cylinder is None and self.box is None and not self.plates:
            raise ValueError("a facet model needs a cylinder, a box or at least one plate")
        if self.cylinder is not None and self.box is not None:
            raise ValueError("give one body (cylinder or box); add plates for the rest")
        return self


@dataclass(frozen=True)
class FacetModel:
    """Facets as arrays: area ``[F]``, unit normal ``[F, 3]`` (body frame), BRDF model and parameters ``[F]``."""

    area_m2: np.ndarray
    normal: np.ndarray
    model: np.ndarray
    diffuse_albedo: np.ndarray
    specular_albedo: np.ndarray
    specular_exponent: np.ndarray

    @property
    def n_facets(self) -> int:
        return len(self.area_m2)

    def reflectance_m2_sr(self, to_sun_body: np.ndarray, to_observer_body: np.ndarray) -> np.ndarray:
        """``R = sum A f (n.s)(n.o)`` over facets facing both directions [m^2 sr^-1]; unit vectors ``[n, 3]``."""
        cos_s = to_sun_body @ self.normal.T
        cos_o = to_observer_body @ self.normal.T
        cos_so = np.einsum("ij,ij->i", to_sun_body, to_observer_body)[:, None]
        facing = (cos_s > 0) & (cos_o > 0)
        total = np.zeros(len(to_sun_body))
        for kind in np.unique(self.model):
            k = self.model == kind
            cs, co = np.where(facing[:, k], cos_s[:, k], 0.0), np.where(facing[:, k], cos_o[:, k], 0.0)
            f = brdf.evaluate(kind, self.diffuse_albedo[k], self.specular_albedo[k], self.specular_exponent[k],
                              cs, co, cos_so)
            total += np.sum(np.where(facing[:, k], self.area_m2[k] * f * cs * co, 0.0), axis=1)
        return total


def cylinder_sides(spec: CylinderSpec) -> int:
    """Facets around a cylinder: normals at most one lobe width (1 sigma, in normal angle) apart, >= 72.

    A Gaussian lobe sampled every sigma sums to a flat curve within 1e-8 (Poisson
    summation), so a smooth cylinder spinning about its axis stays steady.
    """
    if spec.n_sides is not None:
        return spec.n_sides
    b = spec.brdf
    if b.model == "lambert" or b.specular_albedo == 0 or b.specular_exponent == 0:
        return MIN_CYLINDER_SIDES
    m = float(brdf.sun_blurred_exponent(b.specular_exponent, half_vector=b.model == "ashikhmin_shirley"))
    width_rad = 1.0 / math.sqrt(m) / (2.0 if b.model == "phong" else 1.0)   # lobe width in facet-normal angle
    return int(min(MAX_CYLINDER_SIDES, max(MIN_CYLINDER_SIDES, math.ceil(2.0 * math.pi / width_rad))))


def build(spec: FacetModelSpec) -> FacetModel:
    """The facets of a :class:`FacetModelSpec`."""
    rows: list[tuple[float, tuple, BrdfSpec]] = []
    if spec.cylinder is not None:
        c = spec.cylinder
        n = cylinder_sides(c)
        side_area = 2.0 * math.pi * c.radius_m * c.length_m / n
        for k in range(n):
            phi = 2.0 * math.pi * (k + 0.5) / n
            rows.append((side_area, (math.cos(phi), math.sin(phi), 0.0), c.brdf))
        if c.end_caps:
            cap = math.pi * c.radius_m**2
            rows.append((cap, (0.0, 0.0, 1.0), c.top_brdf or c.brdf))
            rows.append((cap, (0.0, 0.0, -1.0), c.bottom_brdf or c.brdf))
    if spec.box is not None:
        x, y, z = spec.box.size_m
        for area, axis in ((y * z, 0), (x * z, 1), (x * y, 2)):
            for sign in (1.0, -1.0):
                normal = [0.0, 0.0, 0.0]
                normal[axis] = sign
                rows.append((area, tuple(normal), spec.box.brdf))
    for plate in spec.plates:
        rows.append((plate.area_m2, plate.normal, plate.brdf))
    return FacetModel(
        area_m2=np.array([r[0] for r in rows]), normal=np.array([r[1] for r in rows], dtype=np.float64),
        model=np.array([r[2].model for r in rows]), diffuse_albedo=np.array([r[2].diffuse_albedo for r in rows]),
        specular_albedo=np.array([r[2].specular_albedo for r in rows]),
        specular_exponent=np.array([r[2].specular_exponent for r in rows]))


def lambertian_plate(area_m2: float, albedo: float) -> FacetModel:
    """One diffuse plate of normal body +z: the ``plate`` shape when it spins or tumbles."""
    return build(FacetModelSpec(plates=[PlateSpec(area_m2=area_m2, normal=(0.0, 0.0, 1.0),
                                                  brdf=BrdfSpec(model="lambert", diffuse_albedo=albedo))]))


def diffuse_cylinder_side_reference(radius_m: float, length_m: float, albedo: float, to_sun_body: np.ndarray,
                                    to_observer_body: np.ndarray) -> np.ndarray:
    """Exact ``R`` of a smooth Lambertian cylinder's side (axis body z) [m^2 sr^-1]: the facets' reference.

    With the directions' components ``s_p``, ``o_p`` across the axis and ``D`` the angle
    between them: ``R = rho/pi r L |s_p||o_p| ((pi - D) cos D + sin D) / 2``, the integral
    over azimuth of ``max(0, cos(phi - a)) max(0, cos(phi - b))``.
    """
    s_p, o_p = to_sun_body[:, :2], to_observer_body[:, :2]
    ns, no = np.linalg.norm(s_p, axis=1), np.linalg.norm(o_p, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.arccos(np.clip(np.einsum("ij,ij->i", s_p, o_p) / (ns * no), -1.0, 1.0))
    overlap = 0.5 * ((np.pi - d) * np.cos(d) + np.sin(d))
    return np.nan_to_num(albedo / np.pi * radius_m * length_m * ns * no * overlap)
