"""The scene's materials as the kernels see them: per-material columns every kind shares (kind, two-sidedness,
reflectance and its texture) and one table per kind (its module's `table`), gathered by material index. A
table a scene's materials do not need is not built, and its code is not traced. A lane gathers a row of a kind's
table, and a reflectance, in one packet load (jit.row_table)."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32, gather_row, gather_vec3, packet_size, row_table
from .bsdf import BSDF
from .dispatch import KIND_CODE, KINDS
from .textures import MeshAttribute, TextureTables


class MaterialTables:
    """`kinds`: the material codes the kernel carries (materials.DIFFUSE, CONDUCTOR, ...; default: those of
    `bsdfs`)."""

    def __init__(self, bsdfs: list[BSDF], kinds: set[int] | None = None, meshes=None):
        backs = [b.back for b in bsdfs if b.back is not None]
        seconds = [b.blend[1] for b in bsdfs if b.blend is not None]
        backs += [b.back for b in seconds if b.back is not None]
        self.bsdfs = list(bsdfs)
        for b in backs + seconds:        # the materials only a two-sided material's back or a blend refers to
            if b not in self.bsdfs:
                self.bsdfs.append(b)
        bsdfs = self.bsdfs
        self.kinds = {KIND_CODE[b.kind] for b in bsdfs} if kinds is None else set(kinds)
        self.any_normalmap = any(b.normalmap is not None for b in bsdfs)
        self.any_bumpmap = any(b.texture_of("bumpmap") is not None for b in bsdfs)
        self._slots, textures = _slots(bsdfs)
        self.textured = bool(self._slots)
        self.any_twosided = any(b.twosided for b in bsdfs)
        # whether a material is not invariant under rotation about the normal (anisotropic roughness, a normal
        # map in tangent space): then the shading frame follows the surface's dp/du as Mitsuba's; elsewhere any
        # frame about the normal gives the same image
        self.oriented = any(not b.isotropic or b.normalmap is not None for b in bsdfs) or self.any_bumpmap
        rows = bsdfs or [BSDF("diffuse", (0.0, 0.0, 0.0))]   # an empty scene still gathers (masked off)
        self._reflectance = row_table(np.array([b.reflectance for b in rows], float))
        self._kind = UInt32([KIND_CODE[b.kind] for b in rows])
        self._twosided = UInt32([int(b.twosided) for b in rows])
        self.any_back = bool(backs)
        self.any_mask = any(b.masked for b in rows)
        self.any_blend = bool(seconds)
        self._blend_weight = Float([b.blend[0] if b.blend is not None else 0.0 for b in rows])
        self._blend_second = UInt32([bsdfs.index(b.blend[1]) if b.blend is not None else i
                                     for i, b in enumerate(rows)])
        self._opacity = Float([b.opacity for b in rows])
        self._back = UInt32([bsdfs.index(b.back) if b.back is not None else i for i, b in enumerate(rows)])
        # the mesh attributes the textures read (`meshes`: the scene's shapes.mesh.MeshSet)
        names = {t.name for t in textures if isinstance(t, MeshAttribute)}
        self.attributed = bool(names)
        self.textures = TextureTables(textures, meshes.attribute_table(names) if names else None) \
            if self.textured else None
        if self.any_normalmap or self.any_bumpmap:
            self._normalmap_flags = Float(np.array([[b.normalmap_flip, b.normalmap_shadowing] for b in rows],
                                                   float).ravel())
            self._bump_scale = Float([b.bump_scale for b in rows])
        self._tables: dict[str, tuple[Float, int, int]] = {}
        for code in sorted(self.kinds):
            module = KINDS[code]
            table = module.table(rows) if hasattr(module, "table") else None
            if table is not None:
                fields = table.shape[1]
                self._tables[module.NAME] = (row_table(table), packet_size(fields), fields)

    def index(self, bsdf: BSDF) -> int:
        return self.bsdfs.index(bsdf)

    def kind(self, material: UInt32, active: Bool) -> UInt32:
        return dr.gather(UInt32, self._kind, material, active)

    def reflectance(self, surf, active: Bool) -> Array3f:
        """A material's reflectance at a surface point: its texture's where it has one."""
        return self.textured_value("reflectance", surf, gather_vec3(self._reflectance, surf.material, active), active)

    def has_texture(self, slot: str) -> bool:
        """Whether some material of the scene gives parameter `slot` by a texture."""
        return slot in self._slots

    def texture_index(self, slot: str, surf, active: Bool) -> UInt32:
        """Each lane's material's texture for `slot` (0: none)."""
        return dr.gather(UInt32, self._slots[slot], surf.material, active)

    def textured_value(self, slot: str, surf, value, active: Bool):
        """Parameter `slot` at the surface point: its texture's value where the material has one (a colour
        where `value` is an Array3f, else a float, Mitsuba's eval_1), `value` elsewhere."""
        if slot not in self._slots:
            return value
        index = self.texture_index(slot, surf, active)
        has = index > 0
        if isinstance(value, Array3f):
            return dr.select(has, self.textures.eval(index, surf.uv, active & has, hit=self._hit(surf)), value)
        return dr.select(has, self.textures.eval_1(index, surf.uv, active & has, self._hit(surf)), value)

    def _hit(self, surf) -> tuple[UInt32, Float, Float] | None:
        """The surface point's primitive and barycentric coordinates, for mesh attributes."""
        return (surf.prim, *surf.bary) if self.attributed else None

    def normalmap(self, surf, active: Bool) -> tuple[Array3f, Bool, Bool, Bool]:
        """A normal map's tilted normal 2 c - 1 at the surface point (0, 0, 1 for materials without one), and
        per lane whether the material has one and its flip_invalid_normals and use_shadowing_function."""
        m, has = Array3f(0.0, 0.0, 1.0), Bool(False)
        if self.any_normalmap:
            index = self.texture_index("normalmap", surf, active)
            has = index > 0
            m = dr.select(has, self.textures.eval(index, surf.uv, active & has, hit=self._hit(surf)),
                          Array3f(0.5, 0.5, 1.0)) * 2.0 - 1.0
        flip = dr.gather(Float, self._normalmap_flags, surf.material * 2, active) > 0
        shadow = dr.gather(Float, self._normalmap_flags, surf.material * 2 + 1, active) > 0
        return m, has, flip, shadow

    def bump_gradient(self, surf, active: Bool) -> tuple[Array2f, Bool]:
        """A bump map's height gradient (scale included) in (u, v), and per lane whether the material has one."""
        index = self.texture_index("bumpmap", surf, active)
        has = index > 0
        scale = dr.gather(Float, self._bump_scale, surf.material, active)
        return self.textures.grad_1(index, surf.uv, active & has) * scale, has

    def twosided(self, material: UInt32, active: Bool) -> Bool:
        if not self.any_twosided:
            return Bool(False)
        return dr.gather(UInt32, self._twosided, material, active) != 0

    def back(self, material: UInt32, active: Bool) -> UInt32:
        """The material seen from below: a two-sided material's back (the material itself where it has none)."""
        if not self.any_back:
            return material
        return dr.gather(UInt32, self._back, material, active)

    def opacity(self, surf, active: Bool) -> Float:
        """A `mask`ed material's opacity, clipped to [0, 1] as Mitsuba's (1 elsewhere)."""
        value = self.textured_value("opacity", surf, dr.gather(Float, self._opacity, surf.material, active), active)
        return dr.clip(value, 0.0, 1.0)

    def blend(self, surf, active: Bool) -> tuple[Float, UInt32]:
        """A `blendbsdf`'s weight w, clipped to [0, 1] as Mitsuba's, and its second material (0 and the
        material itself elsewhere)."""
        w = self.textured_value("weight", surf, dr.gather(Float, self._blend_weight, surf.material, active), active)
        return dr.clip(w, 0.0, 1.0), dr.gather(UInt32, self._blend_second, surf.material, active)

    def has_table(self, kind: str) -> bool:
        return kind in self._tables

    def table(self, kind: str) -> tuple[Float, int]:
        """The kind's table, flat, and its row stride (for fields gathered at a per-lane index)."""
        values, stride, _ = self._tables[kind]
        return values, stride

    def row(self, kind: str, material: UInt32, active: Bool, count: int | None = None) -> list[Float]:
        """Each field of the material's row in the kind's table (its module's `table`); the first `count`."""
        values, stride, fields = self._tables[kind]
        return gather_row(values, stride, material, active, fields if count is None else count)


def _slots(bsdfs: list[BSDF]) -> tuple[dict[str, UInt32], list]:
    """Per textured slot, each material's texture (1 + its index in the list of the scene's distinct
    textures; 0: none), and that list."""
    textures: list = []
    columns: dict[str, list[int]] = {}
    for i, b in enumerate(bsdfs):
        for slot, t in b.slot_textures():
            if not any(t is u for u in textures):
                textures.append(t)
            columns.setdefault(slot, [0] * len(bsdfs))[i] = 1 + next(k for k, u in enumerate(textures) if u is t)
    return {slot: UInt32(column) for slot, column in columns.items()}, textures
