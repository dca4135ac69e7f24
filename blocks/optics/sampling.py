"""Sampling constraints of point-source angular-spectrum propagation (Schmidt 2010 Sec. 8.4 and 9.4; Coy 2005).

For a source region ``D1`` (the sinc's central lobe, ``lambda Z / D_roi``) and an
observation region ``D2`` (the aperture), turbulence widens both (Schmidt 2010 Eq. 9.56):
``D1' = D1 + c lambda Z / r0`` (the source as seen through the seeing disc) and
``D2' = D2 + c lambda L / r0`` (the beam spread by the turbulent path ``L`` in front of
the observer; Schmidt puts turbulence along the whole path, ``L = Z``; here it sits in the
last ``L`` metres), ``c = 2``. A grid of ``N`` points spaced ``delta1`` (source) and
``delta_n`` (observation) must satisfy (Schmidt 2010 Eq. 8.29-8.33, Listing 9.5):

1. ``delta_n <= (lambda Z - D2' delta1) / D1'``  (no aliasing of the observed field);
2. ``N >= D1'/(2 delta1) + D2'/(2 delta_n) + lambda Z / (2 delta1 delta_n)``  (the grid holds both regions);
3. ``|delta_n - (1 + Z/R) delta1| <= lambda Z / D1'``  (the source-plane chirp is sampled); ``R`` is
   the source's curvature radius in the ``exp(+i pi r^2 / lambda R)`` convention, ``R = -Z`` for the
   converging chirp of paper Eq. 3 (Schmidt's Listing 9.5 uses ``R = Z``, which is only stricter);
4. each partial step ``dz_i <= N delta_i delta_(i+1) / lambda``  (the transfer function of step ``i``
   is sampled; Schmidt states the stricter ``min(delta1, delta_n)^2 N / lambda`` for all steps), plus
5. ``delta1 <= D1 / 2``  (the source itself is sampled, so the field is the Eq. 3 source).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft as sfft

from evsda.graph import ParameterError

from .propagation import plane_spacings

#: turbulence widening factor c of Schmidt 2010 Eq. 9.56 [1]
WIDENING = 2.0


@dataclass(frozen=True)
class PropagationGeometry:
    """What a point-source propagation must represent."""

    wavelength_m: float
    distance_m: float                     # source to aperture, Z [m]
    aperture_m: float                     # observation region D2 [m]
    roi_factor: float = 4.0               # D_roi = roi_factor * D2 (Schmidt 2010 Listing 9.5)
    r0_m: float = np.inf                  # Fried parameter of the path [m]
    turbulence_length_m: float = 0.0      # distance from the aperture to the farthest layer [m]
    source_curvature_m: float = field(default=np.nan)   # R; NaN means the point source's -Z

    @property
    def roi_m(self) -> float:
        return self.roi_factor * self.aperture_m

    @property
    def source_lobe_m(self) -> float:
        """``D1 = lambda Z / D_roi`` [m]."""
        return self.wavelength_m * self.distance_m / self.roi_m

    @property
    def widened(self) -> tuple[float, float]:
        """``(D1', D2')`` [m]."""
        lz = self.wavelength_m * self.distance_m
        spread = 0.0 if np.isinf(self.r0_m) else WIDENING * self.wavelength_m / self.r0_m
        return self.source_lobe_m + spread * self.distance_m, self.aperture_m + spread * self.turbulence_length_m

    @property
    def curvature_factor(self) -> float:
        """``1 + Z/R`` of constraint 3 [1]."""
        radius = -self.distance_m if np.isnan(self.source_curvature_m) else self.source_curvature_m
        return 1.0 + self.distance_m / radius


@dataclass(frozen=True)
class PropagationGrid:
    n: int
    delta1_m: float
    deltan_m: float
    planes_m: tuple[float, ...]          # positions after the source [m]; the last is the aperture

    @property
    def spacings_m(self) -> np.ndarray:
        return plane_spacings(self.delta1_m, self.deltan_m, self.planes_m)

    def describe(self) -> str:
        return (f"N = {self.n}, delta1 = {self.delta1_m:.4g} m, delta_n = {self.deltan_m:.4g} m, "
                f"{len(self.planes_m)} steps")


def violations(geometry: PropagationGeometry, grid: PropagationGrid) -> list[str]:
    """Each failed constraint as a phrase; empty when the grid is valid."""
    lz = geometry.wavelength_m * geometry.distance_m
    d1p, d2p = geometry.widened
    d1, dn, n = grid.delta1_m, grid.deltan_m, grid.n
    tol = 1e-12
    out = []
    limit = (lz - d2p * d1) / d1p
    if dn > limit * (1 + tol):
        out.append(f"constraint 1 (no aliasing) needs delta_n <= {limit:.4g} m, got {dn:.4g} m")
    needed = d1p / (2 * d1) + d2p / (2 * dn) + lz / (2 * d1 * dn)
    if n < needed * (1 - tol):
        out.append(f"constraint 2 (grid size) needs N >= {needed:.1f}, got {n}")
    centre = geometry.curvature_factor * d1
    if abs(dn - centre) > lz / d1p * (1 + tol):
        out.append(f"constraint 3 (source chirp) needs |delta_n - {geometry.curvature_factor:.3g} delta1| "
                   f"<= {lz / d1p:.4g} m")
    spacing = grid.spacings_m
    steps = np.diff(np.r_[0.0, grid.planes_m])
    allowed = n * spacing[:-1] * spacing[1:] / geometry.wavelength_m
    worst = int(np.argmax(steps / allowed))
    if steps[worst] > allowed[worst] * (1 + tol):
        out.append(f"constraint 4 (step length) needs step {worst + 1} <= {allowed[worst]:.4g} m, "
                   f"got {steps[worst]:.4g} m")
    if d1 > geometry.source_lobe_m / 2 * (1 + tol):
        out.append(f"the source lobe D1 = {geometry.source_lobe_m:.4g} m needs delta1 <= "
                   f"{geometry.source_lobe_m / 2:.4g} m, got {d1:.4g} m")
    return out


def choose_grid(geometry: PropagationGeometry, deltan_m: float, layer_planes_m=()) -> PropagationGrid:
    """The smallest valid grid with observation spacing ``deltan_m`` and planes at ``layer_planes_m``.

    ``delta1`` is the largest the constraints allow (it shrinks ``N`` in constraint 2), ``N``
    the next FFT-friendly even size, and vacuum planes are inserted where constraint 4 fails.
    Raises ``ValueError`` when no ``delta1`` works with this ``delta_n``.
    """
    lz = geometry.wavelength_m * geometry.distance_m
    d1p, d2p = geometry.widened
    if deltan_m > lz / d1p:
        raise ValueError(f"delta_n = {deltan_m:.4g} m exceeds lambda Z / D1' = {lz / d1p:.4g} m")
    candidates = [(lz - deltan_m * d1p) / d2p, geometry.source_lobe_m / 2]
    factor = geometry.curvature_factor
    if factor > 0:
        candidates.append((deltan_m + lz / d1p) / factor)
    delta1 = min(candidates)
    if delta1 <= 0 or (factor < 0 and abs(deltan_m - factor * delta1) > lz / d1p):
        raise ValueError(f"no source spacing satisfies constraints 1 and 3 with delta_n = {deltan_m:.4g} m")
    needed = d1p / (2 * delta1) + d2p / (2 * deltan_m) + lz / (2 * delta1 * deltan_m)
    n = int(np.ceil(needed))
    n = sfft.next_fast_len(n + n % 2)
    while n % 2:
        n = sfft.next_fast_len(n + 1)
    planes = planes_for(geometry, n, delta1, deltan_m, layer_planes_m)
    return PropagationGrid(n, delta1, deltan_m, planes)


def planes_for(geometry: PropagationGeometry, n: int, delta1: float, deltan: float,
               layer_planes=()) -> tuple[float, ...]:
    """Layer planes plus the aperture, with vacuum planes added until every step meets constraint 4."""
    total = geometry.distance_m
    planes = sorted({float(z) for z in layer_planes if 0.0 < z < total} | {total})
    lam = geometry.wavelength_m
    out = []
    start = 0.0
    for end in planes:
        while True:
            d_start = delta1 + (deltan - delta1) * start / total
            allowed = n * d_start * (delta1 + (deltan - delta1) * end / total) / lam
            if end - start <= allowed:
                break
            # largest step from `start` that meets the constraint, solving n d(s) d(s+dz) / lam = dz
            slope = (deltan - delta1) / total
            a = n * d_start * slope / lam
            step = n * d_start * d_start / lam / (1 - a) if a < 1 else end - start
            step = min(step, end - start) * (1 - 1e-9)
            if step <= 0:
                raise ValueError("constraint 4 cannot be met on this grid")
            start += step
            out.append(start)
        out.append(end)
        start = end
    return tuple(out)


def check_grid(geometry: PropagationGeometry, grid: PropagationGrid, where: str) -> None:
    """Raise one ParameterError naming the failed constraint and a grid that would satisfy it."""
    problems = violations(geometry, grid)
    if not problems:
        return
    try:
        suggestion = choose_grid(geometry, min(grid.deltan_m, geometry.wavelength_m * geometry.distance_m
                                               / geometry.widened[0]))
        hint = f"; a valid grid is {suggestion.describe()}"
    except ValueError:
        hint = ""
    raise ParameterError(f"{where}: the propagation grid ({grid.describe()}) would alias: "
                         f"{problems[0]}{hint}")
