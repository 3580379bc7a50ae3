"""Known faults injected into the tracer, to show the harness can fail (GUIDE section 3, power of the test).

Each fault replaces a module attribute where the tracer looks it up at trace time (unittest.mock.patch),
so no tracer code changes:

- double_cosine: the report code's bug; cosine-sampled directions weighted by the cosine a second time.
- light_counted_twice: the report code's bug; an indirect ray that hits the light adds its emission
  although eq. 10 already counted that light.
- missing_inv_pi: the diffuse BRDF rho instead of rho / pi where it is evaluated (the shadow-ray estimate,
  eq. 10; sampling weights it by rho, correctly).
- schlick_fresnel: Schlick's approximation instead of the exact dielectric Fresnel reflectance.
- wrong_light_density: light points drawn with density 2u in one coordinate while the estimator divides
  by the uniform density 1 / area.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Callable
from unittest import mock

import drjit as dr

import tracer.integrators.report
import tracer.materials.dielectric
import tracer.materials.diffuse
from tracer.geometry import SceneGeometry


@dataclass(frozen=True)
class Fault:
    name: str
    scene: str            # file in mitsuba_scenes/
    estimator: str        # the tracer estimator the fault affects
    max_depth: int        # a depth at which the fault changes the image
    spp: int              # samples per pass (path estimator and Mitsuba) at which CI shows it is caught
    patches: Callable[[], list]

    @contextlib.contextmanager
    def inject(self):
        """Within this context the tracer carries the fault."""
        with contextlib.ExitStack() as stack:
            for p in self.patches():
                stack.enter_context(p)
            yield


def _double_cosine() -> list:
    correct = tracer.integrators.report.indirect_sample

    def double_cosine(bsdf, u1, u2, hemisphere):
        bs, weight = correct(bsdf, u1, u2, hemisphere)
        return bs, dr.select(bsdf.smooth, weight * dr.abs(dr.dot(bs.wo, bsdf.n)), weight)

    return [mock.patch.object(tracer.integrators.report, "indirect_sample", double_cosine)]


def _light_counted_twice() -> list:
    Wavefront = tracer.integrators.report.Wavefront

    def every_ray_sees_emitters(o, d, t_min, t_max, weight, pixel, skip, sees_emitters):
        return Wavefront(o, d, t_min, t_max, weight, pixel, skip, sees_emitters | True)

    return [mock.patch.object(tracer.integrators.report, "Wavefront", every_ray_sees_emitters)]


def _missing_inv_pi() -> list:
    return [mock.patch.object(tracer.materials.diffuse, "diffuse_brdf", lambda albedo: albedo)]


def _schlick_fresnel() -> list:
    def schlick(cos_i, eta):
        exact_f, cos_t, ratio = correct(cos_i, eta)
        r0 = dr.square((eta - 1.0) / (eta + 1.0))
        f = r0 + (1.0 - r0) * dr.power(1.0 - cos_i, 5)
        return dr.select(exact_f >= 1.0, 1.0, f), cos_t, ratio   # total internal reflection kept

    correct = tracer.materials.dielectric.fresnel_dielectric
    return [mock.patch.object(tracer.materials.dielectric, "fresnel_dielectric", schlick)]


def _wrong_light_density() -> list:
    correct = SceneGeometry.sample_light

    def skewed(self, u_select, u1, u2, *rest):
        return correct(self, u_select, dr.sqrt(u1), u2, *rest)   # density 2u, divided by the uniform density

    return [mock.patch.object(SceneGeometry, "sample_light", skewed)]


FAULTS = {f.name: f for f in (
    Fault("double_cosine", "hexagon_room.xml", "report", 3, 64, _double_cosine),
    Fault("light_counted_twice", "hexagon_room.xml", "report", 3, 64, _light_counted_twice),
    Fault("missing_inv_pi", "cornell_box.xml", "path", 2, 64, _missing_inv_pi),
    Fault("schlick_fresnel", "hexagon_room.xml", "path", 4, 256, _schlick_fresnel),   # a small bias, on the glass only
    Fault("wrong_light_density", "cornell_box.xml", "path", 2, 64, _wrong_light_density),
)}
