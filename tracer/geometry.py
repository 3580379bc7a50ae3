"""The scene as Dr.Jit code: closest hit, shadow rays, surface data and light sampling.

Kernels are traced from the scene: every primitive's constants are literals in the kernel, and a shape
kind, a smooth mesh or a second light the scene lacks adds no instruction.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from . import intersect
from .bsdf import fresnel_conductor, fresnel_diffuse_reflectance
from .bvh import BVHKernel
from .bvh_cache import cached_layout
from .jit import INF, NO_PRIM, Array3f, Bool, Float, UInt32, vec3
from .sampling import square_to_uniform_disk_concentric, square_to_uniform_sphere, square_to_uniform_triangle
from .scene import BSDF, Bitmap, Checkerboard, Mesh, Rectangle, Scene, Sphere

DIFFUSE, CONDUCTOR, DIELECTRIC, PLASTIC = 0, 1, 2, 3
POINT_LIGHT = NO_PRIM - 1   # the `prim` of a light sample on a point light (NO_PRIM: on the environment)
DIRECTIONAL_LIGHT = NO_PRIM - 2
TEXTURE_FIELDS = 18         # per material: kind, two colours, to_uv's two rows, a bitmap's offset, size and modes
BVH_THRESHOLD = 56  # triangles above which a BVH beats the unrolled brute-force tests (measured: brute force wins at 48, the BVH at 64)
_KIND_CODE = {"diffuse": DIFFUSE, "conductor": CONDUCTOR, "dielectric": DIELECTRIC, "plastic": PLASTIC}


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
    uv: tuple[Float, Float] | None = None   # texture coordinates, in scenes with textures only


@dataclass
class LightSample:
    y: Array3f
    n: Array3f
    radiance: Array3f
    pdf_area: Float   # includes the choice of the light among the scene's lights
    prim: UInt32
    cone: tuple | None = None   # a spot light's (cos cutoff, cos beam width, cutoff, 1 / transition width)


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
        self.cylinders = scene.cylinders
        self.cylinder_base = self.sphere_base + len(self.spheres)
        self.n_prims = self.cylinder_base + len(self.cylinders)
        self.materials: list[BSDF] = scene.bsdfs
        self.kinds = {_KIND_CODE[b.kind] for b in self.materials} if material_kinds is None else set(material_kinds)
        self.textured = any(b.texture is not None for b in self.materials)
        # conductors other than perfect mirrors need their Fresnel term; without them the kernel has none
        self.fresnel_conductors = any(b.kind == "conductor" and not b.perfect_mirror for b in self.materials)
        self.emitters = scene.emitters
        self.environment = scene.environment
        self.envmap = _EnvmapKernel(scene.envmap) if scene.envmap is not None else None
        self.has_environment = self.environment is not None or self.envmap is not None
        self.points = scene.point_lights
        self.directionals = scene.directional_lights
        self.spots = any(light.spot is not None for light in self.points)
        # lights a shadow ray may be sent to, chosen uniformly: the area lights, point lights, the environment
        self.n_lights = len(self.emitters) + len(self.points) + len(self.directionals) + self.has_environment
        self.has_infinite_lights = self.has_environment or bool(self.directionals)   # shadow rays leave the scene
        self.has_lights = self.n_lights > 0
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
        for i, c in enumerate(self.cylinders):
            material[self.cylinder_base + i] = self.materials.index(c.bsdf)
        self._prim_ranges = self._emitter_prim_ranges()
        for k, e in enumerate(self.emitters):
            lo, hi = self._prim_ranges[k]
            area = e.triangle_areas.sum() if isinstance(e, Mesh) else e.area
            radiance[lo:hi] = e.radiance
            light_pdf[lo:hi] = 1.0 / (self.n_lights * area) if area > 0 else 0.0
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
        if self.textured:
            self._build_texture_tables(materials)
        if PLASTIC in self.kinds:
            self._build_plastic_tables(materials)
        self.mat_eta = Float(np.array([b.eta for b in materials]).ravel())
        self.mat_k = Float(np.array([b.k for b in materials]).ravel())

    def _build_plastic_tables(self, materials: list[BSDF]) -> None:
        """Per material, for smooth plastic: specular reflectance, then eta, 1 / eta^2, the interior's
        diffuse Fresnel reflectance, the specular sampling weight (Mitsuba's: the specular share of the two
        mean reflectances) and whether the internal scattering is nonlinear."""
        table = np.zeros((len(materials), 3 + 5))
        for i, b in enumerate(materials):
            if b.kind == "plastic":
                eta = b.int_ior / b.ext_ior
                s_mean, d_mean = np.mean(b.specular_reflectance), np.mean(b.reflectance)
                table[i] = [*b.specular_reflectance, eta, 1.0 / (eta * eta), fresnel_diffuse_reflectance(1.0 / eta),
                            s_mean / (d_mean + s_mean), float(b.nonlinear)]
        self.mat_plastic = Float(table.ravel())

    def plastic(self, material: UInt32, active: Bool) -> tuple[Array3f, list[Float]]:
        """A plastic material's specular reflectance and [eta, 1 / eta^2, fdr_int, specular weight,
        nonlinear] (see _build_plastic_tables)."""
        spec = Array3f(*(dr.gather(Float, self.mat_plastic, material * 8 + k, active) for k in range(3)))
        return spec, [dr.gather(Float, self.mat_plastic, material * 8 + 3 + k, active) for k in range(5)]

    def _build_texture_tables(self, materials: list[BSDF]) -> None:
        """Per triangle corner texture coordinates (a triangle's own (0,0), (1,0), (0,1) where its mesh has
        none, so that interpolation gives (b1, b2) as Mitsuba), and per material its checkerboard."""
        uvs = np.zeros((max(self.n_tris, 1), 3, 2))
        base = 0
        for m in self.scene.meshes:
            n = len(m.faces)
            uvs[base:base + n] = m.uvs[m.faces] if m.uvs is not None else [[0, 0], [1, 0], [0, 1]]
            base += n
        self.corner_uvs = Float(uvs.ravel())
        tex = np.zeros((len(materials), TEXTURE_FIELDS))
        texels = [np.zeros(3, np.float32)]
        offset = 1
        for i, b in enumerate(materials):
            t = b.texture
            if isinstance(t, Checkerboard):
                tex[i, :13] = [1.0, *t.color0, *t.color1, *np.asarray(t.to_uv)[:2].ravel()]
            elif isinstance(t, Bitmap):
                h, w = t.image.shape[:2]
                tex[i] = [2.0, 0, 0, 0, 0, 0, 0, *np.asarray(t.to_uv)[:2].ravel(), offset, w, h, t.bilinear, t.repeat]
                texels.append(t.image.ravel())
                offset += h * w
        self.mat_texture = Float(tex.ravel())
        self.texels = Float(np.concatenate(texels))
        self.bitmaps = any(isinstance(b.texture, Bitmap) for b in materials)

    def _emitter_prim_ranges(self) -> list[tuple[int, int]]:
        return [self.prim_range(e) for e in self.emitters]

    def prim_range(self, shape: Rectangle | Mesh | Sphere) -> tuple[int, int]:
        """The primitive indices [lo, hi) of a rectangle, a mesh or a sphere of the scene."""
        if isinstance(shape, Rectangle):
            i = self.rects.index(shape)
            return i, i + 1
        if isinstance(shape, Sphere):
            i = self.sphere_base + self.spheres.index(shape)
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
        strictly between its ends: such primitives are left out of the shadow-ray kernel. Shadow rays to an
        environment leave the scene, so with one (or a directional light) every primitive may block."""
        if self.has_infinite_lights:
            return set(range(self.n_prims))
        points = [self.tri_vertices.reshape(-1, 3)]
        points += [r.center + a * e1 + b * e2 for r in self.rects for e1, e2 in [r.edges]
                   for a in (-1, 1) for b in (-1, 1)]
        points += [light.position for light in self.points]     # shadow rays end there too
        points += [c.corners for c in self.cylinders]
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
            if r.disk:
                t = dr.select(dr.fma(x, x, y * y) > 1.0, INF, t)
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
        for k, c in enumerate(self.cylinders):
            i = self.cylinder_base + k
            t = intersect.ray_cylinder(o, d, np.linalg.inv(c.to_world), t_min, INF, skip == i)
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
            is_sphere = (prim >= self.sphere_base) & (prim < self.cylinder_base)
            center, radius = self._sphere_select(prim)
            n = dr.select(is_sphere, dr.normalize(p - center), n)  # unit even where p is off the surface
        for k, c in enumerate(self.cylinders):
            n = dr.select(prim == self.cylinder_base + k, self._cylinder_normal(c, p), n)
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
        uv = self._uv(hit, prim, valid) if self.textured else None
        return Surface(p, n, ns, material, dr.select(valid, hit.prim, NO_PRIM), valid, uv)

    def _uv(self, hit: Hit, prim: UInt32, valid: Bool) -> tuple[Float, Float]:
        """Texture coordinates: a rectangle's local coordinates mapped to [0, 1]^2, a triangle's interpolated
        from its corners (spheres carry no textures)."""
        u, v = dr.fma(hit.b1, 0.5, 0.5), dr.fma(hit.b2, 0.5, 0.5)
        if self.n_tris:
            tri = prim - self.n_rects
            is_tri = valid & (prim >= self.n_rects) & (tri < self.n_tris)
            b0 = 1.0 - hit.b1 - hit.b2
            c = [dr.gather(Float, self.corner_uvs, tri * 6 + k, is_tri) for k in range(6)]
            u = dr.select(is_tri, c[0] * b0 + c[2] * hit.b1 + c[4] * hit.b2, u)
            v = dr.select(is_tri, c[1] * b0 + c[3] * hit.b1 + c[5] * hit.b2, v)
        return u, v

    @staticmethod
    def _cylinder_normal(c, p: Array3f) -> Array3f:
        """The tube's normal at p: the local radial direction (x, y, 0) taken to world space as a normal,
        outward unless the cylinder is flipped."""
        m = np.linalg.inv(c.to_world)
        x, y = (p.x * float(m[r, 0]) + p.y * float(m[r, 1]) + p.z * float(m[r, 2]) + float(m[r, 3]) for r in range(2))
        sign = -1.0 if c.flipped else 1.0
        return dr.normalize(Array3f(*((x * float(m[0, k]) + y * float(m[1, k])) * sign for k in range(3))))

    def _sphere_select(self, prim: UInt32) -> tuple[Array3f, Float]:
        center, radius = vec3(self.spheres[0].center), Float(self.spheres[0].radius)
        for k, s in enumerate(self.spheres[1:], 1):
            this = prim == self.sphere_base + k
            center = dr.select(this, vec3(s.center), center)
            radius = dr.select(this, s.radius, radius)
        return center, radius

    def albedo(self, material: UInt32, active: Bool) -> Array3f:
        return dr.gather(Array3f, self.mat_albedo, material, active)

    def albedo_at(self, surf: Surface, active: Bool) -> Array3f:
        """A diffuse surface's reflectance at its hit point: its texture's where it has one."""
        rho = self.albedo(surf.material, active)
        if not self.textured:
            return rho
        t = [dr.gather(Float, self.mat_texture, surf.material * TEXTURE_FIELDS + k, active)
             for k in range(TEXTURE_FIELDS)]
        u, v = surf.uv
        tu = dr.fma(t[7], u, dr.fma(t[8], v, t[9]))
        tv = dr.fma(t[10], u, dr.fma(t[11], v, t[12]))
        first = (tu - dr.floor(tu) > 0.5) == (tv - dr.floor(tv) > 0.5)
        texture = dr.select(first, Array3f(t[1], t[2], t[3]), Array3f(t[4], t[5], t[6]))
        if self.bitmaps:
            texture = dr.select(t[0] > 1.5, self._bitmap(t, tu, tv, active & (t[0] > 1.5)), texture)
        return dr.select(t[0] > 0, texture, rho)

    def _bitmap(self, t: list[Float], u: Float, v: Float, active: Bool) -> Array3f:
        """A bitmap texture's texels around (u, v), filtered and wrapped (tracer/bitmap.py)."""
        offset, w, h, bilinear, repeat = t[13], t[14], t[15], t[16] > 0, t[17] > 0

        def wrap(i: Float, n: Float) -> UInt32:
            return UInt32(dr.select(repeat, i - n * dr.floor(i / n), dr.clip(i, 0.0, n - 1.0)))

        def texel(i: Float, j: Float) -> Array3f:
            index = UInt32(offset) + wrap(j, h) * UInt32(w) + wrap(i, w)
            return dr.gather(Array3f, self.texels, index, active)

        x = dr.select(bilinear, dr.fma(u, w, -0.5), u * w)
        y = dr.select(bilinear, dr.fma(v, h, -0.5), v * h)
        x0, y0 = dr.floor(x), dr.floor(y)
        wx, wy = dr.select(bilinear, x - x0, 0.0), dr.select(bilinear, y - y0, 0.0)
        top = texel(x0, y0) * (1.0 - wx) + texel(x0 + 1.0, y0) * wx
        bottom = texel(x0, y0 + 1.0) * (1.0 - wx) + texel(x0 + 1.0, y0 + 1.0) * wx
        return top * (1.0 - wy) + bottom * wy

    def kind(self, material: UInt32, active: Bool) -> UInt32:
        return dr.gather(UInt32, self.mat_kind, material, active)

    def twosided(self, material: UInt32, active: Bool) -> Bool:
        if not any(b.twosided for b in self.materials):
            return Bool(False)
        return dr.gather(UInt32, self.mat_twosided, material, active) != 0

    def conductor_weight(self, material: UInt32, cos_i: Float, active: Bool) -> Array3f:
        """A conductor's reflected weight: its specular reflectance times the Fresnel reflectance at cos_i
        (exactly 1 in a scene whose conductors are all perfect mirrors)."""
        if not self.fresnel_conductors:
            return Array3f(1.0)
        eta = dr.gather(Array3f, self.mat_eta, material, active)
        k = dr.gather(Array3f, self.mat_k, material, active)
        return self.albedo(material, active) * fresnel_conductor(cos_i, eta, k)

    def iors(self, material: UInt32, active: Bool) -> tuple[Float, Float]:
        return (dr.gather(Float, self.mat_int_ior, material, active),
                dr.gather(Float, self.mat_ext_ior, material, active))

    # ---- lights -----------------------------------------------------------------------------------
    def emitted(self, surf: Surface, wi: Array3f) -> Array3f:
        """Radiance an area light emits along wi (pointing away from the surface, back along the ray that
        found it): only on the side its normal faces; on a ray that hits nothing, the environment's."""
        if not self.has_lights:
            return Array3f(0.0)
        le = Array3f(0.0)
        if self.emitters:
            le = dr.gather(Array3f, self.prim_radiance, surf.prim, surf.valid)
            le = dr.select(surf.valid & (dr.dot(surf.ns, wi) > 0), le, Array3f(0.0))
        if self.has_environment:
            le = dr.select(surf.valid, le, self.environment_radiance(-wi))
        return le

    def environment_radiance(self, d: Array3f) -> Array3f:
        """Radiance arriving from the environment along -d (d: the direction leaving the scene)."""
        if self.envmap is not None:
            return self.envmap.radiance(d)
        return vec3(self.environment)

    def light_pdf_area(self, surf: Surface) -> Float:
        """Area density with which sample_light picks this point (0 off the lights)."""
        return dr.gather(Float, self.prim_light_pdf, surf.prim, surf.valid)

    def environment_pdf(self, d: Array3f):
        """Solid-angle density with which sample_light picks direction d to the environment."""
        if self.envmap is not None:
            return self.envmap.pdf(d) * (1.0 / self.n_lights)
        return 1.0 / (self.n_lights * 4.0 * np.pi)

    def sample_light(self, u_select: Float, u1: Float, u2: Float) -> LightSample:
        """A light chosen uniformly, then a point uniform in area on it; for the environment, a direction
        uniform on the sphere, returned as y (with n = -y, prim = NO_PRIM and pdf_area its solid-angle
        density); for a point light its position (prim = POINT_LIGHT, pdf_area the choice's probability)."""
        n_lights = self.n_lights
        index = dr.minimum(UInt32(u_select * n_lights), n_lights - 1)
        out = None
        for k, e in enumerate(self.emitters):
            if isinstance(e, Rectangle):
                s = self._sample_rectangle(e, k, u1, u2)
            elif isinstance(e, Sphere):
                s = self._sample_sphere(e, k, u1, u2)
            else:
                s = self._sample_mesh(e, k, u1, u2)
            out = s if out is None else _select_sample(index == k, s, out)
        for k, light in enumerate(self.points):
            axis, *cone = light.cone()     # the axis rides in n
            s = LightSample(vec3(light.position), vec3(axis), vec3(light.intensity), Float(1.0 / n_lights),
                            UInt32(POINT_LIGHT), tuple(Float(x) for x in cone) if self.spots else None)
            out = s if out is None else _select_sample(index == len(self.emitters) + k, s, out)
        for k, light in enumerate(self.directionals):   # y: the direction towards it; n: the one it shines along
            s = LightSample(vec3(-light.direction), vec3(light.direction), vec3(light.irradiance),
                            Float(1.0 / n_lights), UInt32(DIRECTIONAL_LIGHT))
            out = s if out is None else _select_sample(index == len(self.emitters) + len(self.points) + k, s, out)
        if self.has_environment:
            d = self.envmap.sample(u1, u2) if self.envmap is not None else square_to_uniform_sphere(u1, u2)
            s = LightSample(d, -d, self.environment_radiance(d), Float(self.environment_pdf(d)), UInt32(NO_PRIM))
            out = s if out is None else _select_sample(index == n_lights - 1, s, out)
        return out

    def _sample_rectangle(self, r: Rectangle, k: int, u1: Float, u2: Float) -> LightSample:
        e1, e2 = r.edges
        a, b = square_to_uniform_disk_concentric(u1, u2) if r.disk else (2.0 * u1 - 1.0, 2.0 * u2 - 1.0)
        y = vec3(r.center) + vec3(e1) * a + vec3(e2) * b
        pdf = 1.0 / (self.n_lights * r.area)
        return LightSample(y, vec3(r.normal), vec3(r.radiance), Float(pdf), UInt32(self._prim_ranges[k][0]))

    def _sample_sphere(self, s: Sphere, k: int, u1: Float, u2: Float) -> LightSample:
        n = square_to_uniform_sphere(u1, u2)
        pdf = 1.0 / (self.n_lights * s.area)
        return LightSample(dr.fma(n, s.radius, vec3(s.center)), n, vec3(s.radiance), Float(pdf),
                           UInt32(self._prim_ranges[k][0]))

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
        pdf = 1.0 / (self.n_lights * areas.sum())
        return LightSample(y, n, vec3(m.radiance), Float(pdf), prim)

    def describe(self) -> list[str]:
        """What the traced kernel contains, for `tracer info`."""
        tris = "in a BVH" if self.bvh is not None else "brute force"
        lines = [f"intersection: {self.n_rects} rectangles (ray-plane, eq. 2-4), {self.n_tris} triangles "
                 f"(Moeller-Trumbore, {tris}), {len(self.spheres)} spheres (quadratic)"
                 + (f", {len(self.cylinders)} cylinders (quadratic)" if self.cylinders else "")]
        lines.append(f"shading normals: {'interpolated on smooth meshes' if self.smooth else 'geometric only'}")
        lines.append(f"materials: {', '.join(sorted({b.kind for b in self.materials}))}")
        env = " and a constant environment" if self.environment is not None else (
            " and an environment map" if self.envmap is not None else "")
        points = f", {len(self.points)} point light(s)" if self.points else ""
        lines.append(f"light sampling: {len(self.emitters)} area light(s){points}{env}")
        return lines


def _select_sample(mask: Bool, a: LightSample, b: LightSample) -> LightSample:
    cone = None
    if a.cone is not None or b.cone is not None:
        a_cone, b_cone = (s.cone if s.cone is not None else (Float(-2.0),) * 2 + (Float(0.0),) * 2 for s in (a, b))
        cone = tuple(dr.select(mask, x, y) for x, y in zip(a_cone, b_cone))
    return LightSample(dr.select(mask, a.y, b.y), dr.select(mask, a.n, b.n), dr.select(mask, a.radiance, b.radiance),
                       dr.select(mask, a.pdf_area, b.pdf_area), dr.select(mask, a.prim, b.prim), cone)


class _EnvmapKernel:
    """An `envmap` emitter in the kernel: radiance by direction, and the density and sampling of
    tracer/envmap.py's distribution (the map's tables gathered from; its frame as literals)."""

    def __init__(self, env):
        from .envmap import distribution

        self.h, self.w = env.image.shape[:2]
        self.texels = Float(np.asarray(env.image, np.float32).ravel())
        linear = env.to_world[:3, :3]
        self.to_world, self.to_local = linear, np.linalg.inv(linear)
        dist = distribution(env.image)
        self.mix = dist.mix_uniform
        self.row_cdf = Float(dist.row_cdf.astype(np.float32))
        self.col_cdf = Float(dist.col_cdf.astype(np.float32).ravel())
        self.cell_p = Float(dist.cell_p.astype(np.float32).ravel())

    def _local(self, d: Array3f) -> Array3f:
        m = self.to_local
        return Array3f(*(d.x * float(m[r, 0]) + d.y * float(m[r, 1]) + d.z * float(m[r, 2]) for r in range(3)))

    def _uv(self, v: Array3f) -> tuple[Float, Float]:
        u = dr.atan2(v.x, -v.z) * (0.5 / dr.pi)
        return u - dr.floor(u), dr.clip(dr.safe_acos(v.y) / dr.pi, 0.0, 1.0)

    def _texel(self, i: UInt32, j: UInt32) -> Array3f:
        return dr.gather(Array3f, self.texels, j * self.w + i)

    def radiance(self, d: Array3f) -> Array3f:
        u, t = self._uv(self._local(d))
        x = u * self.w - 0.5                              # texel-centred, periodic in u
        x0 = dr.floor(x)
        wx = x - x0
        i0 = UInt32(dr.select(x0 < 0, x0 + self.w, x0))
        i1 = dr.select(i0 + 1 >= self.w, i0 + 1 - self.w, i0 + 1)
        y = t * (self.h - 1)                              # rows at t = j / (H - 1)
        j0 = dr.minimum(UInt32(dr.floor(y)), self.h - 1)
        j1 = dr.minimum(j0 + 1, self.h - 1)
        wy = y - Float(j0)
        top = self._texel(i0, j0) * (1.0 - wx) + self._texel(i1, j0) * wx
        bottom = self._texel(i0, j1) * (1.0 - wx) + self._texel(i1, j1) * wx
        return top * (1.0 - wy) + bottom * wy

    def pdf(self, d: Array3f) -> Float:
        v = self._local(d)
        u, t = self._uv(v)
        i = dr.minimum(UInt32(u * self.w), self.w - 1)
        j = dr.minimum(UInt32(t * self.h), self.h - 1)
        sin_theta = dr.maximum(dr.safe_sqrt(1.0 - dr.square(v.y / dr.norm(v))), 1e-7)
        p_cells = dr.gather(Float, self.cell_p, j * self.w + i) * (self.w * self.h / (2.0 * dr.pi * dr.pi))
        return self.mix / (4.0 * dr.pi) + (1.0 - self.mix) * p_cells / sin_theta

    def sample(self, u1: Float, u2: Float) -> Array3f:
        uniform = u1 < self.mix
        s = dr.select(uniform, u1 / self.mix, (u1 - self.mix) / (1.0 - self.mix)) if self.mix < 1 else u1
        j = dr.binary_search(0, self.h - 1, lambda k: dr.gather(Float, self.row_cdf, k) <= s)
        lo = dr.select(j > 0, dr.gather(Float, self.row_cdf, j - 1, j > 0), 0.0)
        t = (Float(j) + dr.clip((s - lo) / (dr.gather(Float, self.row_cdf, j) - lo), 0.0, 1.0 - 2.0 ** -24)) / self.h
        base = j * self.w
        i = dr.binary_search(0, self.w - 1, lambda k: dr.gather(Float, self.col_cdf, base + k) <= u2)
        lo = dr.select(i > 0, dr.gather(Float, self.col_cdf, base + i - 1, i > 0), 0.0)
        u = (Float(i) + dr.clip((u2 - lo) / (dr.gather(Float, self.col_cdf, base + i) - lo), 0.0,
                                1.0 - 2.0 ** -24)) / self.w
        theta, phi = t * dr.pi, u * dr.two_pi
        sin_t, cos_t = dr.sincos(theta)
        sin_p, cos_p = dr.sincos(phi)
        m = self.to_world
        local = Array3f(sin_p * sin_t, cos_t, -cos_p * sin_t)
        d = dr.normalize(Array3f(*(local.x * float(m[r, 0]) + local.y * float(m[r, 1]) + local.z * float(m[r, 2])
                                   for r in range(3))))
        return dr.select(uniform, square_to_uniform_sphere(s, u2), d)
