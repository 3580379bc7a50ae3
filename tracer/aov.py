"""Auxiliary images (AOVs) for a denoiser: the albedo and the shading normal of the first non-specular
surface seen through each pixel, the feature images of Open Image Denoise's `RT` filter.

OIDN's documentation (doc/api.md, "RT") asks for the features of the first hit, but recommends following
perfect specular (delta) paths through mirrors and glass and storing the first diffuse surface's features
instead, a smooth dielectric's albedo being the Fresnel blend of the reflected and the refracted albedo.
Each sample here makes that blend's Monte Carlo estimate: at glass it reflects with probability F and
refracts otherwise. The features go through the colour image's own pixel filter (a Film), as OIDN requires.

What a sample records where it stops:
- a surface whose BSDF has a non-delta lobe: the reflectance its kind gives (`albedo`; diffuse: rho, else 0) and its shading normal on the side seen (world space, unit
  length); a one-sided surface seen from behind renders black, so its albedo is 0;
- an area light seen from its emitting side: the colour of its radiance, Le / max(Le), and its normal;
- a miss (the ray leaves the scene) or a mirror seen from behind: albedo 0, a miss also normal 0;
- a path still specular after MAX_SPECULAR vertices (trapped in glass): albedo 1 and the last specular
  normal, the albedo OIDN suggests for a mirror or a dielectric itself.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from .camera import pixel_count, primary_rays
from .film import Film, ReconstructionFilter
from .geometry import SceneGeometry
from .materials import SurfaceBSDF
from .materials.dispatch import delta_only
from .jit import INF, NO_PRIM, PCG32, Array2f, Array3f, Bool, Float, UInt32, opaque_u32
from .launch import chunks, seed_state
from .plan import PATH_CHUNK
from .rendering import Timed, timed
from .sampling import seeded_rng
from .scene import Scene

MAX_SPECULAR = 8     # specular vertices followed before a path is given up (albedo 1)
AOV_STREAM = 0xA0    # random stream of the AOV samples, distinct from the colour image's
DEFAULT_SPP = 8


@dataclass
class AovResult(Timed):
    albedo: np.ndarray      # (height, width, 3) float32 in [0, 1]
    normal: np.ndarray      # (height, width, 3) float32 in [-1, 1], world space, filtered (not renormalised)
    spp: int
    seconds: float = 0.0
    compile_seconds: float = 0.0


def render_aovs(scene: Scene, spp: int = DEFAULT_SPP, seed: int | None = None,
                rfilter: ReconstructionFilter | None = None) -> AovResult:
    """Albedo and normal images, `spp` samples per pixel, filtered like the colour image (the scene's
    pixel filter unless `rfilter` is given)."""
    if spp < 1:
        raise ValueError(f"AOV spp must be >= 1, got {spp}")
    seed = scene.seed if seed is None else seed
    geo, cam = SceneGeometry(scene), scene.camera
    rfilter = cam.rfilter if rfilter is None else rfilter
    albedo_film, normal_film = Film(cam.width, cam.height, rfilter), Film(cam.width, cam.height, rfilter)

    def run():
        for first, n in chunks(pixel_count(cam) * spp, PATH_CHUNK, False, "aov"):
            sample = dr.arange(UInt32, n) + opaque_u32(first)
            rng = seeded_rng(sample, seed_state(seed, AOV_STREAM))
            o, d, t_min, t_max, x, y = primary_rays(cam, sample // opaque_u32(spp), rng)
            albedo, normal = first_diffuse_features(geo, o, d, t_min, t_max, rng)
            albedo_film.put(x, y, albedo, run=spp)
            normal_film.put(x, y, normal, run=spp)
            dr.eval(albedo_film.data, normal_film.data)
        return albedo_film.develop(), normal_film.develop()

    (albedo, normal), seconds, compile_s = timed(run)
    # float rounding of the filter's weighted sums only
    return AovResult(np.clip(albedo, 0.0, 1.0), np.clip(normal, -1.0, 1.0), spp, seconds, compile_s)


@dr.syntax
def first_diffuse_features(geo: SceneGeometry, o: Array3f, d: Array3f, t_min: Float, t_max: Float,
                           rng: PCG32) -> tuple[Array3f, Array3f]:
    """Albedo and shading normal where each camera ray, followed through mirrors and glass, stops."""
    albedo, normal = Array3f(0.0), Array3f(0.0)
    skip, bounce, active = UInt32(NO_PRIM), UInt32(0), Bool(True)
    while active:
        albedo, normal, o, d, skip, active = _vertex(geo, rng, o, d, t_min, t_max, skip, bounce, albedo, normal)
        t_min, t_max = Float(0.0), Float(INF)
        bounce += 1
    return albedo, normal


def _vertex(geo, rng, o, d, t_min, t_max, skip, bounce, albedo, normal):
    """One vertex: record the features and stop, or continue along a direction sampled from a BSDF whose
    lobes are all delta."""
    hit = geo.closest_hit(o, d, t_min, t_max, skip)
    surf = geo.surface(hit)
    wi = -d
    bsdf = SurfaceBSDF(geo.materials, surf, wi, surf.valid)
    lit = surf.valid & bsdf.lit
    rho = bsdf.albedo(lit)
    ns = bsdf.normal
    light = Bool(False)
    if geo.emitters:
        le = geo.emitted(surf, wi)
        light = dr.max(le) > 0
        rho = dr.select(light, le / dr.max(le), rho)
    follow = lit & ~light & bsdf.kinds_where(delta_only)
    u1 = rng.next_float32()
    bs, _ = bsdf.sample(u1, Array2f(rng.next_float32(), rng.next_float32()), follow)
    new_d = dr.select(follow, bs.wo, d)
    give_up = follow & (bounce + 1 >= MAX_SPECULAR)
    rho = dr.select(give_up, Array3f(1.0), rho)
    record = surf.valid & (~follow | give_up)
    albedo = dr.select(record, rho, albedo)
    normal = dr.select(record, ns, normal)
    return albedo, normal, surf.p, new_d, surf.prim, follow & ~give_up
