"""The BSDF interface every material kind implements, its flags and sample record, and the host description
of a material as the loader builds it from a Mitsuba <bsdf>.

The contract (Mitsuba's, as in its BSDF base class; pbrt-v4's BxDF is the same): a kind is one module of
tracer/materials/ listed in materials.dispatch.KINDS, and works in the LOCAL shading frame: z is the shading
normal, wi and wo both point away from the surface, cos_theta(w) = w.z. The module provides

    NAME                    the kind's name (BSDF.kind), also its key in the tables
    FLAGS                   every lobe the kind may have (materials.flags.BSDFFlags, Mitsuba's bits, or-ed;
                            side bits such as FRONT_SIDE may be set too)
    PLUGINS, from_xml       the XML plugins it reads and their parameters (returns a BSDF)
    table(bsdfs)            optional: one row of floats per material (np.ndarray (n, fields); rows of other
                            kinds are ignored), or None where no material of the scene needs one
    params(tables, surf, active) -> P
                            the lane's parameters, gathered once per vertex from its row
                            (tables.row(NAME, surf.material, active)) and the shared columns
                            (tables.reflectance(surf, active): a reflectance, textured where the material is)
    sample(p, wi, u1: Float, u2: Array2f, active) -> (BSDFSample, weight: Array3f)
                            a direction wo drawn from the BSDF (u1 picks a lobe, u2 the direction) and
                            weight = f * |cos_theta(wo)| / pdf (0 where nothing is sampled)
    eval(p, wi, wo, active) -> Array3f        f * |cos_theta(wo)| of the non-delta lobes (0 for delta ones)
    pdf(p, wi, wo, active) -> Float           the solid-angle density with which sample draws wo from its
                                              non-delta lobes (0 for delta ones)
    SPLIT, split(p, wi, active) -> [(wo, weight)]
                                              optional, for kinds whose lobes are all delta: every lobe with
                                              its weight f * |cos| (not divided by a probability), SPLIT of them; the
                                              branching estimator then follows each lobe (the report's glass,
                                              eq. 7-8, 12) instead of one sampled lobe
    albedo(p) -> Array3f                      optional: the reflectance shown in the albedo AOV
    null_transmission(p, wi, active) -> Array3f
                                              optional, for kinds with a NULL lobe: the fraction of light
                                              that passes straight through (Mitsuba's eval_null_transmission;
                                              `volpath`'s shadow rays carry it across the surface; 0 without)

BSDFSample (materials.flags) holds wo, pdf, eta and sampled_type. Its pdf for a delta lobe is the
probability of choosing that lobe (Mitsuba's convention); sampled_type says which lobe was taken (a path's
next vertex skips MIS after a delta lobe). eta is the relative index of refraction n2 / n1 of a sampled
transmission (1 for reflection): a path's radiance scale 1/eta^2 is part of the weight, and Russian roulette
reads the product of the etas.

Sides. A kind without transmission lobes is black seen from below (wi.z <= 0), as Mitsuba's one-sided BSDFs:
its functions return 0 there (so each module stands alone, e.g. in a chi-square test), and the dispatcher
also uses FLAGS to send no shadow rays and no branches from such lanes. `twosided` materials are resolved by
the dispatcher, not by the kinds: seen from below, wi and wo are mirrored through the surface (z negated),
as Mitsuba's twosided does, so a kind never sees a two-sided case.

Worked example: a new kind `roughconductor` with fields alpha, specular reflectance, eta and k.

    # tracer/materials/roughconductor.py
    NAME, FLAGS = "roughconductor", BSDFFlags.GLOSSY_REFLECTION | BSDFFlags.FRONT_SIDE
    PLUGINS = {"roughconductor": ("distribution", "alpha", ...)}
    def from_xml(ctx, props, node) -> BSDF: ...           # a BSDF("roughconductor", ...) with its parameters
    def table(bsdfs):                                     # alpha, specular reflectance (3), eta (3), k (3)
        rows = np.zeros((len(bsdfs), 10))
        for i, b in enumerate(bsdfs):
            if b.kind == NAME:
                rows[i] = [b.alpha, *b.specular_reflectance, *b.eta, *b.k]
        return rows
    def params(tables, surf, active):                     # any structure: sample, eval and pdf receive it
        r = tables.row(NAME, surf.material, active)       # r[k]: field k of each lane's row, a Float
        return RoughConductorParams(microfacet(True, r[0]), Array3f(*r[4:7]), Array3f(*r[7:10]),
                                    Array3f(*r[1:4]))     # a texture: tables.reflectance(surf, active)
    def sample(p, wi, u1, u2, active): ...                # in the local frame; sampled_type GLOSSY_REFLECTION
    def eval(p, wi, wo, active): ...
    def pdf(p, wi, wo, active): ...

and one line in materials.dispatch.KINDS. The loader then reads the plugin (materials.PLUGINS), the table is
built for scenes that use the kind, its code is compiled into kernels only there, and both estimators use it
through materials.dispatch.SurfaceBSDF: the path tracer's next-event estimation and MIS, the branching
estimator's N shadow rays and M sampled directions. Host fields the kind needs go into BSDF below.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import drjit as dr

from ..jit import Array3f, UInt32
from .flags import BSDFFlags, BSDFSample
from .textures import Texture

__all__ = ["BSDF", "BSDFFlags", "BSDFSample", "has_flag", "reflect_local", "front", "zero_unless"]

# BSDFFlags (materials.flags, Mitsuba 3's bits) as plain ints for kernels, and the unions Mitsuba names
NULL, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION = (int(f) for f in (
    BSDFFlags.NULL, BSDFFlags.DIFFUSE_REFLECTION, BSDFFlags.DIFFUSE_TRANSMISSION))
GLOSSY_REFLECTION, GLOSSY_TRANSMISSION = int(BSDFFlags.GLOSSY_REFLECTION), int(BSDFFlags.GLOSSY_TRANSMISSION)
DELTA_REFLECTION, DELTA_TRANSMISSION = int(BSDFFlags.DELTA_REFLECTION), int(BSDFFlags.DELTA_TRANSMISSION)
REFLECTION = DIFFUSE_REFLECTION | GLOSSY_REFLECTION | DELTA_REFLECTION
TRANSMISSION = NULL | DIFFUSE_TRANSMISSION | GLOSSY_TRANSMISSION | DELTA_TRANSMISSION
DIFFUSE = DIFFUSE_REFLECTION | DIFFUSE_TRANSMISSION
GLOSSY = GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
SMOOTH = DIFFUSE | GLOSSY
DELTA = NULL | DELTA_REFLECTION | DELTA_TRANSMISSION
LOBES = REFLECTION | TRANSMISSION          # the bits that name lobes (not FRONT_SIDE, ANISOTROPIC, ...)


def has_flag(flags: UInt32, bits: int):
    """Whether any of `bits` is set in `flags` (per lane)."""
    return (flags & int(bits)) != 0


def reflect_local(wi: Array3f) -> Array3f:
    """Mirror direction of wi about the local normal z (eq. 5 in the shading frame)."""
    return Array3f(-wi.x, -wi.y, wi.z)


def front(wi: Array3f, wo: Array3f | None = None):
    """Lanes where wi (and wo) lie above the surface: where a one-sided reflection is not black."""
    ok = wi.z > 0
    return ok if wo is None else ok & (wo.z > 0)


def zero_unless(mask, value: Array3f) -> Array3f:
    return dr.select(mask, value, Array3f(0.0))


@dataclass(frozen=True)
class BSDF:
    """A material: its kind's fields, and whether it is `twosided` (then `back`, if given, is the material seen
    from below). `diffuse` (Lambertian), `conductor` (smooth: `reflectance` times the exact
    Fresnel reflectance of the complex index eta + i k; eta 0, k 1 is a perfect mirror), `dielectric`, or
    `plastic` (Mitsuba's smooth plastic: a dielectric interface over a diffuse base of `reflectance`)."""

    kind: str
    reflectance: tuple[float, float, float] = (0.5, 0.5, 0.5)
    twosided: bool = False
    int_ior: float = 1.5046
    ext_ior: float = 1.000277
    eta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    k: tuple[float, float, float] = (1.0, 1.0, 1.0)
    texture: Texture | None = None   # the reflectance (a diffuse one) given by a texture
    specular_reflectance: tuple[float, float, float] = (1.0, 1.0, 1.0)   # plastic's specular layer
    nonlinear: bool = False                                              # plastic's internal scattering model
    specular_transmittance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # roughdielectric's
    distribution: str = "beckmann"      # the rough kinds' microfacet distribution (materials.microfacet)
    alpha_u: float = 0.1
    alpha_v: float = 0.1
    sample_visible: bool = True
    back: BSDF | None = None        # a two-sided material's back, where it differs from the front (this BSDF)
    opacity: float = 1.0            # a `mask`: the probability of scattering by this BSDF (else the ray passes)
    blend: tuple[float, BSDF] | None = None   # a `blendbsdf`: (w, the second material); f = (1 - w) f + w f2
    normalmap: Texture | None = None  # a `normalmap` around it: the tilted normals (materials.normalmap)
    normalmap_flip: bool = True       # its flip_invalid_normals
    normalmap_shadowing: bool = True  # its use_shadowing_function
    bump_scale: float = 1.0           # a `bumpmap` around it (its texture: slot 'bumpmap'): the height's scale
    extra: tuple[tuple[str, float], ...] = ()   # a kind's own scalar parameters by name (principled's)
    textures: tuple[tuple[str, Texture], ...] = ()   # other parameters given by textures: (slot, texture)
    pplastic_weight: float = 0.5      # pplastic's probability of sampling its specular lobe (materials.pplastic)

    def slot_textures(self) -> list[tuple[str, Texture]]:
        """Every parameter a texture drives, by slot: 'reflectance', 'normalmap' and the `textures`."""
        named = [("reflectance", self.texture), ("normalmap", self.normalmap)]
        return [(slot, t) for slot, t in named if t is not None] + list(self.textures)

    def every_texture(self) -> list[Texture]:
        """The textures of this material, its back and its blend's second material."""
        parts = [self] + [b for b in (self.back, self.blend[1] if self.blend else None) if b is not None]
        return [t for p in parts for t in ([t for _, t in p.slot_textures()] if p is self else p.every_texture())]

    def texture_of(self, slot: str) -> Texture | None:
        return dict(self.slot_textures()).get(slot)

    def with_texture(self, slot: str, texture: Texture | None) -> BSDF:
        """This material with `slot` given by `texture` (None: unchanged)."""
        if texture is None:
            return self
        return replace(self, textures=tuple((s, t) for s, t in self.textures if s != slot) + ((slot, texture),))

    @property
    def masked(self) -> bool:
        """A `mask` with an opacity below 1 somewhere."""
        return self.opacity < 1.0 or self.texture_of("opacity") is not None

    @property
    def isotropic(self) -> bool:
        """Roughness the same along both tangents (the frame's rotation about the normal does not matter):
        alpha_u and alpha_v, and a kind's own `anisotropic` parameter (principled's) 0."""
        anisotropic = dict(self.extra).get("anisotropic", 0.0) != 0 or self.texture_of("anisotropic") is not None
        return (self.alpha_u == self.alpha_v and self.texture_of("alpha_u") is self.texture_of("alpha_v")
                and not anisotropic)

    @property
    def perfect_mirror(self) -> bool:
        """A conductor that reflects everything at every angle (Fresnel reflectance 1, reflectance 1)."""
        return self.eta == (0.0, 0.0, 0.0) and self.k == (1.0, 1.0, 1.0) and self.reflectance == (1.0, 1.0, 1.0)
