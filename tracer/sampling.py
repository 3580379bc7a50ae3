"""Warps from the unit square to the domains the estimators sample, with their densities."""
import drjit as dr

from .jit import Array3f, Float

INV_PI = 1.0 / dr.pi


def square_to_cosine_hemisphere(u1: Float, u2: Float) -> Array3f:
    """Cosine-weighted direction about +z (Malley's method); density cos(theta) / pi."""
    r, phi = dr.sqrt(u1), dr.two_pi * u2
    s, c = dr.sincos(phi)
    return Array3f(r * c, r * s, dr.safe_sqrt(1.0 - u1))


def cosine_hemisphere_pdf(cos_theta: Float) -> Float:
    return dr.maximum(cos_theta, 0.0) * INV_PI


def square_to_uniform_hemisphere(u1: Float, u2: Float) -> Array3f:
    """Uniform direction about +z; density 1 / (2 pi).

    The report's eq. 11 maps spherical angles to x, y, z; drawing cos(theta) (not theta) uniformly is
    what makes the directions uniform in solid angle.
    """
    z = u1
    r = dr.safe_sqrt(1.0 - z * z)
    s, c = dr.sincos(dr.two_pi * u2)
    return Array3f(r * c, r * s, z)


def uniform_hemisphere_pdf(cos_theta: Float) -> Float:
    return dr.select(cos_theta > 0, 1.0 / dr.two_pi, 0.0)


def square_to_uniform_triangle(u1: Float, u2: Float) -> tuple[Float, Float]:
    """Barycentric coordinates (b1, b2) of a point uniform in area on a triangle."""
    su = dr.sqrt(u1)
    return u2 * su, 1.0 - su


def coordinate_system(n: Array3f) -> tuple[Array3f, Array3f]:
    """Two unit tangents completing n to an orthonormal frame (Duff et al. 2017)."""
    sign = dr.select(n.z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    return (Array3f(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            Array3f(b, sign + n.y * n.y * a, -n.y))


def to_world(local: Array3f, n: Array3f) -> Array3f:
    s, t = coordinate_system(n)
    return s * local.x + t * local.y + n * local.z
