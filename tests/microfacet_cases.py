"""The microfacet BSDFs' parameter sets shared by their tests, each built both for the tracer's modules
(tracer.materials.rough*) and as the dict Mitsuba's load_dict reads."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracer.jit import Array3f, Float
from tracer.materials import roughconductor, roughdielectric, roughplastic
from tracer.materials.microfacet import microfacet

MODULES = {"roughconductor": roughconductor, "roughdielectric": roughdielectric, "roughplastic": roughplastic}


@dataclass(frozen=True)
class Case:
    kind: str
    distribution: str = "beckmann"
    alpha: float | tuple[float, float] = 0.1     # (alpha_u, alpha_v): anisotropic
    sample_visible: bool = True
    int_ior: float = 1.5
    ext_ior: float = 1.0
    eta: tuple = (0.2, 0.9, 1.1)                  # a conductor's
    k: tuple = (3.9, 2.4, 2.1)
    specular: tuple = (1.0, 1.0, 1.0)             # specular_reflectance
    transmittance: tuple = (1.0, 1.0, 1.0)        # a dielectric's specular_transmittance
    diffuse: tuple = (0.5, 0.5, 0.5)              # a plastic's diffuse_reflectance
    nonlinear: bool = False

    @property
    def module(self):
        return MODULES[self.kind]

    def __str__(self):
        a = self.alpha if isinstance(self.alpha, float) else f"{self.alpha[0]}x{self.alpha[1]}"
        return f"{self.kind}-{self.distribution}-a{a}-{'vis' if self.sample_visible else 'all'}"

    def distr(self):
        au, av = (self.alpha, None) if isinstance(self.alpha, float) else self.alpha
        return microfacet(self.distribution == "ggx", au, av, self.sample_visible)

    def params(self):
        rgb = lambda v: Array3f(*(float(x) for x in v))   # noqa: E731
        eta = self.int_ior / self.ext_ior
        if self.kind == "roughconductor":
            return roughconductor.RoughConductorParams(self.distr(), rgb(self.eta), rgb(self.k), rgb(self.specular))
        if self.kind == "roughdielectric":
            return roughdielectric.RoughDielectricParams(self.distr(), Float(eta), rgb(self.specular),
                                                         rgb(self.transmittance))
        table, r_int = roughplastic.coating(self.distribution == "ggx", float(self.alpha), eta)
        s, d = np.mean(self.specular), np.mean(self.diffuse)
        return roughplastic.RoughPlasticParams(self.distr(), Float(eta), rgb(self.specular), rgb(self.diffuse),
                                               self.nonlinear, Float(s / (s + d)), Float(r_int), Float(table))

    def mitsuba_dict(self) -> dict:
        rgb = lambda v: {"type": "rgb", "value": list(v)}   # noqa: E731
        d = {"type": self.kind, "distribution": self.distribution, "sample_visible": self.sample_visible}
        if isinstance(self.alpha, float):
            d["alpha"] = self.alpha
        else:
            d["alpha_u"], d["alpha_v"] = self.alpha
        if self.kind == "roughconductor":
            d.update(eta=rgb(self.eta), k=rgb(self.k), specular_reflectance=rgb(self.specular))
        else:
            d.update(int_ior=self.int_ior, ext_ior=self.ext_ior, specular_reflectance=rgb(self.specular))
        if self.kind == "roughdielectric":
            d["specular_transmittance"] = rgb(self.transmittance)
        if self.kind == "roughplastic":
            d.update(diffuse_reflectance=rgb(self.diffuse), nonlinear=self.nonlinear)
        return d


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=0)


def direction(theta_deg: float, phi_deg: float = 30.0) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
