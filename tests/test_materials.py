"""Fresnel reflectance, mirror reflection and refraction (tracer/materials) against float64 references.

u = 2^-24 is the float32 unit roundoff; references are evaluated in float64 from the float32 inputs.
"""
import math

import numpy as np
import pytest

from tracer.materials.dielectric import dielectric_interface
from tracer.materials.diffuse import diffuse_brdf
from tracer.materials.fresnel import fresnel_dielectric, reflect, refract
from tracer.jit import Float

from .float32 import U, arr3, f32, unit  # noqa: E402


def fresnel_ref(cos_i, eta):
    """Unpolarised Fresnel reflectance in float64, n1 = 1, n2 = eta; 1 under total internal reflection."""
    n1, n2 = 1.0, eta
    sin_t2 = (n1 / n2) ** 2 * (1 - cos_i ** 2)
    tir = sin_t2 >= 1
    cos_t = np.sqrt(np.maximum(1 - sin_t2, 0))
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return np.where(tir, 1.0, (rs ** 2 + rp ** 2) / 2), cos_t


def fresnel(cos_i, eta):
    f, cos_t, ratio = fresnel_dielectric(Float(np.asarray(cos_i, np.float32)), Float(np.float32(eta)))
    return f.numpy().astype(np.float64), cos_t.numpy().astype(np.float64), ratio.numpy().astype(np.float64)


@pytest.mark.parametrize("eta", [1.5, 1 / 1.5])
def test_fresnel_matches_closed_form(eta):
    eta = float(np.float32(eta))
    theta = np.radians(np.arange(0.0, 90.0, 0.25))
    cos_i = f32(np.cos(theta))
    f, cos_t, ratio = fresnel(cos_i, eta)
    f_ref, cos_t_ref = fresnel_ref(cos_i, eta)
    # float32 evaluation of O(1) quantities with a dozen roundings: ~1e-6. Near the critical angle
    # cos_t = sqrt(1 - sin_t^2) amplifies the ~2u error of sin_t^2 by 1/(2 cos_t) and F is steep in
    # cos_t there, so add the reference's own sensitivity to a 4u relative change of sin_t^2.
    sin_t2 = (1 - cos_i ** 2) / eta ** 2
    bump = np.sqrt(np.maximum(1 - sin_t2 * (1 + 4 * U), 0))
    sens = np.abs(np.where(sin_t2 * (1 + 4 * U) < 1, _f_of_cos_t(cos_i, bump, eta), 1.0) - f_ref)
    assert np.all(np.abs(f - f_ref) <= 1e-5 + 2 * sens)
    assert np.max(np.abs(f - f_ref)[sens < 1e-6]) < 2e-6
    assert np.allclose(ratio, 1 / eta, rtol=2 * U)
    ok = f_ref < 1
    assert np.all(np.abs(cos_t - cos_t_ref)[ok] <= 4 * U + 2 * U / np.maximum(cos_t_ref[ok], 1e-30))


def _f_of_cos_t(cos_i, cos_t, eta):
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return (rs ** 2 + rp ** 2) / 2


def test_fresnel_total_internal_reflection_beyond_critical_angle():
    eta = float(np.float32(1 / 1.5))
    critical = math.degrees(math.asin(eta))                     # 41.81 degrees
    theta = np.radians(np.linspace(critical + 0.01, 90.0, 200))
    f, _, _ = fresnel(np.cos(theta), eta)
    assert np.all(f == 1.0)
    below = np.radians(np.linspace(0.0, critical - 0.01, 200))
    f_below, _, _ = fresnel(np.cos(below), eta)
    assert np.all(f_below < 1.0)
    # and nothing above the critical angle going into the denser medium
    f_dense, _, _ = fresnel(np.cos(theta[:-1]), 1.5)     # (at exactly 90 degrees F = 1 for any eta)
    assert np.all(f_dense < 1.0)


@pytest.mark.parametrize("eta", [1.5, 1 / 1.5, 1.333, 2.4])
def test_fresnel_normal_incidence(eta):
    eta = float(np.float32(eta))
    f, cos_t, _ = fresnel([1.0], eta)
    assert f[0] == pytest.approx(((eta - 1) / (eta + 1)) ** 2, rel=16 * U)
    assert cos_t[0] == 1.0


def test_fresnel_grazing_incidence_reflects_everything():
    f, _, _ = fresnel([0.0], 1.5)
    assert f[0] == pytest.approx(1.0, abs=4 * U)


def test_fresnel_eta_one_is_invisible():
    theta = np.radians(np.arange(0.0, 86.0, 1.0))
    cos_i = f32(np.cos(theta))
    f, cos_t, ratio = fresnel(cos_i, 1.0)
    # cos_t = sqrt(1 - (1 - cos_i^2)) carries ~2u absolute error in cos_t^2, i.e. u / cos_i in cos_t,
    # so |r| <= ~u / cos_i^2 and F <= (2u / cos_i^2)^2
    assert np.all(np.abs(cos_t - cos_i) <= 2 * U / cos_i)
    assert np.all(f <= (2 * U / cos_i ** 2) ** 2 + 1e-30)
    assert np.all(ratio == 1.0)


def _random_frames(n, seed):
    """Unit normals and unit directions arriving at their front side (d . n < 0), as float32 values."""
    rng = np.random.default_rng(seed)
    nrm = f32(unit(rng.normal(size=(n, 3))))
    d = unit(rng.normal(size=(n, 3)))
    d = np.where((np.sum(d * nrm, axis=1) < 0)[:, None], d, -d)
    d = f32(d)
    keep = np.sum(d * nrm, axis=1) < -1e-3
    return d[keep], nrm[keep]


def test_reflect_obeys_eq5_and_preserves_length():
    d, n = _random_frames(2000, 1)
    r = reflect(arr3(d), arr3(n)).numpy().T.astype(np.float64)
    ref = d - 2 * np.sum(d * n, axis=1, keepdims=True) * n
    assert np.all(np.abs(r - ref) <= 8 * U)
    # angle of reflection equals angle of incidence, r - d is along n, and |r| = |d|
    assert np.allclose(np.sum(r * n, axis=1), -np.sum(d * n, axis=1), atol=8 * U)
    assert np.allclose(np.cross(r - d, n), 0, atol=16 * U)
    assert np.allclose(np.linalg.norm(r, axis=1), np.linalg.norm(d, axis=1), atol=8 * U)
    # reflecting twice is the identity
    rr = reflect(arr3(r), arr3(n)).numpy().T
    assert np.allclose(rr, d, atol=16 * U)


@pytest.mark.parametrize("eta", [1.5, 1 / 1.5])
def test_refract_obeys_snell_and_is_unit(eta):
    d, n = _random_frames(4000, 2)
    cos_i = -np.sum(d * n, axis=1)
    f, cos_t, ratio = fresnel_dielectric(Float(cos_i.astype(np.float32)), Float(np.float32(eta)))
    keep = f.numpy() < 1                       # total internal reflection has no refracted ray
    t = refract(arr3(d), arr3(n), Float(cos_i.astype(np.float32)), cos_t, ratio).numpy().T.astype(np.float64)
    t, d, n, cos_i = t[keep], d[keep], n[keep], cos_i[keep]
    assert keep.sum() > len(keep) // 5
    assert np.allclose(np.linalg.norm(t, axis=1), 1.0, atol=4 * U)
    sin_i = np.linalg.norm(np.cross(d, n), axis=1)
    sin_t = np.linalg.norm(np.cross(t, n), axis=1)
    # n1 sin_i = n2 sin_t with n1 = 1, n2 = eta; sines of unit float32 vectors are good to a few u
    # (absolute), and the refracted direction to a few u / cos_t (cos_t from a square root)
    cos_t_ref = np.sqrt(np.maximum(1 - (sin_i / eta) ** 2, 0))
    tol = 16 * U * (1 + 1 / np.maximum(cos_t_ref, 1e-3))
    assert np.all(np.abs(eta * sin_t - sin_i) <= eta * tol)
    # it continues through the surface and stays in the plane of incidence
    assert np.all(np.sum(t * n, axis=1) < 0)
    plane = unit(np.cross(d, n))
    assert np.all(np.abs(np.sum(t * plane, axis=1)) <= tol)
    # and bends the right way: tangential components point the same way as the incident one's
    assert np.all(np.sum((t - np.sum(t * n, 1, keepdims=True) * n) * (d - np.sum(d * n, 1, keepdims=True) * n),
                         axis=1) >= 0)


def test_dielectric_interface_entering_and_exiting():
    int_ior, ext_ior = 1.5, 1.0
    n = np.array([[0.0, 0.0, 1.0]] * 2)
    th = np.radians(30.0)
    d = np.array([[math.sin(th), 0.0, -math.cos(th)],    # from outside, against n: entering
                  [math.sin(th), 0.0, math.cos(th)]])    # from inside, along n: exiting
    f, refl, refr, scale = dielectric_interface(arr3(d), arr3(n), Float(int_ior), Float(ext_ior))
    f, refl, refr, scale = f.numpy(), refl.numpy().T, refr.numpy().T, scale.numpy()
    # radiance scale (n1 / n2)^2: entering n1 = ext, n2 = int; exiting n1 = int, n2 = ext
    assert scale[0] == pytest.approx((ext_ior / int_ior) ** 2, rel=4 * U)
    assert scale[1] == pytest.approx((int_ior / ext_ior) ** 2, rel=4 * U)
    # F from the right side: 30 degrees going in; 30 degrees going out of glass (below 41.8 degrees)
    f_in, _ = fresnel_ref(np.array([math.cos(th)]), int_ior / ext_ior)
    f_out, _ = fresnel_ref(np.array([math.cos(th)]), ext_ior / int_ior)
    assert f[0] == pytest.approx(f_in[0], abs=2e-6) and f[1] == pytest.approx(f_out[0], abs=2e-6)
    # reflection flips the normal component, refraction keeps its sign (it crosses the surface)
    assert np.allclose(refl, d * [1, 1, -1], atol=4 * U)
    assert refr[0, 2] < 0 and refr[1, 2] > 0
    assert refr[0, 0] == pytest.approx(math.sin(th) * ext_ior / int_ior, abs=8 * U)
    assert refr[1, 0] == pytest.approx(math.sin(th) * int_ior / ext_ior, abs=8 * U)


def test_dielectric_interface_total_internal_reflection_from_inside():
    th = np.radians(60.0)                                  # beyond the critical angle of glass
    d = np.array([[math.sin(th), 0.0, math.cos(th)]])      # inside, heading out
    f, refl, _, _ = dielectric_interface(arr3(d), arr3([[0.0, 0.0, 1.0]]), Float(1.5), Float(1.0))
    assert f.numpy()[0] == 1.0
    assert np.allclose(refl.numpy().T, [[math.sin(th), 0.0, -math.cos(th)]], atol=4 * U)


def test_dielectric_interface_eta_one_passes_straight_through():
    d, n = _random_frames(500, 3)
    d = np.concatenate([d, -d])                           # entering and exiting
    n = np.concatenate([n, n])
    f, _, refr, scale = dielectric_interface(arr3(d), arr3(n), Float(1.33), Float(1.33))
    cos = np.abs(np.sum(d * n, axis=1))
    assert np.all(scale.numpy() == 1.0)
    assert np.all(f.numpy() <= (2 * U / cos ** 2) ** 2 + 1e-30)
    # undeviated up to the rounding of cos_t (u / cos) and of the normalisation
    err = np.linalg.norm(refr.numpy().T - d, axis=1)
    assert np.all(err <= 4 * U / cos + 8 * U)


def test_diffuse_brdf_is_albedo_over_pi():
    rho = np.array([[0.2, 0.5, 0.9]])
    out = diffuse_brdf(arr3(rho)).numpy().T
    assert np.allclose(out, rho / math.pi, rtol=2 * U)
