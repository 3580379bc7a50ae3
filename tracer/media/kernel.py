"""The scene's media as kernel code: each lane's medium is a code (0: none, the vacuum; k: the scene's
k-th medium), and every function here runs each medium the scene has, masked to its lanes (a scene
without media traces none of it). Shapes hold media as Mitsuba's do: a ray crossing a shape with an
`interior` or `exterior` medium enters the interior where it goes against the shape's geometric normal,
the exterior (none when not given) where it goes along it."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from . import phase as phases
from .medium import Interaction, MediumKernel

VACUUM = 0


class MediaKernel:
    def __init__(self, scene, geo):
        self.media = [MediumKernel(m) for m in scene.media]
        n = max(geo.n_prims, 1)
        interior, exterior = np.zeros(n, np.uint32), np.zeros(n, np.uint32)
        for shape, (inside, outside) in scene.shape_media.items():
            lo, hi = geo.prim_range(shape)
            interior[lo:hi], exterior[lo:hi] = inside, outside
        self.interior, self.exterior = UInt32(interior), UInt32(exterior)
        self.camera = scene.camera_medium
        self.own = geo.own       # instanced triangles hold no media (the loader refuses them)

    def _each(self, code: UInt32):
        for k, m in enumerate(self.media, start=1):
            yield code == k, m

    def _flag(self, code: UInt32, flag) -> Bool:
        out = Bool(False)
        for mask, m in self._each(code):
            if flag(m.medium):
                out |= mask
        return out

    def homogeneous(self, code: UInt32) -> Bool:
        return self._flag(code, lambda m: m.homogeneous)

    def spectral(self, code: UInt32) -> Bool:
        return self._flag(code, lambda m: m.spectral_extinction)

    def sample_emitters(self, code: UInt32) -> Bool:
        return self._flag(code, lambda m: m.sample_emitters)

    def sample_interaction(self, code: UInt32, o: Array3f, d: Array3f, t_max: Float, u: Float, channel,
                           active: Bool) -> Interaction:
        out = None
        for mask, m in self._each(code):
            mi = m.sample_interaction(o, d, t_max, u, channel, active & mask)
            out = mi if out is None else Interaction(*(dr.select(mask, a, b) for a, b in zip(
                (mi.t, mi.p, mi.sigma_s, mi.sigma_n, mi.sigma_t, mi.combined, mi.mint),
                (out.t, out.p, out.sigma_s, out.sigma_n, out.sigma_t, out.combined, out.mint))))
        return out

    def phase_eval(self, code: UInt32, d: Array3f, wo: Array3f) -> Float:
        out = Float(0.0)
        for mask, m in self._each(code):
            out = dr.select(mask, phases.eval(m.medium.phase, d, wo), out)
        return out

    def phase_sample(self, code: UInt32, d: Array3f, u: Array2f) -> tuple[Array3f, Float]:
        wo, pdf = Array3f(d), Float(0.0)
        for mask, m in self._each(code):
            w, p = phases.sample(m.medium.phase, d, u)
            wo, pdf = dr.select(mask, w, wo), dr.select(mask, p, pdf)
        return wo, pdf

    def transition(self, prim: UInt32, valid: Bool) -> tuple[Bool, UInt32, UInt32]:
        """Whether crossing primitive `prim` changes the medium, and its interior and exterior codes."""
        valid = self.own(prim, valid)
        inside = dr.gather(UInt32, self.interior, prim, valid)
        outside = dr.gather(UInt32, self.exterior, prim, valid)
        return valid & ((inside | outside) != 0), inside, outside

    def target(self, surf, d: Array3f, medium: UInt32) -> UInt32:
        """The medium a ray leaving surface `surf` along d travels in (`medium` where it is no transition)."""
        crossing, inside, outside = self.transition(surf.prim, surf.valid)
        return dr.select(crossing, dr.select(dr.dot(d, surf.n) > 0, outside, inside), medium)

    def describe(self) -> str:
        kinds = [f"{m.medium.kind} ({'hg g = %g' % m.medium.phase.g if not m.medium.phase.isotropic else 'isotropic'})"
                 for m in self.media]
        return f"media: {', '.join(kinds)}"
