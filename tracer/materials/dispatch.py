"""The BSDF at a surface point, for any material kind (the contract: materials.bsdf): the registry of kinds,
the shading frame, two-sided materials, and each lane's kind's sample, eval and pdf.

Only the kinds a scene's kernel carries (MaterialTables.kinds) are traced: each one's functions run on
every lane, masked to its own, and the lanes' results are selected by kind."""
from __future__ import annotations

from dataclasses import replace

import drjit as dr

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..sampling import coordinate_system
from . import (conductor, dielectric, diffuse, null, plastic, roughconductor, roughdielectric, roughplastic,
               thindielectric)
from .bsdf import DELTA, NULL, SMOOTH, TRANSMISSION, BSDFSample

# a kind's code is its index
KINDS = (diffuse, conductor, dielectric, plastic, null, thindielectric, roughconductor, roughdielectric, roughplastic)
KIND_CODE = {module.NAME: code for code, module in enumerate(KINDS)}


class SurfaceBSDF:
    """The BSDF of each lane's surface point seen along wi (world space, pointing away from the surface).

    Directions in and out are in world space; the kinds see them in the local shading frame (z the shading
    normal), mirrored through the surface on the back of a two-sided material.
    A `mask`ed material (opacity < 1) is its BSDF with probability opacity and a null lobe (the ray passes
    unchanged) otherwise: eval and pdf are scaled by the opacity, as in Mitsuba's `mask`.
    `smooth`: lanes whose BSDF has a non-delta lobe (next-event estimation applies);
    `delta`: lanes whose BSDF has a delta lobe (a mask's null lobe included);
    `lit`: lanes where the BSDF is not black from wi's side (one-sided kinds without transmission)."""

    def __init__(self, tables, surf, wi: Array3f, active: Bool):
        self.n = surf.ns
        self.s, self.t = shading_tangents(self.n, surf.dpdu)
        wi = self._local(wi)
        self.opacity = tables.opacity(surf.material, active) if tables.any_mask else None   # the mask's own
        self.flip = None                   # lanes on the back of a two-sided material (None: no such material)
        if tables.any_twosided:
            self.flip = tables.twosided(surf.material, active) & (wi.z < 0)
            wi = Array3f(wi.x, wi.y, dr.select(self.flip, -wi.z, wi.z))
            if tables.any_back:
                surf = replace(surf, material=dr.select(self.flip, tables.back(surf.material, active), surf.material))
        self.wi = wi
        self.kind = tables.kind(surf.material, active)
        self.kinds = [(code, KINDS[code]) for code in sorted(tables.kinds)]
        self.params = {code: module.params(tables, surf, active & (self.kind == code))
                       for code, module in self.kinds}
        self.smooth = self.kinds_where(lambda m: m.FLAGS & SMOOTH)
        self.delta = self.kinds_where(lambda m: m.FLAGS & DELTA)
        self.lit = (wi.z > 0) | self.kinds_where(lambda m: m.FLAGS & TRANSMISSION)
        if self.opacity is not None:
            masked = self.opacity < 1.0
            self.delta, self.lit = self.delta | masked, self.lit | masked

    def state(self) -> list:
        """The arrays it holds, for SceneGeometry.keep."""
        return [self.s, self.t, self.n, self.wi, self.kind, self.flip, self.opacity, self.smooth, self.delta, self.lit,
                list(self.params.values())]

    def kinds_where(self, has) -> Bool:
        """Lanes whose kind's FLAGS satisfy `has` (static per kind)."""
        codes = [code for code, module in self.kinds if has(module)]
        if len(codes) == len(self.kinds):
            return Bool(True)
        out = Bool(False)
        for code in codes:
            out |= self.kind == code
        return out

    @property
    def normal(self) -> Array3f:
        """The shading normal on the side of wi for two-sided materials (the frame's z as the kind sees it)."""
        return dr.select(self.flip, -self.n, self.n) if self.flip is not None else self.n

    def _local(self, v: Array3f) -> Array3f:
        return Array3f(dr.dot(v, self.s), dr.dot(v, self.t), dr.dot(v, self.n))

    def to_local(self, v: Array3f) -> Array3f:
        """A world direction in the frame the lane's kind sees (mirrored on a two-sided material's back)."""
        v = self._local(v)
        return Array3f(v.x, v.y, dr.select(self.flip, -v.z, v.z)) if self.flip is not None else v

    def to_world(self, v: Array3f) -> Array3f:
        z = dr.select(self.flip, -v.z, v.z) if self.flip is not None else v.z
        return self.s * v.x + self.t * v.y + self.n * z

    def _each(self, name: str, *args, smooth_only: bool = False):
        """(code mask, result) of the named function of every kind carried (only kinds with non-delta lobes
        where `smooth_only`: the others' eval and pdf are 0)."""
        for code, module in self.kinds:
            if smooth_only and not module.FLAGS & SMOOTH:
                continue
            mask = self.kind == code
            yield mask, getattr(module, name)(self.params[code], *args[:-1], args[-1] & mask)

    def eval_pdf(self, wo: Array3f, active: Bool) -> tuple[Array3f, Float]:
        """f * |cos(wo)| and the solid-angle pdf of sampling world direction wo."""
        wo = self.to_local(wo)
        value, density = Array3f(0.0), Float(0.0)
        for (mask, f), (_, p) in zip(self._each("eval", self.wi, wo, active, smooth_only=True),
                                     self._each("pdf", self.wi, wo, active, smooth_only=True)):
            value, density = dr.select(mask, f, value), dr.select(mask, p, density)
        if self.opacity is not None:
            value, density = value * self.opacity, density * self.opacity
        return value, density

    def eval(self, wo: Array3f, active: Bool) -> Array3f:
        return self.eval_pdf(wo, active)[0]

    def sample(self, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
        """A sampled direction (BSDFSample, wo in world space) and its weight f |cos| / pdf."""
        if self.opacity is None:
            return self._sample(u1, u2, active)
        nested = u1 < self.opacity               # a mask: its BSDF with probability opacity, else straight on
        bs, weight = self._sample(dr.select(nested, u1 / self.opacity, u1), u2, active & nested)
        through = BSDFSample(self.to_world(-self.wi), 1.0 - self.opacity, Float(1.0), UInt32(NULL))
        bs = BSDFSample(*(dr.select(nested, a, b) for a, b in zip(
            (bs.wo, bs.pdf * self.opacity, bs.eta, bs.sampled_type), (through.wo, through.pdf, through.eta,
                                                                          through.sampled_type))))
        return bs, dr.select(nested, weight, dr.select(active, Array3f(1.0), Array3f(0.0)))

    def _sample(self, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
        out, weight = None, Array3f(0.0)
        for mask, (bs, w) in self._each("sample", self.wi, u1, u2, active):
            if out is None:
                out = bs
            else:
                out = BSDFSample(*(dr.select(mask, a, b) for a, b in
                                   zip((bs.wo, bs.pdf, bs.eta, bs.sampled_type),
                                       (out.wo, out.pdf, out.eta, out.sampled_type))))
            weight = dr.select(mask, w, weight)
        if out is None:        # a scene without materials
            return BSDFSample(Array3f(0.0), Float(0.0), Float(1.0), UInt32(0)), weight
        return replace(out, wo=self.to_world(out.wo)), weight

    def split(self, slot: UInt32, active: Bool) -> tuple[Array3f, Array3f]:
        """Lobe `slot` of each lane's split kind: world direction and weight f |cos| (delta lobes)."""
        wo, weight = Array3f(0.0), Array3f(0.0)
        for code, module in self.kinds:
            if not hasattr(module, "split"):
                continue
            mask = active & (self.kind == code)
            for k, (d, w) in enumerate(module.split(self.params[code], self.wi, mask)):
                chosen = mask & (slot == k)
                wo, weight = dr.select(chosen, d, wo), dr.select(chosen, w, weight)
        return self.to_world(wo), weight

    def albedo(self, active: Bool) -> Array3f:
        """The reflectance the albedo AOV shows (kinds that give one; 0 elsewhere)."""
        out = Array3f(0.0)
        for code, module in self.kinds:
            if hasattr(module, "albedo"):
                out = dr.select(active & (self.kind == code), module.albedo(self.params[code]), out)
        return out


def shading_tangents(n: Array3f, dpdu: Array3f | None) -> tuple[Array3f, Array3f]:
    """The shading frame's tangents about the shading normal n: Mitsuba's (its SurfaceInteraction's
    sh_frame), dp/du made orthogonal to n (Gram-Schmidt), then n x s; without dpdu (a scene whose materials
    are all invariant under rotation about the normal) any frame: Duff et al.'s about n."""
    if dpdu is None:
        return coordinate_system(n)
    s = dr.normalize(dpdu - n * dr.dot(n, dpdu))
    return s, dr.cross(n, s)


def split_count(code: int) -> int:
    """How many lobes the kind's `split` lists (0: none; it is sampled)."""
    return getattr(KINDS[code], "SPLIT", 0)


def delta_only(module) -> bool:
    """Whether every lobe of the kind (its module) is a delta lobe."""
    return not module.FLAGS & SMOOTH and bool(module.FLAGS & DELTA)
