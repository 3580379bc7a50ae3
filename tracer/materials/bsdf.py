"""The host description of a material, as the loader builds it from a Mitsuba <bsdf>, and the kind codes
the kernels branch on."""
from __future__ import annotations

from dataclasses import dataclass

from .textures import Bitmap, Checkerboard

DIFFUSE, CONDUCTOR, DIELECTRIC, PLASTIC = 0, 1, 2, 3
KIND_CODE = {"diffuse": DIFFUSE, "conductor": CONDUCTOR, "dielectric": DIELECTRIC, "plastic": PLASTIC}


@dataclass(frozen=True)
class BSDF:
    """`diffuse` (Lambertian, one-sided unless `twosided`), `conductor` (smooth: `reflectance` times the exact
    Fresnel reflectance of the complex index eta + i k; eta 0, k 1 is a perfect mirror), `dielectric`, or
    `plastic` (Mitsuba's smooth plastic: a dielectric interface over a diffuse base of `reflectance`)."""

    kind: str
    reflectance: tuple[float, float, float] = (0.5, 0.5, 0.5)
    twosided: bool = False
    int_ior: float = 1.5046
    ext_ior: float = 1.000277
    eta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    k: tuple[float, float, float] = (1.0, 1.0, 1.0)
    texture: Checkerboard | Bitmap | None = None   # a diffuse reflectance given by a texture
    specular_reflectance: tuple[float, float, float] = (1.0, 1.0, 1.0)   # plastic's specular layer
    nonlinear: bool = False                                              # plastic's internal scattering model

    @property
    def perfect_mirror(self) -> bool:
        """A conductor that reflects everything at every angle (Fresnel reflectance 1, reflectance 1)."""
        return self.eta == (0.0, 0.0, 0.0) and self.k == (1.0, 1.0, 1.0) and self.reflectance == (1.0, 1.0, 1.0)
