"""The BSDF at a surface point, for any material kind (the contract: materials.bsdf): the registry of kinds,
the shading frame, two-sided materials, and each lane's kind's sample, eval and pdf.

Only the kinds a scene's kernel carries (MaterialTables.kinds) are traced: each one's functions run on
every lane, masked to its own, and the lanes' results are selected by kind. In a scene with a `blendbsdf`
every lane would so run every kind twice (once per blended material): there sample and eval go through
dr.switch instead, an indirect call that runs, per SIMD packet, only the kinds its lanes hold. Both give
the same image bit for bit. Render CPU seconds with the call over without it, warm kernel cache: blendbsdf.xml
0.50x, textured_parameters.xml 0.73x (medians of 4 renders, 2 interleaved processes a side), the cold
compilation of blendbsdf.xml 1.20 s against 3.26 s. Without a blend the call's overhead outweighs what it
skips: with it on every scene of several kinds, one process a side, hexagon_room.xml took 1.11x,
thin_and_null.xml 1.20x, conductors.xml 1.09x, principled.xml 1.03x (roughplastic.xml alone 0.84x)."""
from __future__ import annotations

from dataclasses import replace
from functools import partial

import drjit as dr

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..sampling import coordinate_system
from . import (bumpmap, conductor, dielectric, diffuse, normalmap, null, plastic, polarizer, pplastic, principled,
               principledthin, roughconductor, roughdielectric, roughplastic, thindielectric)
from .bsdf import DELTA, NULL, SMOOTH, TRANSMISSION, BSDFSample, has_flag

# a kind's code is its index
KINDS = (diffuse, conductor, dielectric, plastic, null, thindielectric, roughconductor, roughdielectric, roughplastic,
         principled, principledthin, polarizer, pplastic)
KIND_CODE = {module.NAME: code for code, module in enumerate(KINDS)}


class _Kinds:
    """Each lane's kind and its parameters for one material index per lane, in the local frame: the kinds'
    own functions, selected by kind."""

    def __init__(self, tables, surf, wi: Array3f, active: Bool):
        self.wi, self.tables, self.surf = wi, tables, surf
        self.kind = tables.kind(surf.material, active)
        self.kinds = [(code, KINDS[code]) for code in sorted(tables.kinds)]
        self.params = {code: module.params(tables, surf, active & (self.kind == code))
                       for code, module in self.kinds}
        self.called = by_indirect_call(tables)     # sample and eval by dr.switch

    def _switch(self, function, *args):
        """function(tables, module, surf, wi, *args) of each lane's kind, by an indirect call."""
        position = UInt32(0)
        for k, (code, _) in enumerate(self.kinds):
            position = dr.select(self.kind == code, k, position)
        targets = [partial(function, self.tables, module) for _, module in self.kinds]
        return dr.switch(position, targets, self.surf, self.wi, *args)

    def where(self, has) -> Bool:
        """Lanes whose kind's FLAGS satisfy `has` (static per kind)."""
        codes = [code for code, module in self.kinds if has(module)]
        if len(codes) == len(self.kinds):
            return Bool(True)
        out = Bool(False)
        for code in codes:
            out |= self.kind == code
        return out

    def _each(self, name: str, *args, smooth_only: bool = False):
        """(code mask, result) of the named function of every kind carried (only kinds with non-delta lobes
        where `smooth_only`: the others' eval and pdf are 0)."""
        for code, module in self.kinds:
            if smooth_only and not module.FLAGS & SMOOTH:
                continue
            mask = self.kind == code
            yield mask, getattr(module, name)(self.params[code], *args[:-1], args[-1] & mask)

    def eval_pdf(self, wo: Array3f, active: Bool) -> tuple[Array3f, Float]:
        if self.called:
            return self._switch(_eval_pdf, wo, active)
        value, density = Array3f(0.0), Float(0.0)
        for (mask, f), (_, p) in zip(self._each("eval", self.wi, wo, active, smooth_only=True),
                                     self._each("pdf", self.wi, wo, active, smooth_only=True)):
            value, density = dr.select(mask, f, value), dr.select(mask, p, density)
        return value, density

    def sample(self, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
        if self.called:
            return self._switch(_sample, u1, u2, active)
        out, weight = None, Array3f(0.0)
        for mask, (bs, w) in self._each("sample", self.wi, u1, u2, active):
            out = bs if out is None else _select(mask, bs, out)
            weight = dr.select(mask, w, weight)
        if out is None:        # a scene without materials
            return BSDFSample(Array3f(0.0), Float(0.0), Float(1.0), UInt32(0)), weight
        return out, weight

    def split(self, slot: UInt32, active: Bool) -> tuple[Array3f, Array3f]:
        wo, weight = Array3f(0.0), Array3f(0.0)
        for code, module in self.kinds:
            if not hasattr(module, "split"):
                continue
            mask = active & (self.kind == code)
            for k, (d, w) in enumerate(module.split(self.params[code], self.wi, mask)):
                chosen = mask & (slot == k)
                wo, weight = dr.select(chosen, d, wo), dr.select(chosen, w, weight)
        return wo, weight

    def null_transmission(self, active: Bool) -> Array3f:
        out = Array3f(0.0)
        for code, module in self.kinds:
            if hasattr(module, "null_transmission"):
                mask = active & (self.kind == code)
                out = dr.select(mask, module.null_transmission(self.params[code], self.wi, mask), out)
        return out

    def albedo(self, active: Bool) -> Array3f:
        out = Array3f(0.0)
        for code, module in self.kinds:
            if hasattr(module, "albedo"):
                out = dr.select(active & (self.kind == code), module.albedo(self.params[code]), out)
        return out


def by_indirect_call(tables) -> bool:
    """Whether the kinds' sample and eval go through dr.switch: in scenes with a blend of several kinds."""
    return tables.any_blend and len(tables.kinds) > 1


def _eval_pdf(tables, module, surf, wi: Array3f, wo: Array3f, active: Bool) -> tuple[Array3f, Float]:
    """A dr.switch target: f * |cos| and pdf of one kind (0 for a kind of delta lobes only)."""
    if not module.FLAGS & SMOOTH:
        return Array3f(0.0), Float(0.0)
    params = module.params(tables, surf, active)
    return module.eval(params, wi, wo, active), module.pdf(params, wi, wo, active)


def _sample(tables, module, surf, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """A dr.switch target: one kind's sample and weight."""
    return module.sample(module.params(tables, surf, active), wi, u1, u2, active)


def _select(mask: Bool, a: BSDFSample, b: BSDFSample) -> BSDFSample:
    return BSDFSample(*(dr.select(mask, x, y) for x, y in zip((a.wo, a.pdf, a.eta, a.sampled_type),
                                                               (b.wo, b.pdf, b.eta, b.sampled_type))))


class SurfaceBSDF:
    """The BSDF of each lane's surface point seen along wi (world space, pointing away from the surface).

    Directions in and out are in world space; the kinds see them in the local shading frame (z the shading
    normal), mirrored through the surface on the back of a two-sided material. A `blendbsdf` is two
    materials, f = (1 - w) f0 + w f1, sampled by one of them (the second with probability w); a sample from
    a non-delta lobe reports the mixture's pdf, the density MIS needs. A `mask`ed material (opacity < 1) is
    its BSDF with probability opacity and a null lobe (the ray passes unchanged) otherwise: eval and pdf are
    scaled by the opacity, as in Mitsuba's `mask`.
    `smooth`: lanes whose BSDF has a non-delta lobe (next-event estimation applies);
    `delta`: lanes whose BSDF has a delta lobe (a mask's null lobe included);
    `lit`: lanes where the BSDF is not black from wi's side (one-sided kinds without transmission)."""

    def __init__(self, tables, surf, wi: Array3f, active: Bool):
        self.n = self.n0 = surf.ns
        self.s, self.t = shading_tangents(self.n, surf.dpdu)
        self.tilt = None                   # normal-mapped lanes' (tilted normal, has, shadowing) (None: no such)
        if tables.any_normalmap or tables.any_bumpmap:
            self._tilt(tables, surf, self._local(wi), active)
        wi = self._local(wi)
        self.opacity = tables.opacity(surf, active) if tables.any_mask else None   # the mask's own
        self.flip = None                   # lanes on the back of a two-sided material (None: no such material)
        if tables.any_twosided:
            self.flip = tables.twosided(surf.material, active) & (wi.z < 0)
            wi = Array3f(wi.x, wi.y, dr.select(self.flip, -wi.z, wi.z))
            if tables.any_back:
                surf = replace(surf, material=dr.select(self.flip, tables.back(surf.material, active), surf.material))
        self.wi = wi
        self.parts = [_Kinds(tables, surf, wi, active)]
        self.blend = None                  # the second material's weight w (None: no blend in the scene)
        if tables.any_blend:
            self.blend, second = tables.blend(surf, active)
            self.parts.append(_Kinds(tables, replace(surf, material=second), wi, active))
        self.kind = self.parts[0].kind
        self.smooth = self._either(lambda m: m.FLAGS & SMOOTH)
        self.delta = self._either(lambda m: m.FLAGS & DELTA)
        self.lit = (wi.z > 0) | self.kinds_where(lambda m: m.FLAGS & TRANSMISSION)
        if self.opacity is not None:
            masked = self.opacity < 1.0
            self.delta, self.lit = self.delta | masked, self.lit | masked

    def _tilt(self, tables, surf, wi: Array3f, active: Bool) -> None:
        """Normal-mapped lanes (materials.normalmap): the frame becomes the tilted one, in world space."""
        m, has, flip, shadow = tables.normalmap(surf, active)
        first = Array3f(1.0, 0.0, 0.0)
        if tables.any_bumpmap:            # bump-mapped lanes (materials.bumpmap)
            grad, bumped = tables.bump_gradient(surf, active)
            nb = bumpmap.bumped_normal(self.n0, surf.n, surf.dpdu, surf.dpdv, grad)
            m = dr.select(bumped, self._local(nb), m)
            first = dr.select(bumped, surf.dpdu, first)      # Mitsuba's: world components in the local frame
            has |= bumped
        mirrored = flip & (wi.z * dr.dot(wi, m) <= 0)
        m = Array3f(dr.select(mirrored, -m.x, m.x), dr.select(mirrored, -m.y, m.y), m.z)
        m = dr.select(has, m, Array3f(0.0, 0.0, 1.0))
        local = normalmap.tilted_frame(m, first)
        self.s, self.t, self.n = (self.s * v.x + self.t * v.y + self.n0 * v.z for v in local)
        self.tilt = (local[2], has, shadow)

    def _tilted(self, wo: Array3f, wo_local: Array3f, value: Array3f) -> tuple[Array3f, Bool]:
        """On normal-mapped lanes, a response (f cos, or a sample's weight) for world direction wo (wo_local:
        in the tilted frame): 0 below the unperturbed or the tilted surface, times the shadowing term."""
        n, has, shadow = self.tilt
        cos = dr.dot(wo, self.n0)
        above = ~has | (cos * wo_local.z > 0)
        value = dr.select(has & shadow, value * normalmap.shadowing(n, cos), value)
        return dr.select(above, value, Array3f(0.0)), above

    def state(self) -> list:
        """The arrays it holds, for SceneGeometry.keep."""
        return [self.s, self.t, self.n, self.n0, list(self.tilt or ()), self.wi, self.flip, self.opacity, self.blend, self.smooth, self.delta,
                self.lit, [(part.kind, list(part.params.values())) for part in self.parts]]

    def kinds_where(self, has) -> Bool:
        """Lanes whose kinds' FLAGS (both a blend's) satisfy `has` (static per kind)."""
        out = self.parts[0].where(has)
        for part in self.parts[1:]:
            out &= part.where(has)
        return out

    def _either(self, has) -> Bool:
        out = self.parts[0].where(has)
        for part in self.parts[1:]:
            out |= part.where(has)
        return out

    @property
    def normal(self) -> Array3f:
        """The shading normal (before any normal map) on the side of wi for two-sided materials."""
        return dr.select(self.flip, -self.n0, self.n0) if self.flip is not None else self.n0

    def _local(self, v: Array3f) -> Array3f:
        return Array3f(dr.dot(v, self.s), dr.dot(v, self.t), dr.dot(v, self.n))

    def to_local(self, v: Array3f) -> Array3f:
        """A world direction in the frame the lane's kind sees (mirrored on a two-sided material's back)."""
        v = self._local(v)
        return Array3f(v.x, v.y, dr.select(self.flip, -v.z, v.z)) if self.flip is not None else v

    def to_world(self, v: Array3f) -> Array3f:
        z = dr.select(self.flip, -v.z, v.z) if self.flip is not None else v.z
        return self.s * v.x + self.t * v.y + self.n * z

    def _eval_pdf_local(self, wo: Array3f, active: Bool) -> tuple[Array3f, Float]:
        value, density = self.parts[0].eval_pdf(wo, active)
        if self.blend is not None:
            v1, p1 = self.parts[1].eval_pdf(wo, active)
            value, density = dr.lerp(value, v1, self.blend), dr.lerp(density, p1, self.blend)
        return value, density

    def eval_pdf(self, wo: Array3f, active: Bool) -> tuple[Array3f, Float]:
        """f * |cos(wo)| and the solid-angle pdf of sampling world direction wo."""
        local = self.to_local(wo)
        value, density = self._eval_pdf_local(local, active)
        if self.tilt is not None:
            value, above = self._tilted(wo, local, value)
            density = dr.select(above, density, 0.0)
        if self.opacity is not None:
            value, density = value * self.opacity, density * self.opacity
        return value, density

    def eval(self, wo: Array3f, active: Bool) -> Array3f:
        return self.eval_pdf(wo, active)[0]

    def sample(self, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
        """A sampled direction (BSDFSample, wo in world space) and its weight f |cos| / pdf."""
        if self.opacity is None:
            bs, weight = self._tilted_sample(*self._sample(u1, u2, active))
            return replace(bs, wo=self.to_world(bs.wo)), weight
        nested = u1 < self.opacity               # a mask: its BSDF with probability opacity, else straight on
        bs, weight = self._tilted_sample(*self._sample(dr.select(nested, u1 / self.opacity, u1), u2, active & nested))
        through = BSDFSample(-self.wi, 1.0 - self.opacity, Float(1.0), UInt32(NULL))
        bs = _select(nested, replace(bs, pdf=bs.pdf * self.opacity), through)
        return (replace(bs, wo=self.to_world(bs.wo)),
                dr.select(nested, weight, dr.select(active, Array3f(1.0), Array3f(0.0))))

    def _tilted_sample(self, bs: BSDFSample, weight: Array3f) -> tuple[BSDFSample, Array3f]:
        """A local sample on normal-mapped lanes: nothing below the unperturbed or the tilted surface, the
        weight times the shadowing term."""
        if self.tilt is None:
            return bs, weight
        weight, above = self._tilted(self.to_world(bs.wo), bs.wo, weight)
        return replace(bs, pdf=dr.select(above, bs.pdf, 0.0)), weight

    def _sample(self, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
        """A local sample of the (blended) BSDF."""
        if self.blend is None:
            return self.parts[0].sample(u1, u2, active)
        w = self.blend
        second = u1 < w
        u = dr.select(second, u1 / w, (u1 - w) / (1.0 - w))
        bs0, w0 = self.parts[0].sample(u, u2, active & ~second)
        bs1, w1 = self.parts[1].sample(u, u2, active & second)
        bs, weight = _select(second, bs1, bs0), dr.select(second, w1, w0)
        mixture = self._eval_pdf_local(bs.wo, active)[1]
        chosen = bs.pdf * dr.select(second, w, 1.0 - w)
        return replace(bs, pdf=dr.select(has_flag(bs.sampled_type, DELTA), chosen, mixture)), weight

    def split(self, slot: UInt32, active: Bool) -> tuple[Array3f, Array3f]:
        """Lobe `slot` of each lane's split kind: world direction and weight f |cos| (delta lobes)."""
        wo, weight = self.parts[0].split(slot, active)
        return self.to_world(wo), weight

    def null_transmission(self, active: Bool) -> Array3f:
        """The fraction of light passing straight through the surface (Mitsuba's eval_null_transmission): a
        blend's mixture, a mask's 1 - opacity plus opacity times its BSDF's."""
        value = self.parts[0].null_transmission(active)
        if self.blend is not None:
            value = dr.lerp(value, self.parts[1].null_transmission(active), self.blend)
        if self.opacity is not None:
            value = dr.select(active, (1.0 - self.opacity) + self.opacity * value, Array3f(0.0))
        return value

    def albedo(self, active: Bool) -> Array3f:
        """The reflectance the albedo AOV shows (kinds that give one; 0 elsewhere)."""
        return self.parts[0].albedo(active)


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
