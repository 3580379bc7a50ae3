"""The scene's materials as the kernels see them: per-material tables gathered by material index, and the
lookups the integrators make. A table a scene's materials do not need is not built, and its code is not
traced (plastic, textures, conductor Fresnel)."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float, UInt32
from . import plastic
from .bsdf import BSDF, KIND_CODE
from .fresnel import fresnel_conductor
from .textures import TextureTables


class MaterialTables:
    """`kinds`: the material codes the kernel carries (DIFFUSE, CONDUCTOR, ...; default: those of `bsdfs`)."""

    def __init__(self, bsdfs: list[BSDF], kinds: set[int] | None = None):
        self.bsdfs = bsdfs
        self.kinds = {KIND_CODE[b.kind] for b in bsdfs} if kinds is None else set(kinds)
        self.textured = any(b.texture is not None for b in bsdfs)
        # conductors other than perfect mirrors need their Fresnel term; without them the kernel has none
        self.fresnel_conductors = any(b.kind == "conductor" and not b.perfect_mirror for b in bsdfs)
        self.any_twosided = any(b.twosided for b in bsdfs)
        rows = bsdfs or [BSDF("diffuse", (0.0, 0.0, 0.0))]   # an empty scene still gathers (masked off)
        self._albedo = Float(np.array([b.reflectance for b in rows]).ravel())
        self._kind = UInt32([KIND_CODE[b.kind] for b in rows])
        self._twosided = UInt32([int(b.twosided) for b in rows])
        self._int_ior = Float([b.int_ior for b in rows])
        self._ext_ior = Float([b.ext_ior for b in rows])
        self.textures = TextureTables(rows) if self.textured else None
        self._plastic = plastic.table(rows) if KIND_CODE["plastic"] in self.kinds else None
        self._eta = Float(np.array([b.eta for b in rows]).ravel())
        self._k = Float(np.array([b.k for b in rows]).ravel())

    def index(self, bsdf: BSDF) -> int:
        return self.bsdfs.index(bsdf)

    def kind(self, material: UInt32, active: Bool) -> UInt32:
        return dr.gather(UInt32, self._kind, material, active)

    def albedo(self, material: UInt32, active: Bool) -> Array3f:
        return dr.gather(Array3f, self._albedo, material, active)

    def albedo_at(self, surf, active: Bool) -> Array3f:
        """A diffuse surface's reflectance at its hit point: its texture's where it has one."""
        rho = self.albedo(surf.material, active)
        if not self.textured:
            return rho
        return self.textures.reflectance(surf.material, surf.uv, rho, active)

    def twosided(self, material: UInt32, active: Bool) -> Bool:
        if not self.any_twosided:
            return Bool(False)
        return dr.gather(UInt32, self._twosided, material, active) != 0

    def conductor_weight(self, material: UInt32, cos_i: Float, active: Bool) -> Array3f:
        """A conductor's reflected weight: its specular reflectance times the Fresnel reflectance at cos_i
        (exactly 1 in a scene whose conductors are all perfect mirrors)."""
        if not self.fresnel_conductors:
            return Array3f(1.0)
        eta = dr.gather(Array3f, self._eta, material, active)
        k = dr.gather(Array3f, self._k, material, active)
        return self.albedo(material, active) * fresnel_conductor(cos_i, eta, k)

    def iors(self, material: UInt32, active: Bool) -> tuple[Float, Float]:
        return dr.gather(Float, self._int_ior, material, active), dr.gather(Float, self._ext_ior, material, active)

    def plastic(self, material: UInt32, active: Bool) -> tuple[Array3f, list[Float]]:
        """A plastic material's specular reflectance and [eta, 1 / eta^2, fdr_int, specular weight,
        nonlinear] (materials.plastic)."""
        return plastic.lookup(self._plastic, material, active)
