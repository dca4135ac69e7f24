"""Equivalent layers: a Cn^2 profile rendered as fewer thin layers (the ``equivalent_layers`` parameter).

Each layer of a profile costs the pupil path its own phase screens for every source, so a profile of ``L``
layers costs ``L`` screens' walks. Adaptive-optics work lumps a profile into fewer *equivalent turbulent
layers* (Fusco et al. 1999, Proc. SPIE 3763, doi:10.1117/12.363606; Fusco et al. 2001, J. Opt. Soc. Am. A 18,
2527; compared with other compressions by Saxenhuber et al. 2017, Appl. Opt. 56, 2621,
doi:10.1364/AO.56.002621; the rule below as AOtools' ``turbulence.profile_compression.equivalent_layers``
implements it): the layers, sorted by altitude, are split into ``N`` groups of neighbours, and each group
becomes one layer with

* the group's summed turbulence integral ``J = sum_i J_i`` (``J = Cn^2 dh``), so every ``r0`` (the whole
  path's, ``r0 = (0.423 k^2 sec(zeta) sum J)^(-3/5)``, Hardy 1998 Eq. 3.40) is kept exactly;
* the 5/3-moment altitude ``h = (sum_i J_i h_i^(5/3) / J)^(3/5)`` (Fusco et al. 1999's equivalent layer), so
  the isoplanatic angle ``theta0 ~ (sum J h^(5/3))^(-3/5)`` (Fried 1982; Hardy 1998 Eq. 3.61) is kept exactly;
* the 5/3-moment wind speed ``|v| = (sum_i J_i |v_i|^(5/3) / J)^(3/5)`` (as AOtools' ``equivalent_layers``
  does for the coherence time), in the direction of the ``J |v|^(5/3)``-weighted mean of the layers' wind
  directions.

What that keeps for a point's phase in frozen flow: each layer's footprint moves at ``u_i = h_i s' - v_i``
(:mod:`.imaging`: ``s'`` the rate of the line of sight's crossing per metre of altitude, zero for a star fixed
in the ground frame, ``~ sec(z) omega`` for a mount slewing at ``omega``), and the phase's temporal structure
function of Kolmogorov layers is ``D(tau) = 6.88 sum_i (|u_i| tau / r0_i)^(5/3)`` (Fried 1966; Roddier 1981,
Prog. Optics 19, 281), i.e. ``6.88 (0.423 k^2 sec z)(sum_i J_i |u_i|^(5/3)) tau^(5/3)``. A star's
(``s' = 0``) is kept exactly by the wind moment, and so is its coherence time ``tau0 = 0.314 r0 / v_bar``; a
slewed footprint's is not (``sum J |h s' - v|^(5/3)`` mixes the slew and the wind: no common group wind keeps
it for every ``s'``). So each source gets its own winds (:func:`footprint_winds`; every source walks its own
screens, :mod:`.pupil_path`): for the source's ``s'``, group ``g``'s footprint moves at ``u_g`` with
``J_g |u_g|^(5/3) = sum_i J_i |u_i|^(5/3)`` over its members, in the direction of ``sum_i J_i |u_i|^(5/3)
u_i / |u_i|``, i.e. at the wind ``w_g = h_g s' - u_g``: **every source's ``D(tau)`` and ``tau0`` are kept
exactly** (at ``s' = 0`` the group wind above), at the ``s'`` of its first two render times, or with the
optics' ``follow_sight_rate`` at each render time's (:func:`follow_drift`: a long pass's ``s'`` changes). Not
kept: other altitude moments (the scintillation's ``sum J h^(5/6)`` and ``sum J h^2``, Roddier 1981), the outer
scale's cut at long lags, and aperture-filtered statistics such as the image motion's temporal spectrum (these weigh
the layers' speeds by other powers).
docs/optics.md, "Equivalent layers", gives this profile's figures.

How many: ``equivalent_layers: auto`` (:func:`auto_layers`) takes the fewest groups, at least
:data:`AUTO_FEWEST`, that keep, besides the moments
above, each of three that no group keeps within :data:`AUTO_TOLERANCE` of the full profile's: the scintillation's
altitude moments ``sum J h^(5/6)`` (small apertures: the Rytov variance, Roddier 1981; Andrews & Phillips 2005
Eq. 12.38; the path probes' scintillation term reads the compressed profile) and ``sum J h^2`` (large apertures,
Dravins et al. 1997 Eq. 10), and a star's image-motion rate, ``sum J |v|^2`` (an aperture average is smooth, so at
lags below ``D / v`` its structure function weighs the speeds by ``v^2``: Tyler 1994, J. Opt. Soc. Am. A 11, 358).

Which groups: the split of the sorted layers into ``N`` neighbours' groups that minimises the optimal-grouping
cost of Saxenhuber et al. (2017), ``sum_groups sum_i J_i |h_i - h_group|``, with the equivalent altitude as the
group's: the cost adds over groups, so dynamic programming over the split points finds the exact minimum
(Bellman 1957, *Dynamic Programming*) where Saxenhuber et al. search locally.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numba
import numpy as np

from .atmosphere import Atmosphere, Layer

#: ``equivalent_layers: auto`` keeps :func:`kept_moments` within this fraction of the full profile's [1]: median_seeing
#: in 3 groups (the fewest within it) is off by +6.3 % (``sum J h^(5/6)``), -2.2 % and -2.1 %, and its tracked pass
#: keeps every statistic of benchmarks/speed_vs_error.py within the every-layer noise floor (docs/speed.md)
AUTO_TOLERANCE = 0.1
#: and takes at least this many groups [1]: 3 kept the tracked pass within the every-layer noise floor on five
#: profiles; mauna_kea in 2 (within the tolerance) scattered its stars' counts past it (docs/speed.md)
AUTO_FEWEST = 3

jit = numba.njit(cache=True, error_model="numpy", nogil=True)


def moment(weights: np.ndarray, values: np.ndarray) -> float:
    """The ``weights``-weighted 5/3-moment ``(sum w |x|^(5/3) / sum w)^(3/5)`` of ``values`` [their unit]; the
    unweighted one where the weights sum to zero (layers without turbulence)."""
    weights, values = np.asarray(weights, dtype=float), np.abs(np.asarray(values, dtype=float))
    if np.sum(weights) <= 0:
        weights = np.ones_like(values)
    return float((np.sum(weights * values ** (5 / 3)) / np.sum(weights)) ** (3 / 5))


def equivalent_layer(layers: tuple[Layer, ...]) -> Layer:
    """One layer for ``layers``: their summed ``J``, the 5/3-moment altitude and wind speed, and the
    ``J |v|^(5/3)``-weighted mean wind direction (module docstring)."""
    cn2 = np.array([layer.cn2_dh for layer in layers])
    speed = np.array([layer.wind_speed_m_s for layer in layers])
    direction = np.array([layer.wind_direction_rad for layer in layers])
    weight = cn2 * speed ** (5 / 3)
    mean_direction = (float(np.arctan2(np.sum(weight * np.sin(direction)), np.sum(weight * np.cos(direction))))
                      if np.sum(weight) > 0 else float(direction[np.argmax(cn2)]))
    return Layer(moment(cn2, [layer.altitude_m for layer in layers]), float(np.sum(cn2)), moment(cn2, speed),
                 mean_direction)


def footprint_winds(atmosphere: Atmosphere, sight_rate) -> np.ndarray:
    """The winds (L, 2) [m/s] that carry a source's footprints through the layers of an equivalent ``atmosphere``
    (:attr:`.Atmosphere.members` set) for its line of sight crossing them at ``sight_rate`` ``s'`` (2,) [1/s] per
    metre of altitude: each group's ``w_g = h_g s' - u_g``, ``|u_g|`` the ``J``-weighted 5/3-moment of its members'
    footprint speeds ``|h_i s' - v_i|`` and its direction that of ``sum_i J_i |u_i|^(5/3) u_i / |u_i|`` (module
    docstring; the members' strongest layer's where that sum vanishes): :func:`group_winds`, which
    :func:`follow_drift` calls at every render time."""
    rate = np.asarray(sight_rate, dtype=float)
    winds = np.empty((len(atmosphere.layers), 2))
    group_winds(*member_columns(atmosphere), float(rate[0]), float(rate[1]), winds)
    return winds


def member_columns(atmosphere: Atmosphere) -> tuple[np.ndarray, ...]:
    """An equivalent ``atmosphere``'s groups and members as :func:`group_winds` reads them: each group's altitude
    (G,) [m], where its members start and end in the members' columns (G + 1,), the members' altitudes (M,) [m],
    ``J`` (M,) [m^(1/3)] and winds (M, 2) [m/s], and what is fixed per group (:func:`group_weights`)."""
    members = [member for group in atmosphere.members for member in group]
    first = np.cumsum([0, *(len(group) for group in atmosphere.members)]).astype(np.int64)
    cn2 = np.array([member.cn2_dh for member in members])
    return (np.array([layer.altitude_m for layer in atmosphere.layers]), first,
            np.array([member.altitude_m for member in members]), cn2,
            np.ascontiguousarray([member.wind_m_s for member in members], dtype=float).reshape(len(members), 2),
            *group_weights(first, cn2))


def group_weights(first: np.ndarray, cn2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`group_winds` needs of each group whatever the line of sight: its members' weights (M,)
    [m^(1/3)] in the 5/3-moment of their footprint speeds, their ``J`` (1 each where the group's ``J`` do not sum
    above zero: the unweighted moment, as :func:`moment`), the weights' sum (G,) added in the members' order (their
    count where unweighted), and its strongest member (G,), the first of the largest ``J``, whose footprint sets the
    direction where the members' pull vanishes. Once per atmosphere, so in Python, whose floats add as the compiled
    code's."""
    weight, weights, strongest = np.empty_like(cn2), np.zeros(len(first) - 1), first[:-1].copy()
    for g, (start, end) in enumerate(zip(first[:-1].tolist(), first[1:].tolist())):
        group = cn2[start:end].tolist()
        total = 0.0
        for j in group:
            total += j
        strongest[g] += group.index(max(group))
        weight[start:end], weights[g] = (group, total) if total > 0 else (1.0, end - start)
    return weight, weights, strongest


@jit
def group_winds(group_altitude, first, altitude, cn2, wind, weight, weights, strongest, rx, ry, winds):
    """Each group's wind ``w_g = h_g s' - u_g`` into ``winds`` (G, 2) [m/s] for the line of sight's rate ``s' =
    (rx, ry)`` [1/s] (:func:`footprint_winds`): ``|u_g| = (sum_i J_i |u_i|^(5/3) / J_g)^(3/5)`` over its members'
    footprint velocities ``u_i = h_i s' - v_i``, in the direction of ``sum_i J_i |u_i|^(2/3) u_i`` (its strongest
    member's ``u_i`` where that vanishes; no motion where that is zero too). Columns: :func:`member_columns`.
    ``|u|^(5/3)`` is taken as ``|u| |u|^(2/3)``, one power for both sums; the sums add the members in order."""
    for g in range(group_altitude.shape[0]):
        moment, pull_x, pull_y = 0.0, 0.0, 0.0
        for m in range(first[g], first[g + 1]):
            ux, uy = altitude[m] * rx - wind[m, 0], altitude[m] * ry - wind[m, 1]
            speed = math.hypot(ux, uy)
            two_thirds = speed ** (2 / 3)
            moment += weight[m] * (speed * two_thirds)
            pull_x += cn2[m] * two_thirds * ux
            pull_y += cn2[m] * two_thirds * uy
        if pull_x == 0.0 and pull_y == 0.0:
            pull_x = altitude[strongest[g]] * rx - wind[strongest[g], 0]
            pull_y = altitude[strongest[g]] * ry - wind[strongest[g], 1]
        norm = math.hypot(pull_x, pull_y)
        speed = (moment / weights[g]) ** (3 / 5)
        fx, fy = (speed * pull_x / norm, speed * pull_y / norm) if norm > 0 else (0.0, 0.0)
        winds[g, 0], winds[g, 1] = group_altitude[g] * rx - fx, group_altitude[g] * ry - fy


@jit
def follow_drift(group_altitude, first, altitude, cn2, wind, weight, weights, strongest, t_s, sight, last_t,
                 last_sight, drift, winds, out):
    """Each group's footprint drift (G, F, 2) [m] into ``out`` for a source followed at its line of sight's rate
    (``follow_sight_rate``): its footprint sits at ``h_g sight - drift_g``, and from one render time to the next
    the drift grows by ``w_g dt``, ``w_g`` :func:`group_winds` for the secant rate
    ``s' = (sight_k - sight_(k-1)) / dt`` (0 where not finite), so that each step moves the footprint by
    ``u_g dt`` with ``J_g |u_g|^(5/3) = sum_i J_i |h_i s' - v_i|^(5/3)`` (module docstring; Fried 1966; Roddier
    1981) at every render time, not only at the first two.

    ``group_altitude`` ... ``strongest``: :func:`member_columns`; ``t_s`` (F,) [s] and ``sight`` (F, 2) [1] these
    render times' lines of sight; ``last_t`` [s], ``last_sight`` (2,), ``drift`` (G, 2) and ``winds`` (G, 2) the
    source's state at its last render time, advanced in place (a frame at or before it is extrapolated with its
    winds and advances nothing). Frame by frame in order, so the same numbers however the render times are cut
    into calls. Returns the last render time and the frames that advanced it."""
    advanced = 0
    for f in range(t_s.shape[0]):
        dt = t_s[f] - last_t
        if dt > 0:
            rx, ry = (sight[f, 0] - last_sight[0]) / dt, (sight[f, 1] - last_sight[1]) / dt
            rx, ry = rx if math.isfinite(rx) else 0.0, ry if math.isfinite(ry) else 0.0
            group_winds(group_altitude, first, altitude, cn2, wind, weight, weights, strongest, rx, ry, winds)
            for g in range(group_altitude.shape[0]):
                drift[g, 0] += winds[g, 0] * dt
                drift[g, 1] += winds[g, 1] * dt
                out[g, f, 0], out[g, f, 1] = drift[g, 0], drift[g, 1]
            last_t, last_sight[0], last_sight[1] = t_s[f], sight[f, 0], sight[f, 1]
            advanced += 1
        else:
            for g in range(group_altitude.shape[0]):
                out[g, f, 0], out[g, f, 1] = drift[g, 0] + winds[g, 0] * dt, drift[g, 1] + winds[g, 1] * dt
    return last_t, advanced


def group_cost(altitude: np.ndarray, cn2: np.ndarray) -> float:
    """Saxenhuber et al. (2017)'s grouping cost of one group, ``sum_i J_i |h_i - h_eq|`` [m^(4/3)], ``h_eq`` the
    5/3-moment altitude."""
    return float(np.sum(cn2 * np.abs(altitude - moment(cn2, altitude))))


def best_groups(altitude: np.ndarray, cn2: np.ndarray, n_groups: int) -> list[range]:
    """The split of layers sorted by ``altitude`` into ``n_groups`` runs of neighbours with the least summed
    :func:`group_cost`, by dynamic programming over the split points (index ranges into the sorted layers)."""
    count = len(altitude)
    cost = [[group_cost(altitude[i:j], cn2[i:j]) if j > i else np.inf for j in range(count + 1)]
            for i in range(count + 1)]
    best = np.full((n_groups + 1, count + 1), np.inf)          # best[g, j]: the first j layers in g groups
    start = np.zeros((n_groups + 1, count + 1), dtype=int)
    best[0, 0] = 0.0
    for groups in range(1, n_groups + 1):
        for end in range(groups, count + 1):
            totals = [best[groups - 1, i] + cost[i][end] for i in range(groups - 1, end)]
            choice = int(np.argmin(totals))
            best[groups, end], start[groups, end] = totals[choice], groups - 1 + choice
    runs, end = [], count
    for groups in range(n_groups, 0, -1):
        runs.append(range(start[groups, end], end))
        end = start[groups, end]
    return runs[::-1]


def kept_moments(atmosphere: Atmosphere) -> np.ndarray:
    """``sum J h^(5/6)`` [m^(1/3) m^(5/6)], ``sum J h^2`` [m^(1/3) m^2] and ``sum J |v|^2`` [m^(1/3) (m/s)^2] of the
    layers: what :func:`auto_layers` keeps (module docstring)."""
    cn2 = np.array([layer.cn2_dh for layer in atmosphere.layers])
    altitude = np.array([layer.altitude_m for layer in atmosphere.layers])
    speed = np.array([layer.wind_speed_m_s for layer in atmosphere.layers])
    return np.array([np.sum(cn2 * altitude ** (5 / 6)), np.sum(cn2 * altitude**2), np.sum(cn2 * speed**2)])


def auto_layers(atmosphere: Atmosphere, tolerance: float = AUTO_TOLERANCE, fewest: int = AUTO_FEWEST) -> int:
    """The fewest equivalent layers, ``fewest`` or more, whose :func:`kept_moments` are each within ``tolerance`` of
    ``atmosphere``'s [1]; its own count where no fewer are."""
    full = kept_moments(atmosphere)
    for count in range(fewest, len(atmosphere.layers)):
        if np.all(np.abs(kept_moments(equivalent_layers(atmosphere, count)) - full) <= tolerance * np.abs(full)):
            return count
    return len(atmosphere.layers)


def equivalent_layers(atmosphere: Atmosphere, n_layers: int | str) -> Atmosphere:
    """``atmosphere`` as ``n_layers`` equivalent layers (module docstring; ``"auto"``: :func:`auto_layers`'s
    count), each with its members (:attr:`.Atmosphere.members`, which :func:`footprint_winds` reads); unchanged (the
    same object) when it has that many layers or fewer."""
    if n_layers == "auto":
        n_layers = auto_layers(atmosphere)
    if n_layers < 1:
        raise ValueError(f"equivalent layers: n_layers must be at least 1, not {n_layers}")
    if len(atmosphere.layers) <= n_layers:
        return atmosphere
    layers = sorted(atmosphere.layers, key=lambda layer: layer.altitude_m)
    altitude = np.array([layer.altitude_m for layer in layers])
    cn2 = np.array([layer.cn2_dh for layer in layers])
    members = tuple(tuple(layers[i] for i in run) for run in best_groups(altitude, cn2, n_layers))
    return replace(atmosphere, layers=tuple(equivalent_layer(group) for group in members), members=members)
