"""Mitsuba's `shapegroup` and `instance` as two-level instancing: the meshes of a group are held once, in
the group's own space, in one BVH (the bottom level: tracer.shapes.bvh's tree and walk, unchanged), and a
second BVH (the top level) holds the instances' world-space boxes. A ray that reaches an instance in the
top level is carried into the group's space by the instance's inverse transform and walked through the
group's BVH there (the nested walk keeps its own stack registers); its direction is not renormalised, so
a hit's ray parameter t is the same in both spaces (as pbrt-v4's TransformedPrimitive, Embree's and
Mitsuba's instances). The hit is returned in world space as Mitsuba's `instance` gives it
(instance.cpp's compute_surface_interaction): the point and dp/du, dp/dv by the instance's transform M,
the geometric and shading normals by its inverse transpose (M^-T n, renormalised), texture coordinates
and materials as the group's mesh has them.

Memory grows with the distinct meshes and, per instance, by a top-level leaf row (16 values), its node's
share and its two matrices, not by copies of the triangles. A hit on an instanced triangle is numbered
base + instance * (the group's triangles) + the triangle's index in the group, after the scene's own
primitives: the `skip` of a ray leaving it selects that triangle of that instance alone.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import drjit as dr
import numpy as np

from .. import transform
from ..jit import HOST_FLOAT, NO_PRIM, Array3f, ArrayXf, Bool, Float, UInt32, gather_vec3, opaque_u32, row_table
from .bvh import BVHKernel, layout, leaf_prim, leaf_rows
from .mesh import Mesh, MeshSet
from .planar import inset_point

KINDS = ("obj", "ply", "serialized", "cube")   # the members of a shapegroup that are instanced (meshes)
ROW = 16                                       # values per top-level leaf row
_MATRIX = (0, 1, 2, 4, 5, 6, 7, 8, 9, 10, 11, 12)   # where a leaf row holds the 3 x 4 inverse (value 3: the id)


@dataclass(eq=False)
class ShapeGroup:
    """A shapegroup's meshes in its own space and the transforms of its instances (one 4 x 4 each). Its
    other members (spheres, rectangles, ...) the loader places as shapes of their own per instance."""

    name: str
    meshes: list = field(default_factory=list)
    to_world: list = field(default_factory=list)

    @property
    def transforms(self) -> np.ndarray:
        return np.array(self.to_world, np.float64).reshape(-1, 4, 4)

    @property
    def triangles(self) -> int:
        return sum(len(m.faces) for m in self.meshes)

    def box(self) -> np.ndarray:
        """(2, 3) the box of the group's meshes in its own space."""
        v = np.concatenate([m.vertices for m in self.meshes])
        return np.array([v.min(0), v.max(0)], np.float64)

    def world_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), each (instances, 3): the world box of each instance, the box around its transformed
        group box's corners (holds the transformed meshes, as pbrt-v4's Transform of a Bounds3f)."""
        box = self.box()
        corners = np.array([[box[(c >> k) & 1, k] for k in range(3)] for c in range(8)])
        m = self.transforms
        world = np.einsum("nij,cj->nci", m[:, :3, :3], corners) + m[:, None, :3, 3]
        return world.min(1), world.max(1)

    def copies(self) -> list[Mesh]:
        """Each instance's meshes placed in the world (vertices by M, normals by M^-T): the triangles the
        instances draw, for descriptions of the scene in triangles (validation's scene.json), not the kernels."""
        return [replace(m, vertices=transform.apply_point(t, m.vertices), name=f"{self.name}#{k + 1}/{m.name}",
                        normals=None if m.normals is None else transform.apply_normal(t, m.normals))
                for k, t in enumerate(self.transforms) for m in self.meshes]

    def extent_points(self) -> list[np.ndarray]:
        return [np.concatenate(self.world_boxes())] if self.meshes and self.to_world else []


class InstanceBVH(BVHKernel):
    """The top level: a BVH over the instances' world boxes (each given to the build as the triangle lo, hi,
    hi, as spheres.SphereBVH); a leaf slot's row holds the instance's inverse transform (3 x 4) and its
    index as the primitive id."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, to_local: np.ndarray):
        tables = layout(np.stack([lo, hi, hi], 1))
        self._set_nodes(tables)
        rows = leaf_rows(tables.order, 0, ROW)
        rows[:, list(_MATRIX)] = to_local[tables.order, :3, :].reshape(-1, 12)
        self.prims = Float(rows.ravel())

    def to_local(self, slot: UInt32, o: Array3f, d: Array3f) -> tuple[UInt32, Array3f, Array3f]:
        """The instance in leaf slot `slot` and the ray (o, d) in its group's space: M^-1 o, M^-1 d."""
        x = dr.gather(ArrayXf, self.prims, slot, shape=(ROW, dr.width(slot)))
        r = [[x[_MATRIX[4 * i + j]] for j in range(4)] for i in range(3)]
        o_local = Array3f(*(dr.fma(r[i][0], o.x, dr.fma(r[i][1], o.y, dr.fma(r[i][2], o.z, r[i][3])))
                            for i in range(3)))
        d_local = Array3f(*(dr.fma(r[i][0], d.x, dr.fma(r[i][1], d.y, r[i][2] * d.z)) for i in range(3)))
        return leaf_prim(x), o_local, d_local


class InstanceSet:
    """A shapegroup's meshes (a MeshSet in its own space, always in a BVH: the bottom level) and its
    instances (InstanceBVH: the top level), numbered from primitive `base`."""

    def __init__(self, group: ShapeGroup, base: int):
        self.group, self.base = group, base
        self.meshes = MeshSet(group.meshes, 0, bvh_threshold=0)
        self.triangles, self.instances = self.meshes.count, len(group.to_world)
        self.count = self.triangles * self.instances
        m = group.transforms
        m_inv = np.linalg.inv(m)
        self.top = InstanceBVH(*group.world_boxes(), m_inv)
        # per instance: M's columns (3 x 3 and the translation), then M^-1's rows (3 x 3), 21 values
        table = np.concatenate([m[:, :3, :].transpose(0, 2, 1).reshape(-1, 12),
                                m_inv[:, :3, :3].reshape(-1, 9)], 1)
        self.matrices = Float(table.astype(HOST_FLOAT).ravel())
        self.normal_table = row_table(self.meshes.normals())
        self.frame_table = row_table(self.meshes.frames())
        self.material = None    # per triangle of the group: its material's index (set_materials)

    def set_materials(self, index) -> None:
        """The group's triangles' material indices, `index(bsdf)` of their meshes' BSDFs."""
        material = np.zeros(max(self.triangles, 1), np.uint32)
        for m, lo, n in self.meshes.shape_primitives():
            material[lo:lo + n] = index(m.bsdf)
        self.material = UInt32(material)

    @cached_property
    def _range(self) -> tuple[UInt32, UInt32, UInt32]:
        """base, the group's triangles and the set's primitives, as run-time constants (jit.opaque_u32)."""
        return opaque_u32(self.base), opaque_u32(self.triangles), opaque_u32(self.count)

    # ---- ray queries ------------------------------------------------------------------------------
    def _walk(self, batch: bool, kind: str):
        return (lambda *a, **k: self.top._walk_batch(*a, kind=kind, **k)) if batch else self.top._walk

    def _enter(self, slot: UInt32, o: Array3f, d: Array3f, skip: UInt32):
        """The instance in top-level slot `slot`: its first primitive, the ray in its group's space and
        `skip` as the group's triangle (NO_PRIM where skip is not one of this instance's)."""
        inst, o_local, d_local = self.top.to_local(slot, o, d)
        base, triangles, _ = self._range
        first = base + inst * triangles
        local = skip - first                     # wraps past the triangles where skip lies below `first`
        return first, o_local, d_local, dr.select(local < triangles, local, NO_PRIM)

    def closest_hit(self, o: Array3f, d: Array3f, t_min, t_best: Float, prim: UInt32, b1: Float, b2: Float,
                    skip: UInt32, batch: bool = False):
        """Improves (t_best, prim, b1, b2) with the instances' triangles, as BVHKernel.closest_hit."""
        def visit_instance(slot, ray, t_best, prim, b1, b2):
            o, d, t_min, skip = ray
            first, o_local, d_local, skip_local = self._enter(slot, o, d, skip)
            t_best, local, b1, b2 = self.meshes.bvh.closest_hit(o_local, d_local, t_min, t_best, UInt32(NO_PRIM),
                                                                b1, b2, skip_local)
            return t_best, dr.select(local != NO_PRIM, first + local, prim), b1, b2

        return self._walk(batch, "closest hit")(
            (o, d, Float(t_min), UInt32(skip)), Bool(True), lambda ray, t_best, *_: t_best, visit_instance,
            lambda *_: Bool(False), (Float(t_best), UInt32(prim), Float(b1), Float(b2)))

    def occluded(self, o: Array3f, d: Array3f, dist: Float, skip: UInt32, active: Bool = True,
                 batch: bool = False) -> Bool:
        """Whether an instanced triangle other than `skip` lies on o + t d, 0 < t < dist (instanced meshes
        never emit, so a shadow ray's target is never one of them). Any hit answers: the instances' boxes
        farthest first, as BVHKernel.occluded's rows (a ray leaving an instance's surface enters its box first)."""
        def visit_instance(slot, ray, blocked):
            o, d, dist, skip = ray
            _, o_local, d_local, skip_local = self._enter(slot, o, d, skip)
            return (blocked | self.meshes.bvh.occluded(o_local, d_local, dist, skip_local, UInt32(NO_PRIM),
                                                       ~blocked),)

        return self._walk(batch, "shadow")((o, d, Float(dist), UInt32(skip)), Bool(active), lambda ray, _: ray[2],
                                           visit_instance, lambda blocked: blocked, (Bool(False),), farthest=True)[0]

    # ---- surface data -----------------------------------------------------------------------------
    def local(self, prim: UInt32, valid: Bool) -> tuple[Bool, UInt32, UInt32]:
        """Where prim is one of the set's: (mask, instance, the group's triangle)."""
        base, triangles, count = self._range
        rel = prim - base
        mine = valid & (rel < count)
        inst = dr.select(mine, rel // triangles, 0)
        return mine, inst, dr.select(mine, rel - inst * triangles, 0)

    def _matrix(self, inst: UInt32, mine: Bool) -> list[Array3f]:
        """M's three columns and translation, then M^-1's three rows, of instance `inst`."""
        return [Array3f(*(dr.gather(Float, self.matrices, inst * 21 + 3 * k + c, mine) for c in range(3)))
                for k in range(7)]

    def hit_point(self, prim: UInt32, b1: Float, b2: Float, p: Array3f) -> Array3f:
        """The hit point on an instanced triangle kept inside it (shapes.planar.inset_point) in the group's
        space, then placed by M (p elsewhere)."""
        mine, inst, tri = self.local(prim, Bool(True))
        origin, e1, e2 = (gather_vec3(self.frame_table, tri * 3 + k, mine) for k in range(3))
        q = inset_point(origin, e1, e2, b1, b2, Bool(False))
        c = self._matrix(inst, mine)
        return dr.select(mine, c[0] * q.x + c[1] * q.y + c[2] * q.z + c[3], p)

    def surface(self, prim: UInt32, valid: Bool, p: Array3f, b1: Float, b2: Float, n: Array3f, ns: Array3f,
                material: UInt32, uv, dpdu, dpdv):
        """(n, ns, material, uv, dpdu, dpdv) where prim is an instanced triangle: the group's mesh's, placed
        in the world by the instance (normals by M^-T, tangents by M); the given values elsewhere."""
        mine, inst, tri = self.local(prim, valid)
        c = self._matrix(inst, mine)

        def vector(v):      # M v, for dp/du and dp/dv
            return c[0] * v.x + c[1] * v.y + c[2] * v.z

        def normal(v):      # M^-T v, renormalised: (M^-T v)_j = sum_i (M^-1)_ij v_i
            return dr.normalize(c[4] * v.x + c[5] * v.y + c[6] * v.z)

        n_local = gather_vec3(self.normal_table, tri, mine)
        out_n = dr.select(mine, normal(n_local), n)
        out_ns = dr.select(mine, normal(self.meshes.shading_normal(tri, b1, b2, n_local)), ns)
        out_material = dr.select(mine, dr.gather(UInt32, self.material, tri, mine), material)
        if uv is not None:
            local_uv = self.meshes.uv(tri, mine, p, b1, b2, uv)
            uv = (dr.select(mine, local_uv[0], uv[0]), dr.select(mine, local_uv[1], uv[1]))
        if dpdu is not None:
            dpdu = dr.select(mine, vector(self.meshes.tangent(tri, mine, p, b1, b2, dpdu)), dpdu)
        if dpdv is not None:
            dpdv = dr.select(mine, vector(self.meshes.cotangent(tri, mine, dpdv)), dpdv)
        return out_n, out_ns, out_material, uv, dpdu, dpdv

    # ---- host side ---------------------------------------------------------------------------------
    @cached_property
    def _corners(self) -> np.ndarray:
        """(8 instances, 3) the corners of the instances' world boxes (a hull of their triangles)."""
        lo, hi = self.group.world_boxes()
        return np.concatenate([np.where([(c >> k) & 1 for k in range(3)], hi, lo) for c in range(8)])

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return (self._corners - p0) @ n

    def side_bounds(self, p0: np.ndarray, n: np.ndarray) -> tuple[float, float]:
        side = self.sides(p0, n)
        return side.min(), side.max()

    def describe(self) -> str:
        return (f"shapegroup '{self.group.name}': {self.instances} instance(s) of {self.triangles} triangles "
                f"(a top-level BVH over the instances' boxes, each ray carried into the group's space by the "
                f"instance's inverse transform and walked through the group's BVH)")

