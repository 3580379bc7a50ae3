"""The scene as Dr.Jit code: closest hit, shadow rays, surface data and light sampling.

Kernels are traced from the scene: every primitive's constants are literals in the kernel, and a shape
kind, a smooth mesh or a second light the scene lacks adds no instruction.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from . import intersect
from .bvh import BVHKernel
from .bvh_cache import cached_layout
from .jit import INF, NO_PRIM, Array3f, Bool, Float, UInt32, vec3
from .sampling import square_to_uniform_triangle
from .scene import BSDF, Mesh, Rectangle, Scene

DIFFUSE, CONDUCTOR, DIELECTRIC = 0, 1, 2
BVH_THRESHOLD = 56  # triangles above which a BVH beats the unrolled brute-force tests (measured: brute force wins at 48, the BVH at 64)
_KIND_CODE = {"diffuse": DIFFUSE, "conductor": CONDUCTOR, "dielectric": DIELECTRIC}


@dataclass
class Hit:
    t: Float
    prim: UInt32
    b1: Float
    b2: Float
    p: Array3f        # the hit point, kept inside its rectangle or triangle (intersect.inset_point)

    @property
    def valid(self) -> Bool:
        return self.prim != NO_PRIM


@dataclass
class Surface:
    """A ray's hit point: geometric normal n (the shape's own side), shading normal ns, material index."""

    p: Array3f
    n: Array3f
    ns: Array3f
    material: UInt32
    prim: UInt32
    valid: Bool


@dataclass
class LightSample:
    y: Array3f
    n: Array3f
    radiance: Array3f
    pdf_area: Float   # includes the choice of the light among the scene's lights
    prim: UInt32


class SceneGeometry:
    """`bvh_threshold`: triangles above which they go into a BVH; `material_kinds`: the material codes the
    kernel carries (DIFFUSE, CONDUCTOR, DIELECTRIC; default: those of the scene's materials)."""

    def __init__(self, scene: Scene, bvh_threshold: int = BVH_THRESHOLD, material_kinds: set[int] | None = None):
        self.scene = scene
        self.rects = scene.rectangles
        self.spheres = scene.spheres
        self.tri_vertices = np.concatenate([m.vertices[m.faces] for m in scene.meshes]) if scene.meshes \
            else np.zeros((0, 3, 3))
        self.n_rects, self.n_tris = len(self.rects), len(self.tri_vertices)
        self.sphere_base = self.n_rects + self.n_tris
        self.n_prims = self.sphere_base + len(self.spheres)
        self.materials: list[BSDF] = scene.bsdfs
        self.kinds = {_KIND_CODE[b.kind] for b in self.materials} if material_kinds is None else set(material_kinds)
        self.emitters = scene.emitters
        self.smooth = any(m.normals is not None for m in scene.meshes)
        self.bvh = BVHKernel(self.tri_vertices, self.n_rects, cached_layout(self.tri_vertices)) \
            if self.n_tris > bvh_threshold else None
        self.occluders = self._possible_occluders()
        self._build_tables()

    # ---- host-side tables, gathered by primitive index -------------------------------------------
    def _build_tables(self) -> None:
        n = max(self.n_prims, 1)  # an empty scene still needs a table to gather (masked off) from
        normals, material = np.zeros((n, 3)), np.zeros(n, np.uint32)
        radiance, light_pdf = np.zeros((n, 3)), np.zeros(n)
        corner_normals = np.zeros((max(self.n_tris, 1), 3, 3))
        for i, r in enumerate(self.rects):
            normals[i], material[i] = r.normal, self.materials.index(r.bsdf)
        base = self.n_rects
        for m in self.scene.meshes:
            v = m.vertices[m.faces]
            fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
            sl = slice(base, base + len(m.faces))
            normals[sl], material[sl] = fn, self.materials.index(m.bsdf)
            tri = slice(base - self.n_rects, base - self.n_rects + len(m.faces))
            corner_normals[tri] = m.normals[m.faces] if m.normals is not None else fn[:, None, :]
            base += len(m.faces)
        for i, s in enumerate(self.spheres):
            material[self.sphere_base + i] = self.materials.index(s.bsdf)
        self._prim_ranges = self._emitter_prim_ranges()
        for k, e in enumerate(self.emitters):
            lo, hi = self._prim_ranges[k]
            area = e.area if isinstance(e, Rectangle) else e.triangle_areas.sum()
            radiance[lo:hi] = e.radiance
            light_pdf[lo:hi] = 1.0 / (len(self.emitters) * area) if area > 0 else 0.0
        self.prim_normal = Float(normals.ravel())
        self.prim_material = UInt32(material)
        self.prim_radiance = Float(radiance.ravel())
        self.prim_light_pdf = Float(light_pdf)
        self.corner_normals = Float(corner_normals.ravel())
        tv = self.tri_vertices
        frames = np.concatenate([np.array([[r.center, *r.edges] for r in self.rects]).reshape(-1, 3, 3),
                                 np.stack([tv[:, 0], tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0]], 1)])
        self.prim_frame = Float((frames if len(frames) else np.zeros((1, 3, 3))).ravel())
        materials = self.materials or [BSDF("diffuse", (0.0, 0.0, 0.0))]
        self.mat_albedo = Float(np.array([b.reflectance for b in materials]).ravel())
        self.mat_kind = UInt32([_KIND_CODE[b.kind] for b in materials])
        self.mat_twosided = UInt32([int(b.twosided) for b in materials])
        self.mat_int_ior = Float([b.int_ior for b in materials])
        self.mat_ext_ior = Float([b.ext_ior for b in materials])

    def _emitter_prim_ranges(self) -> list[tuple[int, int]]:
        return [self.prim_range(e) for e in self.emitters]

    def prim_range(self, shape: Rectangle | Mesh) -> tuple[int, int]:
        """The primitive indices [lo, hi) of a rectangle or a mesh of the scene."""
        if isinstance(shape, Rectangle):
            i = self.rects.index(shape)
            return i, i + 1
        base = self.n_rects
        for m in self.scene.meshes:
            if m is shape:
                return base, base + len(m.faces)
            base += len(m.faces)
        raise ValueError("the mesh is not part of this scene")

    def _possible_occluders(self) -> set[int]:
        """Primitives that can block a shadow ray. A shadow ray joins two points of the scene, so a planar
        primitive with the whole scene on one side of its plane (a wall of a convex room) never lies
        strictly between its ends: such primitives are left out of the shadow-ray kernel."""
        points = [self.tri_vertices.reshape(-1, 3)]
        points += [r.center + a * e1 + b * e2 for r in self.rects for e1, e2 in [r.edges]
                   for a in (-1, 1) for b in (-1, 1)]
        points = np.vstack([np.atleast_2d(p) for p in points if np.size(p)]) if any(np.size(p) for p in points) \
            else np.zeros((0, 3))
        eps = 1e-6 * self.scene.extent()
        planes = [(r.center, r.normal) for r in self.rects]
        if self.bvh is None:  # BVH triangles are all tested; only the unrolled ones are worth culling
            planes += [(v[0], n) for v, n in zip(self.tri_vertices, self._face_normals())]
        keep = set(range(self.sphere_base, self.n_prims))
        for i, (p0, n) in enumerate(planes):
            side = (points - p0) @ n
            side = np.concatenate([side] + [[(s.center - p0) @ n - s.radius, (s.center - p0) @ n + s.radius]
                                            for s in self.spheres])
            if not (np.all(side >= -eps) or np.all(side <= eps)):
                keep.add(i)
        return keep

    def _face_normals(self) -> np.ndarray:
        v = self.tri_vertices
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    # ---- ray queries ------------------------------------------------------------------------------
    def closest_hit(self, o: Array3f, d: Array3f, t_min, t_max, skip: UInt32) -> Hit:
        """Nearest hit along o + t d, never on primitive `skip` (the one the ray leaves)."""
        t_best, prim = Float(t_max), UInt32(NO_PRIM)
        b1, b2 = Float(0), Float(0)
        for i, t, u, v in self._candidates(o, d, t_min, skip):
            closer = t < t_best
            t_best = dr.select(closer, t, t_best)
            prim = dr.select(closer, i, prim)
            if u is not None:
                b1, b2 = dr.select(closer, u, b1), dr.select(closer, v, b2)
        if self.bvh is not None:
            t_best, prim, b1, b2 = self.bvh.closest_hit(o, d, t_min, t_best, prim, b1, b2, skip)
        return Hit(t_best, prim, b1, b2, self._hit_point(o, d, t_best, prim, b1, b2))

    def _hit_point(self, o, d, t, prim, b1, b2) -> Array3f:
        """o + t d, or on a rectangle or triangle the point of its local coordinates kept inside it
        (intersect.inset_point), from the primitive's frame (origin, e1, e2)."""
        p = dr.fma(d, t, o)
        planar = prim < self.sphere_base
        if not (self.n_rects or self.n_tris):
            return p
        origin, e1, e2 = (dr.gather(Array3f, self.prim_frame, prim * 3 + k, planar) for k in range(3))
        inset = intersect.inset_point(origin, e1, e2, b1, b2, prim < self.n_rects)
        return dr.select(planar, inset, p)

    def occluded(self, o: Array3f, d: Array3f, dist: Float, skip: UInt32, target: UInt32,
                 active: Bool = True) -> Bool:
        """Whether anything but `skip` and `target` lies on the segment o + t d, 0 < t < dist. Lanes that
        are not active may answer either way; only the BVH skips work for them."""
        blocked = Bool(False)
        for i, t, _, _ in self._candidates(o, d, 0.0, skip, target, self.occluders):
            blocked |= t < dist
        if self.bvh is not None:
            blocked |= self.bvh.occluded(o, d, dist, skip, target, active & ~blocked)
        return blocked

    def _candidates(self, o, d, t_min, skip, target=None, only=None):
        """Per primitive (of `only`, if given): (index, t, b1, b2) of its hit, t = inf on a miss or for an
        excluded primitive; (b1, b2): a rectangle's local coordinates, a triangle's barycentrics."""
        for i, r in enumerate(self.rects):
            if only is not None and i not in only:
                continue
            du, dv = r.dual_edges
            t, x, y = intersect.ray_rectangle(o, d, vec3(r.center), vec3(du), vec3(dv), vec3(r.normal), t_min, INF)
            yield i, self._exclude(t, i, skip, target), x, y
        for j, v in enumerate(self.tri_vertices if self.bvh is None else ()):
            if only is not None and self.n_rects + j not in only:
                continue
            t, b1, b2 = intersect.ray_triangle(o, d, vec3(v[0]), vec3(v[1] - v[0]), vec3(v[2] - v[0]), t_min, INF)
            yield self.n_rects + j, self._exclude(t, self.n_rects + j, skip, target), b1, b2
        for k, s in enumerate(self.spheres):
            i = self.sphere_base + k
            t = intersect.ray_sphere(o, d, vec3(s.center), s.radius, t_min, INF, skip == i)
            yield i, (t if target is None else dr.select(target == i, INF, t)), None, None

    @staticmethod
    def _exclude(t, i, skip, target):
        out = skip == i
        if target is not None:
            out |= target == i
        return dr.select(out, INF, t)

    # ---- surface data -----------------------------------------------------------------------------
    def surface(self, hit: Hit) -> Surface:
        valid = hit.valid
        prim = dr.select(valid, hit.prim, 0)
        p = hit.p
        n = dr.gather(Array3f, self.prim_normal, prim, valid)
        if self.spheres:
            is_sphere = prim >= self.sphere_base
            center, radius = self._sphere_select(prim)
            n = dr.select(is_sphere, dr.normalize(p - center), n)  # unit even where p is off the surface
        ns = n
        if self.smooth:
            tri = prim - self.n_rects
            is_tri = (prim >= self.n_rects) & (tri < self.n_tris)
            b0 = 1.0 - hit.b1 - hit.b2
            interp = (dr.gather(Array3f, self.corner_normals, tri * 3, is_tri) * b0
                      + dr.gather(Array3f, self.corner_normals, tri * 3 + 1, is_tri) * hit.b1
                      + dr.gather(Array3f, self.corner_normals, tri * 3 + 2, is_tri) * hit.b2)
            ns = dr.select(is_tri, dr.normalize(interp), n)
        material = dr.gather(UInt32, self.prim_material, prim, valid)
        return Surface(p, n, ns, material, dr.select(valid, hit.prim, NO_PRIM), valid)

    def _sphere_select(self, prim: UInt32) -> tuple[Array3f, Float]:
        center, radius = vec3(self.spheres[0].center), Float(self.spheres[0].radius)
        for k, s in enumerate(self.spheres[1:], 1):
            this = prim == self.sphere_base + k
            center = dr.select(this, vec3(s.center), center)
            radius = dr.select(this, s.radius, radius)
        return center, radius

    def albedo(self, material: UInt32, active: Bool) -> Array3f:
        return dr.gather(Array3f, self.mat_albedo, material, active)

    def kind(self, material: UInt32, active: Bool) -> UInt32:
        return dr.gather(UInt32, self.mat_kind, material, active)

    def twosided(self, material: UInt32, active: Bool) -> Bool:
        if not any(b.twosided for b in self.materials):
            return Bool(False)
        return dr.gather(UInt32, self.mat_twosided, material, active) != 0

    def iors(self, material: UInt32, active: Bool) -> tuple[Float, Float]:
        return (dr.gather(Float, self.mat_int_ior, material, active),
                dr.gather(Float, self.mat_ext_ior, material, active))

    # ---- lights -----------------------------------------------------------------------------------
    def emitted(self, surf: Surface, wo: Array3f) -> Array3f:
        """Radiance an area light emits towards wo: only on the side its normal faces."""
        if not self.emitters:
            return Array3f(0.0)
        le = dr.gather(Array3f, self.prim_radiance, surf.prim, surf.valid)
        return dr.select(surf.valid & (dr.dot(surf.ns, wo) > 0), le, Array3f(0.0))

    def light_pdf_area(self, surf: Surface) -> Float:
        """Area density with which sample_light picks this point (0 off the lights)."""
        return dr.gather(Float, self.prim_light_pdf, surf.prim, surf.valid)

    def sample_light(self, u_select: Float, u1: Float, u2: Float) -> LightSample:
        """A light chosen uniformly, then a point uniform in area on it."""
        n_em = len(self.emitters)
        index = dr.minimum(UInt32(u_select * n_em), n_em - 1)
        out = None
        for k, e in enumerate(self.emitters):
            s = self._sample_rectangle(e, k, u1, u2) if isinstance(e, Rectangle) else self._sample_mesh(e, k, u1, u2)
            out = s if out is None else _select_sample(index == k, s, out)
        return out

    def _sample_rectangle(self, r: Rectangle, k: int, u1: Float, u2: Float) -> LightSample:
        e1, e2 = r.edges
        y = vec3(r.center) + vec3(e1) * (2.0 * u1 - 1.0) + vec3(e2) * (2.0 * u2 - 1.0)
        pdf = 1.0 / (len(self.emitters) * r.area)
        return LightSample(y, vec3(r.normal), vec3(r.radiance), Float(pdf), UInt32(self._prim_ranges[k][0]))

    def _sample_mesh(self, m: Mesh, k: int, u1: Float, u2: Float) -> LightSample:
        areas = m.triangle_areas
        cdf = Float(np.cumsum(areas) / areas.sum())
        # reuse u1: pick the triangle, then rescale the remainder of u1 to [0, 1)
        tri = dr.binary_search(0, len(areas) - 1, lambda i: dr.gather(Float, cdf, i) <= u1)
        lo = dr.select(tri > 0, dr.gather(Float, cdf, tri - 1, tri > 0), 0.0)
        hi = dr.gather(Float, cdf, tri)
        u1 = dr.clip((u1 - lo) / (hi - lo), 0.0, 1.0 - 2.0 ** -24)
        b1, b2 = square_to_uniform_triangle(u1, u2)
        prim = UInt32(self._prim_ranges[k][0]) + tri
        corners = Float(m.vertices[m.faces].ravel())
        v = [dr.gather(Array3f, corners, tri * 3 + c) for c in range(3)]
        y = v[0] * (1.0 - b1 - b2) + v[1] * b1 + v[2] * b2
        n = dr.gather(Array3f, self.prim_normal, prim)
        if m.normals is not None:
            cn = [dr.gather(Array3f, self.corner_normals, (prim - self.n_rects) * 3 + c) for c in range(3)]
            n = dr.normalize(cn[0] * (1.0 - b1 - b2) + cn[1] * b1 + cn[2] * b2)
        pdf = 1.0 / (len(self.emitters) * areas.sum())
        return LightSample(y, n, vec3(m.radiance), Float(pdf), prim)

    def describe(self) -> list[str]:
        """What the traced kernel contains, for `tracer info`."""
        tris = "in a BVH" if self.bvh is not None else "brute force"
        lines = [f"intersection: {self.n_rects} rectangles (ray-plane, eq. 2-4), {self.n_tris} triangles "
                 f"(Moeller-Trumbore, {tris}), {len(self.spheres)} spheres (quadratic)"]
        lines.append(f"shading normals: {'interpolated on smooth meshes' if self.smooth else 'geometric only'}")
        lines.append(f"materials: {', '.join(sorted({b.kind for b in self.materials}))}")
        lines.append(f"light sampling: {len(self.emitters)} area light(s)")
        return lines


def _select_sample(mask: Bool, a: LightSample, b: LightSample) -> LightSample:
    return LightSample(dr.select(mask, a.y, b.y), dr.select(mask, a.n, b.n), dr.select(mask, a.radiance, b.radiance),
                       dr.select(mask, a.pdf_area, b.pdf_area), dr.select(mask, a.prim, b.prim))
