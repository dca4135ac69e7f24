"""Tumbling bodies and glints: BRDF energy conservation, the mirror geometry of a plate's glint, a
spinning cylinder's light-curve period, facets against the exact cylinder, rigid-body attitude."""

import numpy as np
import pytest

from evsda.blocks.scene import brdf, facets
from evsda.blocks.scene.attitude import NadirPointing, Spin, Tumble, direction_of_radec, rotation_about
from evsda.blocks.scene.reflectors import FacetReflector
from evsda.blocks.scene.satellite import Satellite
from evsda.graph import ParameterError, Window


def directional_albedo(model, rd, rs, m, theta_i, n_alpha=150, n_phi=180):
    """``int f cos(theta_o) d omega`` over the hemisphere for light incident at ``theta_i`` (Gauss-Legendre in the
    angle from the mirror direction, finer inside the lobe)."""
    s = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])
    mirror = np.array([-s[0], 0.0, s[2]])
    e1 = np.cross(mirror, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(mirror, e1)
    width = min(np.pi, 8.0 / np.sqrt(max(float(brdf.sun_blurred_exponent(m)), 1.0)))
    alpha, w_alpha = [], []
    for a, b in ((0.0, width), (width, np.pi)):
        if b > a:
            x, w = np.polynomial.legendre.leggauss(n_alpha)
            alpha.append(a + (b - a) * (x + 1) / 2)
            w_alpha.append(w * (b - a) / 2)
    alpha, w_alpha = np.concatenate(alpha), np.concatenate(w_alpha)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    a, p = np.meshgrid(alpha, phi, indexing="ij")
    o = np.cos(a)[..., None] * mirror + np.sin(a)[..., None] * (np.cos(p)[..., None] * e1 + np.sin(p)[..., None] * e2)
    cos_o = o[..., 2]
    up = cos_o > 0
    f = brdf.evaluate(model, rd, rs, m, np.cos(theta_i), np.where(up, cos_o, 0.0), o @ s)
    return float(np.sum(np.where(up, f * cos_o, 0.0) * np.sin(a) * w_alpha[:, None]) * 2 * np.pi / n_phi)


INCIDENCE = np.radians([0.0, 45.0, 80.0, 89.0])


@pytest.mark.parametrize("model,rd,rs,m", [
    ("lambert", 1.0, 0.0, 0.0),
    ("phong", 0.0, 1.0, 20.0), ("phong", 0.0, 1.0, 1e7), ("phong", 0.4, 0.6, 300.0),
    ("ashikhmin_shirley", 1.0, 0.0, 10.0), ("ashikhmin_shirley", 0.0, 1.0, 1e7), ("ashikhmin_shirley", 1.0, 1.0, 100.0),
])
def test_every_brdf_conserves_energy(model, rd, rs, m):
    """A surface never reflects more than it receives: directional albedo <= 1 at every incidence, for the most
    reflective parameters each model allows (Lambert exactly rho; modified Phong exactly rho_d + rho_s at normal
    incidence, Lafortune & Willems 1994)."""
    albedo = np.array([directional_albedo(model, rd, rs, m, t) for t in INCIDENCE])
    assert np.all(albedo <= 1.0 + 2e-3), albedo
    if model == "lambert":
        np.testing.assert_allclose(albedo, rd, atol=2e-4)
    if model == "phong":
        assert albedo[0] == pytest.approx(rd + rs, abs=2e-3)
    if model == "ashikhmin_shirley" and rs == 1.0 and m > 1e6:
        assert albedo[0] == pytest.approx(1.0, abs=2e-3)                  # a perfect mirror keeps it all


def test_brdfs_are_reciprocal():
    rng = np.random.default_rng(3)
    s, o = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in (rng.normal(size=(500, 3)),
                                                                   rng.normal(size=(500, 3))))
    s[:, 2], o[:, 2] = np.abs(s[:, 2]), np.abs(o[:, 2])
    cos_so = np.sum(s * o, axis=1)
    for model in brdf.MODELS:
        forward = brdf.evaluate(model, 0.3, 0.5 if model != "lambert" else 0.0, 80.0, s[:, 2], o[:, 2], cos_so)
        backward = brdf.evaluate(model, 0.3, 0.5 if model != "lambert" else 0.0, 80.0, o[:, 2], s[:, 2], cos_so)
        np.testing.assert_allclose(forward, backward, rtol=1e-12)


def _spinning_plate(brdf_spec, rate_deg_s=3.6):
    """A plate of normal body +x spinning about GCRS z (body z): its normal sweeps the x-y plane."""
    model = facets.build(facets.FacetModelSpec(plates=[facets.PlateSpec(area_m2=2.0, normal=(1.0, 0.0, 0.0),
                                                                        brdf=brdf_spec)]))
    return FacetReflector(model, Spin(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), np.radians(rate_deg_s)))


def test_flat_plate_glint_appears_at_the_mirror_geometry():
    sun = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    observer = np.array([np.cos(1.7), np.sin(1.7), 0.0])
    bisector = (sun + observer) / np.linalg.norm(sun + observer)
    plate = _spinning_plate(facets.BrdfSpec(model="phong", diffuse_albedo=0.1, specular_albedo=0.8,
                                            specular_exponent=2000.0))
    t_ns = np.arange(0, 100_000_000_000, 10_000_000)                       # one turn in 100 s, every 0.036 deg
    n = len(t_ns)
    r = plate.reflectance_m2_sr(t_ns, None, None, np.tile(sun, (n, 1)), np.tile(observer, (n, 1)))
    peak = int(np.argmax(r))
    normal = plate.attitude.matrices(t_ns[peak])[0] @ [1.0, 0.0, 0.0]
    assert np.degrees(np.arccos(normal @ bisector)) < 0.04                   # at the sampling step
    cos_i = sun @ bisector
    expected = 2.0 * (0.1 / np.pi + 0.8 * (brdf.sun_blurred_exponent(2000.0) + 2) / (2 * np.pi)) * cos_i**2
    assert r[peak] == pytest.approx(expected, rel=1e-3)                      # the peak sample is <= 0.018 deg off
    # the glint is a burst: 30 deg of rotation away from the mirror only the diffuse term is left
    away = int(np.argmin(np.abs(t_ns - (t_ns[peak] + 30 / 3.6 * 1e9)) ))
    assert r[away] < 0.01 * r[peak]


def test_a_mirror_glint_is_bounded_by_the_solar_disc():
    """A perfect mirror's glint is the Sun's image: about twice rho_s E A cos / Omega_sun at its peak (a Gaussian
    lobe of the disc's variance peaks twice as high as the uniform disc), never infinite."""
    plate = _spinning_plate(facets.BrdfSpec(model="phong", diffuse_albedo=0.0, specular_albedo=1.0,
                                            specular_exponent=1e7), rate_deg_s=0.36)
    sun, observer = np.array([[1.0, 0.0, 0.0]]), np.array([[np.cos(0.2), np.sin(0.2), 0.0]])
    t_ns = np.arange(-400_000_000, 400_000_000, 1_000_000) + int(0.1 / np.radians(0.36) * 1e9)
    r = plate.reflectance_m2_sr(t_ns, None, None, np.repeat(sun, len(t_ns), 0), np.repeat(observer, len(t_ns), 0))
    omega_sun = np.pi * brdf.SUN_ANGULAR_RADIUS_RAD**2
    assert r.max() == pytest.approx(2 * 2.0 * np.cos(0.1) / omega_sun, rel=0.03)
    # exactly: the Phong peak of the disc-blurred exponent (Phong's extra cos and (m + 2) / m make the 2.3 %)
    assert r.max() == pytest.approx(2.0 * (brdf.sun_blurred_exponent(1e7) + 2) / (2 * np.pi) * np.cos(0.1) ** 2,
                                    rel=1e-5)


def test_facet_cylinder_matches_the_exact_diffuse_cylinder():
    spec = facets.CylinderSpec(radius_m=1.95, length_m=11.0, end_caps=False,
                               brdf=facets.BrdfSpec(model="lambert", diffuse_albedo=0.3))
    model = facets.build(facets.FacetModelSpec(cylinder=spec))
    assert model.n_facets == facets.MIN_CYLINDER_SIDES
    rng = np.random.default_rng(7)
    s, o = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in (rng.normal(size=(2000, 3)),
                                                                   rng.normal(size=(2000, 3))))
    exact = facets.diffuse_cylinder_side_reference(1.95, 11.0, 0.3, s, o)
    faceted = model.reflectance_m2_sr(s, o)
    scale = 0.3 / np.pi * 1.95 * 11.0 * np.pi / 2                          # the largest R
    assert np.max(np.abs(faceted - exact)) < 1e-3 * scale


def _cylinder(top=None, side=None):
    side = side or facets.BrdfSpec(model="phong", diffuse_albedo=0.2, specular_albedo=0.5, specular_exponent=300.0)
    return facets.build(facets.FacetModelSpec(cylinder=facets.CylinderSpec(radius_m=1.95, length_m=11.0, brdf=side,
                                                                           top_brdf=top)))


def _light_curve(model, spin_axis_body, period_s, seconds, sun, observer, step_ms=20):
    law = Spin(np.array([0.0, 0.3, 1.0]), np.asarray(spin_axis_body, dtype=float), 2 * np.pi / period_s, 0.4)
    t_ns = np.arange(0, int(seconds * 1e9), step_ms * 1_000_000)
    n = len(t_ns)
    return FacetReflector(model, law).reflectance_m2_sr(t_ns, None, None, np.tile(sun, (n, 1)),
                                                        np.tile(observer, (n, 1)))


# Sun and observer 70 deg apart about the bisector +x, which lies in the plane the long axis sweeps when spinning
# end over end about GCRS (0, 0.3, 1): the side glints twice a turn and each end cap glints once
SUN = np.array([np.cos(0.6), 0.8 * np.sin(0.6), 0.6 * np.sin(0.6)])
OBSERVER = np.array([np.cos(0.6), -0.8 * np.sin(0.6), -0.6 * np.sin(0.6)])


def test_spinning_cylinder_light_curve_period_is_half_or_whole_the_spin_period():
    """End over end (spin axis across the long axis), a cylinder with like ends shows the same face twice per turn:
    the light curve repeats every half spin (two glints per period, "the time difference between the two flashes
    is exactly half of the rotation period", satobs.org tumbling-satellite notes). With unlike ends (a dark engine
    end) it repeats only every whole spin."""
    period, per_half = 8.0, 200                                            # 20 ms samples
    symmetric = _light_curve(_cylinder(), (1.0, 0.0, 0.0), period, 3 * period, SUN, OBSERVER)
    unlike = _light_curve(_cylinder(top=facets.BrdfSpec(model="lambert", diffuse_albedo=0.02)), (1.0, 0.0, 0.0),
                          period, 3 * period, SUN, OBSERVER)
    for curve in (symmetric, unlike):
        np.testing.assert_allclose(curve[2 * per_half:], curve[:-2 * per_half], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(symmetric[per_half:], symmetric[:-per_half], rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(unlike[per_half:] - unlike[:-per_half])) > 0.3 * np.max(unlike)   # one end's glint
    # the fundamental period found from the light curve alone
    for curve, expected in ((symmetric, period / 2), (unlike, period)):
        x = curve - curve.mean()
        corr = np.array([np.dot(x[:-lag], x[lag:]) / np.sqrt(np.dot(x[:-lag], x[:-lag]) * np.dot(x[lag:], x[lag:]))
                         for lag in range(1, 3 * per_half)])
        assert (np.argmax(corr > 0.999) + 1) * 0.02 == pytest.approx(expected, abs=0.021)


def test_cylinder_spinning_about_its_axis_is_steady():
    """About its own axis a smooth cylinder always shows the same profile: the facets must not flicker, even with a
    sharp specular lobe (n_sides follows the lobe)."""
    curve = _light_curve(_cylinder(), (0.0, 0.0, 1.0), 5.0, 5.0, SUN, OBSERVER, step_ms=5)
    assert np.ptp(curve) < 1e-3 * curve.mean()


def test_tumble_conserves_momentum_and_energy():
    law = Tumble(np.array([9000.0, 90000.0, 91000.0]), np.radians([20.0, 5.0, 30.0]), direction_of_radec(250, -20),
                 1.0)
    t_ns = np.linspace(-5e9, 300e9, 3001)
    quaternions, omega = law.state(t_ns)
    momentum = np.einsum("nij,nj->ni", law.matrices(t_ns), law.inertia * omega)
    np.testing.assert_allclose(momentum / np.linalg.norm(momentum, axis=1, keepdims=True),
                               np.tile(direction_of_radec(250, -20), (len(t_ns), 1)), atol=1e-9)
    energy = np.sum(law.inertia * omega**2, axis=1)
    assert np.ptp(energy) < 1e-9 * energy[0]


def test_symmetric_top_follows_free_precession():
    """Landau & Lifshitz Sec. 33: for I1 = I2 = I the body-frame rate turns about the symmetry axis at
    (I3 - I) w3 / I, and the symmetry axis cones about the angular momentum at |L| / I."""
    i, i3 = 5000.0, 1200.0
    w0 = np.radians([6.0, 0.0, 40.0])
    law = Tumble(np.array([i, i, i3]), w0, direction_of_radec(10, 50), 0.0)
    t_s = np.linspace(0, 120, 601)
    _, omega = law.state(t_s * 1e9)
    rate = (i3 - i) * w0[2] / i
    np.testing.assert_allclose(omega[:, 0], w0[0] * np.cos(rate * t_s), atol=1e-8)
    np.testing.assert_allclose(omega[:, 1], w0[0] * np.sin(rate * t_s), atol=1e-8)
    axis = law.matrices(t_s * 1e9)[:, :, 2]
    momentum = direction_of_radec(10, 50)
    cone = np.arccos(axis @ momentum)
    np.testing.assert_allclose(cone, np.arccos(i3 * w0[2] / np.linalg.norm([i * w0[0], 0, i3 * w0[2]])), atol=1e-8)
    # the axis turns about L at |L| / I: project it on the plane normal to L and follow its angle
    ref = np.cross(momentum, [0.0, 0.0, 1.0])
    ref /= np.linalg.norm(ref)
    angle = np.unwrap(np.arctan2(axis @ np.cross(momentum, ref), axis @ ref))
    precession = np.linalg.norm([i * w0[0], 0.0, i3 * w0[2]]) / i
    assert np.polyfit(t_s, angle, 1)[0] == pytest.approx(precession, rel=1e-8)


def test_spin_and_nadir_laws_are_rotations():
    spin = Spin(direction_of_radec(40, 10), np.array([0.0, 2.0, 0.0]), np.radians(45.0), 0.2)
    m = spin.matrices(np.linspace(0, 8e9, 9))
    np.testing.assert_allclose(m @ np.swapaxes(m, 1, 2), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(m @ [0.0, 1.0, 0.0], np.tile(direction_of_radec(40, 10), (9, 1)), atol=1e-12)
    np.testing.assert_allclose(m[8], m[0], atol=1e-12)                     # 45 deg/s: one turn in 8 s
    np.testing.assert_allclose(m[4], rotation_about(direction_of_radec(40, 10), np.pi)[0] @ m[0], atol=1e-12)
    r, v = np.array([[7e6, 0.0, 0.0]]), np.array([[0.0, 7.5e3, 100.0]])
    nadir = NadirPointing().matrices(None, r, v)[0]
    np.testing.assert_allclose(nadir @ [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], atol=1e-12)
    assert np.linalg.det(nadir) == pytest.approx(1.0)


def test_a_diffuse_facet_plate_gives_the_old_plate(iss, graz, pass_start, quickstart_pointing, gen4):
    """The facet path against the closed-form plate of paper Eq. 2: one Lambertian facet facing nadir."""
    old = Satellite(shape="plate", area_m2=4.0, albedo=0.3, plate_normal="nadir")
    new = Satellite(shape="facets", facet_model={"plates": [{"area_m2": 4.0, "normal": [0, 0, 1],
                                                             "brdf": {"model": "lambert", "diffuse_albedo": 0.3}}]})
    t_ns = np.arange(2_700_000_000, 3_300_000_000, 50_000_000)
    window = Window(0, 0, 4_000_000_000, pass_start)
    a, b = (block.view(window, iss, graz, quickstart_pointing, gen4).sample(t_ns) for block in (old, new))
    assert np.all(a.photon_flux > 0)
    np.testing.assert_allclose(b.photon_flux, a.photon_flux, rtol=1e-12)


def test_a_spinning_plate_flashes_on_the_focal_plane(iss, graz, pass_start, quickstart_pointing, gen4):
    block = Satellite(shape="plate", area_m2=4.0, albedo=0.3, attitude="spin", spin_rate_deg_s=90.0,
                      spin_axis_ra_deg=120.0, spin_axis_dec_deg=10.0)
    t_ns = np.arange(0, 8_000_000_000, 10_000_000)
    flux = block.view(Window(0, 0, 8_000_000_000, pass_start), iss, graz, quickstart_pointing, gen4).sample(t_ns)
    lit = flux.photon_flux > 0
    assert 0.2 < lit.mean() < 0.8                                           # dark while edge-on or facing away
    fixed = Satellite(shape="plate", area_m2=4.0, albedo=0.3)
    assert np.ptp(flux.photon_flux) > 5 * np.ptp(fixed.view(Window(0, 0, 8_000_000_000, pass_start), iss, graz,
                                                                quickstart_pointing, gen4).sample(t_ns).photon_flux)


@pytest.mark.parametrize("params,message", [
    (dict(shape="facets"), "exactly one of facet_model"),
    (dict(facet_model={"plates": [{"area_m2": 1.0, "normal": [0, 0, 1]}]}), "need shape 'facets'"),
    (dict(shape="facets", facet_model={"plates": [{"area_m2": 1.0, "normal": [0, 0, 2]}]}),
     r"unit vector .*length 2.*did you mean \[0.0, 0.0, 1.0\]"),
    (dict(shape="facets", facet_model={"plates": [{"area_m2": 1.0, "normal": [0, 0, 0]}]}), "unit vector"),
    (dict(shape="facets", facet_model={"plates": [{"area_m2": -1.0, "normal": [0, 0, 1]}]}), "area_m2"),
    (dict(shape="facets", facet_model={"plates": [{"area_m2": float("nan"), "normal": [0, 0, 1]}]}), "area_m2"),
    (dict(shape="facets", facet_model={"box": {"size_m": [1, 0, 2]}}), "positive lengths"),
    (dict(shape="facets", facet_model={}), "needs a cylinder, a box or at least one plate"),
    (dict(shape="facets", facet_model={"cylinder": {"radius_m": 1, "length_m": 5,
                                                    "brdf": {"diffuse_albedo": 0.6, "specular_albedo": 0.6}}}),
     "reflecting more than it receives"),
    (dict(shape="sphere", attitude="spin"), "looks the same in every attitude"),
    (dict(shape="plate", attitude="tumble", inertia_kg_m2=[1, 1, 3], angular_velocity_deg_s=[1, 0, 0]),
     "not a rigid body's"),
    (dict(shape="plate", attitude="tumble"), "needs inertia_kg_m2"),
    (dict(shape="plate", attitude="spin", spin_axis_body=[0, 0, 0]), "non-zero direction"),
])
def test_unphysical_facet_models_and_attitudes_are_one_clear_error(params, message):
    with pytest.raises(ParameterError, match=message):
        Satellite(**params)


def test_facet_model_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "shape.yaml"
    bad.write_text("cylinder: {radius_m: 2, length_m: 10}\nplates:\n  - {area_m2: 3, normal: [1, 1, 0]}\n")
    with pytest.raises(ParameterError, match=r"shape\.yaml: plates\.0\.normal: .*unit vector"):
        Satellite(shape="facets", facet_model_file=str(bad))
    with pytest.raises(ParameterError, match=r"missing\.yaml: facet model file not found"):
        Satellite(shape="facets", facet_model_file=str(tmp_path / "missing.yaml"))


def test_a_tumbling_box_with_panels_through_the_block(iss, graz, pass_start, quickstart_pointing, gen4):
    """The tumble law from the block's parameters, light emitted before t = 0 included (integrated backwards)."""
    shape = {"box": {"size_m": [1.0, 1.5, 2.0]},
             "plates": [{"area_m2": 3.0, "normal": [0, 1, 0], "brdf": {"model": "ashikhmin_shirley",
                                                                        "diffuse_albedo": 0.1, "specular_albedo": 0.6,
                                                                        "specular_exponent": 500}}]}
    block = Satellite(shape="facets", facet_model=shape, attitude="tumble", inertia_kg_m2=[300.0, 400.0, 500.0],
                      angular_velocity_deg_s=[5.0, 20.0, 3.0], spin_axis_ra_deg=200.0, spin_axis_dec_deg=-30.0)
    view = block.view(Window(0, 0, 4_000_000_000, pass_start), iss, graz, quickstart_pointing, gen4)
    flux = view.sample(np.arange(0, 4_000_000_000, 20_000_000)).photon_flux
    assert np.all(np.isfinite(flux)) and np.all(flux > 0)                  # the box always shows a lit face
    assert flux.max() > 2 * flux.min()
    fresh = Satellite(**block.params.model_dump())                          # a resumed run: a new block, later samples
    again = fresh.view(Window(3, 2_000_000_000, 4_000_000_000, pass_start), iss, graz, quickstart_pointing, gen4)
    np.testing.assert_array_equal(again.sample(np.arange(2_000_000_000, 4_000_000_000, 20_000_000)).photon_flux,
                                  flux[100:])
