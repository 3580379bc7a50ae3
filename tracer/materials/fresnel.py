"""Smooth interfaces: mirror and refracted directions (the report's eq. 5, 7, 8, 12) and Fresnel reflectances."""
import drjit as dr

from ..jit import Array3f, Float


def reflect(d: Array3f, n: Array3f) -> Array3f:
    """Mirror direction d - 2 (d.N) N (eq. 5)."""
    return dr.fma(n, -2.0 * dr.dot(d, n), d)


def fresnel_dielectric(cos_i: Float, eta: Float) -> tuple[Float, Float, Float]:
    """Exact unpolarised Fresnel reflectance for light arriving at cos_i > 0 from the side of index
    n1 onto index n2, eta = n2 / n1.

    Returns (F, cos_t, R) with R = n1 / n2 the ratio of eq. 7; F = 1 under total internal reflection.
    """
    ratio = dr.rcp(eta)
    sin2_t = ratio * ratio * dr.maximum(1.0 - cos_i * cos_i, 0.0)   # Snell, eq. 7
    cos_t = dr.safe_sqrt(1.0 - sin2_t)
    r_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    f = 0.5 * (r_s * r_s + r_p * r_p)
    return dr.select(sin2_t >= 1.0, 1.0, f), cos_t, ratio


def refract(d: Array3f, n_facing: Array3f, cos_i: Float, cos_t: Float, ratio: Float) -> Array3f:
    """Refracted direction t = R d + (R cos_i - cos_t) N (eq. 8 / 12), N facing the incoming ray."""
    return dr.normalize(dr.fma(n_facing, ratio * cos_i - cos_t, ratio * d))


def fresnel_conductor(cos_i: Float, eta: Array3f, k: Array3f) -> Array3f:
    """Exact unpolarised Fresnel reflectance of a conductor of complex relative index eta + i k, per channel,
    for light arriving at cos_i > 0 (the s and p terms of Moeller's "Optics", as Mitsuba evaluates them)."""
    cos2 = cos_i * cos_i
    sin2 = 1.0 - cos2
    t1 = eta * eta - k * k - sin2
    a2_plus_b2 = dr.safe_sqrt(t1 * t1 + 4.0 * k * k * eta * eta)
    a = dr.safe_sqrt(0.5 * (a2_plus_b2 + t1))
    term1, term2 = a2_plus_b2 + cos2, 2.0 * cos_i * a
    r_s = (term1 - term2) / (term1 + term2)
    term3, term4 = a2_plus_b2 * cos2 + sin2 * sin2, term2 * sin2
    r_p = r_s * (term3 - term4) / (term3 + term4)
    return 0.5 * (r_s + r_p)


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Hemispherically averaged Fresnel reflectance of an interface of relative index eta, by the fits
    Mitsuba uses: Egan and Hilgeman (1973) for eta < 1, d'Eon and Irving (2011) otherwise."""
    inv = 1.0 / eta
    if eta < 1.0:
        return 0.0636 * inv + eta * (eta * -1.4399 + 0.7099) + 0.6681
    return ((((-1.36881 * inv + 4.98554) * inv - 7.80989) * inv + 6.75335) * inv - 3.4793) * inv + 0.919317
