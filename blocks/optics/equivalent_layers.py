"""Equivalent layers: a Cn^2 profile rendered as fewer thin layers (the ``equivalent_layers`` parameter).

Each layer of a profile costs the pupil path its own phase screens for every source, so a profile of ``L``
layers costs ``L`` screens' walks. Adaptive-optics work lumps a profile into fewer *equivalent turbulent
layers* (Fusco et al. 1999, Proc. SPIE 3763, doi:10.1117/12.363606; Fusco et al. 2001, J. Opt. Soc. Am. A 18,
2527; compared with other compressions by Saxenhuber et al. 2017, Appl. Opt. 56, 2621,
doi:10.1364/AO.56.002621; the rule below as AOtools' ``turbulence.profile_compression.equivalent_layers``
implements it, here with second moments as well): the layers, sorted by altitude, are split into ``N`` groups of
neighbours, and each group becomes one layer with

* the group's summed turbulence integral ``J = sum_i J_i`` (``J = Cn^2 dh``), so every ``r0`` (the whole
  path's, ``r0 = (0.423 k^2 sec(zeta) sum J)^(-3/5)``, Hardy 1998 Eq. 3.40) is kept exactly;
* an altitude and a wind speed that keep the profile's moments of orders 5/3 **and** 2: the groups' 5/3
  moments ``x_g = (sum_i J_i x_i^(5/3) / J)^(3/5)`` (Fusco et al. 1999's equivalent layer; AOtools' winds)
  spread by one common power, ``lam x_g^kappa``, ``lam`` keeping ``sum J x^(5/3)`` and ``kappa >= 1`` (Brent's
  method) ``sum J x^2`` (:func:`spread_to_second_moment`). So ``theta0 ~ (sum J h^(5/3))^(-3/5)`` (Fried 1982;
  Hardy 1998 Eq. 3.61) and ``sum J h^2`` (the large-aperture scintillation index ``17.34 D^(-7/3) sec^3 z
  sum J h^2``, Dravins et al. 1997, PASP 109, 173, Eq. 10) are both kept exactly, and so are ``sum J |v|^(5/3)``
  and ``sum J |v|^2``. One group cannot keep both (a 5/3 mean is below the 2nd of unequal values: Hardy,
  Littlewood & Polya 1934, Thm. 16), and the groups keep them only together: where no ``kappa`` can (one group,
  or groups whose 5/3 moments are equal) the 5/3 moments are kept as they are;
* the direction of the ``J |v|^(5/3)``-weighted mean of the layers' wind directions.

Why both orders. Each layer's footprint moves at ``u_i = h_i s' - v_i`` (:mod:`.imaging`: ``s'`` the rate of the
line of sight's crossing per metre of altitude, zero for a star fixed in the ground frame, ``~ sec(z) omega`` for
a mount slewing at ``omega``). A point's phase has the temporal structure function ``D(tau) = 6.88 sum_i
(|u_i| tau / r0_i)^(5/3)`` (Fried 1966; Roddier 1981, Prog. Optics 19, 281), i.e. ``~ sum_i J_i |u_i|^(5/3)``:
a star's (``s' = 0``) and its ``tau0 = 0.314 r0 / v_bar`` are the 5/3 wind moment's. But a quantity averaged
over the aperture (the image motion, each Zernike mode, a pixel's irradiance) is smooth on the screens, so its
rate ``-sum_i u_i . grad`` has a variance that weighs each layer by ``J_i |u_i|^2`` (exactly for the linear ones:
the image motion's, Tyler 1994, JOSA A 11, 358, tracking frequency ``~ (sum J v^2)^(1/2)``; each Zernike mode's,
whose temporal spectrum falls as ``f^(-17/3)``, Conan et al. 1995, JOSA A 12, 1559), and an event pixel fires on its
log-irradiance's level crossings, whose rate grows with that rate's standard deviation (Rice 1945, Bell Syst.
Tech. J. 24, 46, Sec. 3.3). A star's ``sum J |v|^2`` is kept exactly; for a slewed source ``sum J |u|^2 =
|s'|^2 sum J h^2 - 2 s' . sum J h v + sum J |v|^2``, whose first and last terms are kept and whose cross term
is not (nor the anisotropic part of ``sum J v v^T`` where the winds differ in direction, nor the ``J``-weighted
mean wind, -0.5 % for ``median_seeing.csv`` in 3 groups). Not kept either: the weak-scintillation small-aperture
moment ``sum J h^(5/6)``, the outer scale's cut at long lags. docs/optics.md, "Equivalent layers", gives this
profile's figures.

Which groups: the split of the sorted layers into ``N`` neighbours' groups that minimises the optimal-grouping
cost of Saxenhuber et al. (2017), ``sum_groups sum_i J_i |h_i - h_group|``, with the group's 5/3-moment altitude as
``h_group``: the cost adds over groups, so dynamic programming over the split points finds the exact minimum
(Bellman 1957, *Dynamic Programming*) where Saxenhuber et al. search locally.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import brentq

from .atmosphere import Atmosphere, Layer


#: the orders of the profile's moments that the equivalent altitudes and wind speeds keep exactly (module docstring)
KEPT_ORDERS = (5 / 3, 2.0)
#: the largest common power that spreads the groups' values (:func:`spread_to_second_moment`) [1]
LARGEST_SPREAD = 20.0


def moment(weights: np.ndarray, values: np.ndarray, order: float = 5 / 3) -> float:
    """The ``weights``-weighted moment ``(sum w |x|^p / sum w)^(1/p)`` of order ``p`` of ``values`` [their unit]; the
    unweighted one where the weights sum to zero (layers without turbulence)."""
    weights, values = np.asarray(weights, dtype=float), np.abs(np.asarray(values, dtype=float))
    if np.sum(weights) <= 0:
        weights = np.ones_like(values)
    return float((np.sum(weights * values ** order) / np.sum(weights)) ** (1 / order))


def spread_to_second_moment(group_weights: np.ndarray, group_values: np.ndarray, weights: np.ndarray,
                            values: np.ndarray) -> np.ndarray:
    """The groups' values ``lam x_g^kappa`` [the values' unit] that keep both of the layers' sums
    ``sum w x^(5/3)`` and ``sum w x^2`` (:data:`KEPT_ORDERS`): ``x_g`` the groups' 5/3 moments (``group_values``,
    ``group_weights`` their summed weights), ``lam`` keeping the 5/3 sum, ``kappa`` (1 to :data:`LARGEST_SPREAD`,
    found by Brent's method) the second. ``x_g`` as they are where nothing within groups was lost (every group's
    layers alike) or no such ``kappa`` exists (one group, or groups with equal ``x_g``)."""
    first, second = (float(np.sum(weights * np.abs(values) ** order)) for order in KEPT_ORDERS)
    base = np.abs(np.asarray(group_values, dtype=float))
    if first <= 0 or base.max() <= 0:
        return base
    base = base / base.max()                               # the scale is lam's: keeps the powers in range

    def scaled(kappa: float) -> np.ndarray:
        spread = base ** kappa
        return spread * (first / np.sum(group_weights * spread ** KEPT_ORDERS[0])) ** (1 / KEPT_ORDERS[0])

    def excess(kappa: float) -> float:
        return float(np.sum(group_weights * scaled(kappa) ** KEPT_ORDERS[1]) / second - 1)

    if not (excess(1.0) < 0 < excess(LARGEST_SPREAD)):
        return scaled(1.0)
    return scaled(brentq(excess, 1.0, LARGEST_SPREAD, xtol=1e-15, rtol=4 * np.finfo(float).eps))


def mean_wind_direction(layers: tuple[Layer, ...]) -> float:
    """The ``J |v|^(5/3)``-weighted mean of the ``layers``' wind directions [rad] (the largest ``J``'s where no
    layer has wind)."""
    cn2 = np.array([layer.cn2_dh for layer in layers])
    speed = np.array([layer.wind_speed_m_s for layer in layers])
    direction = np.array([layer.wind_direction_rad for layer in layers])
    weight = cn2 * speed ** (5 / 3)
    if np.sum(weight) <= 0:
        return float(direction[np.argmax(cn2)])
    return float(np.arctan2(np.sum(weight * np.sin(direction)), np.sum(weight * np.cos(direction))))


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


def equivalent_layers(atmosphere: Atmosphere, n_layers: int) -> Atmosphere:
    """``atmosphere`` as ``n_layers`` equivalent layers (module docstring); unchanged (the same object) when it
    has that many layers or fewer."""
    if n_layers < 1:
        raise ValueError(f"equivalent layers: n_layers must be at least 1, not {n_layers}")
    if len(atmosphere.layers) <= n_layers:
        return atmosphere
    layers = sorted(atmosphere.layers, key=lambda layer: layer.altitude_m)
    cn2 = np.array([layer.cn2_dh for layer in layers])
    altitude = np.array([layer.altitude_m for layer in layers])
    speed = np.array([layer.wind_speed_m_s for layer in layers])
    groups = best_groups(altitude, cn2, n_layers)
    group_cn2 = np.array([np.sum(cn2[run.start:run.stop]) for run in groups])

    def kept(values: np.ndarray) -> np.ndarray:
        five_thirds = [moment(cn2[run.start:run.stop], values[run.start:run.stop]) for run in groups]
        return spread_to_second_moment(group_cn2, np.array(five_thirds), cn2, values)
    return replace(atmosphere, layers=tuple(
        Layer(float(h), float(j), float(v), mean_wind_direction(tuple(layers[run.start:run.stop])))
        for h, j, v, run in zip(kept(altitude), group_cn2, kept(speed), groups)))
