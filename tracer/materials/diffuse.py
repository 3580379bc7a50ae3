"""Mitsuba's `diffuse`: the Lambertian BRDF."""
from ..jit import Array3f
from ..sampling import INV_PI


def diffuse_brdf(albedo: Array3f) -> Array3f:
    """Lambertian BRDF f = rho / pi (the f of eq. 10)."""
    return albedo * INV_PI
