"""The scene as Dr.Jit code: closest hit, shadow rays, surface data and light sampling, assembled from one
ShapeSet per shape kind (tracer.shapes), the material tables (tracer.materials) and the lights
(tracer.lights).

Kernels are traced from the scene: a shape kind, a smooth mesh or a second light the scene lacks adds no
instruction. A scene's numbers (primitive numbers, shapes' positions, lights' radiance) enter the kernels as
run-time constants, not literals, so that a scene of the same kinds and structure runs another's kernels from
Dr.Jit's cache.
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from functools import cached_property

import drjit as dr
import numpy as np

from .jit import NO_PRIM, Array3f, Bool, Float, UInt32, gather_row, gather_vec3, host_array, opaque_f, \
    opaque_u32, opaque_vec3, row_buffer, vec3
from .lights import ConstantEnvironment, EnvironmentMap, LightSample, select_sample
from .lights import choice as light_choices
from .lights.envmap import EnvmapKernel
from .materials import MaterialTables
from .media import MediaKernel
from .sampling import square_to_uniform_sphere
from .scene import Scene, SceneError
from .shapes import BVH_THRESHOLD, SETS, CylinderSet, MeshSet, Rectangle, RectangleSet, ShapeSet, SphereSet
from .shapes.rectangle import EmitterTable, corners_of
from .shapes.bvh import BATCHED_WALKS
from .shapes.instance import InstanceSet
from .shapes.planar import inset_point


@dataclass
class Hit:
    t: Float
    prim: UInt32
    b1: Float
    b2: Float
    p: Array3f        # the hit point, kept inside its rectangle or triangle (shapes.planar.inset_point)

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
    dpdu: Array3f | None = None   # the direction of dp/du, in scenes whose materials are oriented only
    dpdv: Array3f | None = None   # dp/dv (true length, as dp/du then), in scenes with bump maps only
    bary: tuple[Float, Float] | None = None   # a triangle's b1, b2, in scenes with mesh attributes only


def _crossed(sets: list, p0: np.ndarray, n: np.ndarray, light_below: bool, light_above: bool, eps: float) -> bool:
    """Whether a segment from a point of `sets` to a light may cross the plane (p0, n) strictly: some light
    lies below it (light_below) and some point of the sets above, or the reverse (sides beyond eps)."""
    if not (light_below or light_above):
        return False
    lo, hi = zip(*(s.side_bounds(p0, n) for s in sets))
    above, below = light_below and max(hi) > eps, light_above and min(lo) < -eps
    if not (above or below):      # the bounds already keep the sets to the lights' side
        return False
    for s in sets:
        side = s.sides(p0, n)
        if (above and np.any(side > eps)) or (below and np.any(side < -eps)):
            return True
    return False


def uses_bvh(scene: Scene) -> bool:
    """Whether a SceneGeometry of the scene (its default bvh_threshold) puts primitives into a BVH."""
    return (MeshSet.uses_bvh(scene.triangle_count) or SphereSet.uses_bvh(len(scene.of_kind(SphereSet.kind)))
            or RectangleSet.uses_bvh(len(scene.of_kind(RectangleSet.kind)))
            or CylinderSet.uses_bvh(len(scene.of_kind(CylinderSet.kind))) or scene.instanced_triangles[1] > 0)


ALWAYS_BOUNCE_BY_BOUNCE = False   # diagnostics and tests: every scene with a mesh BVH goes bounce by bounce


def goes_bounce_by_bounce(scene: Scene, has_mesh_bvh: bool) -> bool:
    """Whether the path tracer goes bounce by bounce (SceneGeometry.bounce_by_bounce), for a scene with or
    without a mesh BVH (also before its geometry is built: rendering.make_plan) and an `envmap` emitter. Only
    a mesh's BVH: the small BVHs of rectangles, disks and spheres are walked faster inside the one kernel
    (path, CPU seconds of a render, 128 x 128, 16 spp, the fastest of 3 interleaved, machine loaded: 40 spheres
    0.10 s in one kernel against 0.23 s bounce by bounce, the 16 x 16-light Cornell box's 261 rectangles 0.53 s
    against 0.71 s). Only under an envmap, as measured, not explained: the median CPU seconds of a render in
    one kernel over the median bounce by bounce (4 renders a side, 2 a process, processes interleaved, 4 spp,
    quiet machine) on mitsuba-data's envmap-lit scenes were 1.18 (texture_checkerboard), 1.28
    (shape_ply_bunny), 1.28 (medium_homogeneous_sss), 1.18 (matpreview), but 0.88 (bsdf_conductor_gold); on
    emitter_spot_no_texture (two spot lights and a `constant` emitter) 0.62, and on the project's mesh
    benchmark (the Cornell box around 250,000 triangles, area light, 64 spp) 0.88."""
    return has_mesh_bvh and (scene.envmap is not None or ALWAYS_BOUNCE_BY_BOUNCE) and BATCHED_WALKS


_recorded: list | None = None    # see recorded_queries
PASSING = ("null", "thindielectric")    # material kinds with a null lobe (materials.bsdf's null_transmission)
LAST_PRIM = NO_PRIM - 2    # primitive numbers from here on mark light samples (lights.sample)


@contextmanager
def recorded_queries():
    """Within: each batched ray query (SceneGeometry.closest_hit and occluded within batched()) keeps its
    rays in the list yielded, as ("closest hit" or "shadow", origins (n, 3), directions (n, 3), the
    farthest distance each may reach (n,)) NumPy arrays, shadow rays where active. For validate bench,
    which replays a render's own rays through both renderers' ray queries."""
    global _recorded
    _recorded = []
    try:
        yield _recorded
    finally:
        _recorded = None


def _record(query: str, o: Array3f, d: Array3f, t_max, active=True) -> None:
    o, d, t_max, active = Array3f(o), Array3f(d), Float(t_max), Bool(active)
    dr.eval(o, d, t_max, active)
    n = max(dr.width(o), dr.width(d), dr.width(t_max), dr.width(active))
    keep = np.broadcast_to(active.numpy(), (n,))
    rows = [np.broadcast_to(np.stack([c.numpy() for c in v], 1), (n, 3))[keep] for v in (o, d)]
    _recorded.append((query, *rows, np.broadcast_to(t_max.numpy(), (n,))[keep]))


class SceneGeometry:
    """`bvh_threshold`: triangles above which they go into a BVH; `material_kinds`: the material codes the
    kernel carries (materials.DIFFUSE, CONDUCTOR, ...; default: those of the scene's materials);
    `light_choice`: how a shadow ray's light is chosen where the scene gives no sampling_weight
    (tracer.lights.choice.POLICIES; default its DEFAULT)."""

    def __init__(self, scene: Scene, bvh_threshold: int = BVH_THRESHOLD, material_kinds: set[int] | None = None,
                 light_choice: str | None = None):
        self.scene = scene
        self.batch = False                     # BVH walks over rays in memory (see `batched`)
        self.shape_sets, base = [], 0          # one per kind, in primitive order
        for cls in SETS:
            options = {"bvh_threshold": bvh_threshold} if cls is MeshSet else {}
            self.shape_sets.append(cls(scene.of_kind(cls.kind), base, **options))
            base += self.shape_sets[-1].count
        self.n_prims = base                    # the scene's own primitives; the instanced ones number after them
        self.instanced = []                    # one two-level BVH per shapegroup with meshes (shapes.instance)
        for group in scene.groups:
            if group.meshes and group.to_world:
                self.instanced.append(InstanceSet(group, base))
                base += self.instanced[-1].count
        if base >= LAST_PRIM:
            raise SceneError(f"{scene.path}: {base:,} primitives with the instanced triangles (each instance's "
                             f"numbered apart); the tracer numbers at most {LAST_PRIM:,}")
        self.rectangles, self.meshes = (self._set(cls) for cls in (RectangleSet, MeshSet))
        self.bvhs = [s.bvh for s in self.shape_sets if s.bvh is not None]   # walked after the unrolled tests
        self.curved_base = sum(s.count for s in self.shape_sets if s.planar)   # primitives below it are planar
        self.materials = MaterialTables(scene.bsdfs, material_kinds, self.meshes)
        self.emitters = scene.emitters
        self.environment = scene.environment
        self.envmap = EnvmapKernel(scene.envmap) if scene.envmap is not None else None
        self.has_environment = scene.has_environment
        self.delta_lights = scene.delta_lights
        self.points = scene.point_lights
        self.directionals = scene.directional_lights
        self.spots = any(light.spot is not None for light in self.points)
        # lights a shadow ray may be sent to, numbered in this order: the area lights, delta lights, the environment
        lights = [*self.emitters, *self.delta_lights,
                  *(x for x in scene.lights if isinstance(x, (ConstantEnvironment, EnvironmentMap)))]
        self.n_lights = len(lights)
        if lights and not any(x.sampling_weight for x in lights):
            raise SceneError(f"{scene.path}: every emitter's sampling_weight is 0, so no light can be chosen "
                             "(Mitsuba refuses this too)")
        self.choice = light_choices.choose(lights, [x.sampling_weight for x in lights],
                                           light_choice or light_choices.DEFAULT, 0.5 * scene.extent())
        self.has_infinite_lights = self.has_environment or bool(self.directionals)   # shadow rays leave the scene
        self.has_lights = self.n_lights > 0
        self.occluders = self._possible_occluders()
        self._build_tables()
        # the media the `volpath` integrator renders (None: none, or another integrator, which ignores them)
        self.media = MediaKernel(scene, self) if scene.media and scene.volumetric else None
        # whether some surface lets shadow rays through (a null lobe): volpath then tracks them across it
        self.materials_pass_light = any(
            b.kind in PASSING or b.opacity < 1 or (b.blend is not None and b.blend[1].kind in PASSING)
            for b in scene.bsdfs)

    # ---- host-side tables, gathered by primitive index -------------------------------------------
    # Rows a lane gathers in one packet load (jit.row_table): prim_shading, the normal and material (as a
    # float); prim_emission, the radiance and light pdf; prim_frame, each of origin, e1 and e2.
    def _build_tables(self) -> None:
        n = max(self.n_prims, 1)  # an empty scene still needs a table to gather (masked off) from
        shading, emission = row_buffer((n,), 4), row_buffer((n,), 4)
        normals, material, radiance, light_pdf = shading[:, :3], shading[:, 3], emission[:, :3], emission[:, 3]
        emitting = np.zeros(n, bool)
        for shapes in self.shape_sets:
            normals[shapes.base:shapes.base + shapes.count] = shapes.normals()
            for s, lo, count in shapes.shape_primitives():
                material[lo:lo + count] = self.materials.index(s.bsdf)
        for k, e in enumerate(self.emitters):
            lo, hi = self.prim_range(e)
            radiance[lo:hi] = e.radiance
            area = e.area
            light_pdf[lo:hi] = self.choice.pdf_area(k, area) if area > 0 else 0.0
            emitting[lo:hi] = area > 0
        if len(self.materials.bsdfs) > 1 << 24:
            raise SceneError(f"{self.scene.path}: more than 2^24 materials (a primitive's is read as a float)")
        self.prim_shading, self.prim_emission = host_array(Float, shading), host_array(Float, emission)
        # emits() reads the light pdf where it is positive exactly on the emitters, else a table of its own
        self.prim_emits = None if np.array_equal(emitting, light_pdf > 0) else UInt32(emitting.astype(np.uint32))
        frames = row_buffer((max(self.curved_base, 1), 3), 3)
        for shapes in self.shape_sets:
            if shapes.planar:
                frames[shapes.base:shapes.base + shapes.count, :, :3] = shapes.frames()
        self.prim_frame = host_array(Float, frames)
        if self.materials.textured:
            self.meshes.build_uvs()
        if self.materials.oriented:
            self.meshes.build_tangents()
        for group in self.instanced:
            group.set_materials(self.materials.index)
            if self.materials.textured:
                group.meshes.build_uvs()
            if self.materials.oriented:
                group.meshes.build_tangents()

    def _set(self, cls: type) -> ShapeSet:
        return next(s for s in self.shape_sets if isinstance(s, cls))

    def _set_of(self, shape):
        """The ShapeSet holding `shape`, and its primitive range."""
        for shapes in self.shape_sets:
            if (r := shapes.prim_range(shape)) is not None:
                return shapes, r
        raise ValueError(f"the {type(shape).__name__.lower()} is not part of this scene")

    def prim_range(self, shape) -> tuple[int, int]:
        """The primitive indices [lo, hi) of a shape of the scene."""
        return self._set_of(shape)[1]

    def _possible_occluders(self) -> set[int]:
        """Primitives that can block a shadow ray. A shadow ray joins a point of the scene to a point on a
        light, so a planar primitive lies strictly between its ends only if the scene reaches strictly to one
        side of its plane and a light strictly to the other: others (a wall of a convex room, a light's tile
        beside other tiles in its plane) are left out of the shadow-ray kernel. Shadow rays to an environment
        leave the scene, so with one (or a directional light) every primitive may block."""
        if self.has_infinite_lights:
            return set(range(self.n_prims))
        ends, radii = self._light_hull()
        eps = 1e-6 * self.scene.extent()
        keep = set(range(self.curved_base, self.n_prims))
        sets = sorted((s for s in [*self.shape_sets, *self.instanced] if s.count),
                      key=lambda s: s.count)   # the cheapest sides first
        for shapes in self.shape_sets:
            for i, p0, n in shapes.culling_planes():
                end = (ends - p0) @ n
                if _crossed(sets, p0, n, bool(np.any(end - radii < -eps)), bool(np.any(end + radii > eps)), eps):
                    keep.add(i)
        return keep

    @property
    def shadow_bvhs(self) -> list:
        """The BVHs that shadow rays walk: those holding a primitive that may block one (occluders)."""
        return [s.bvh for s in self.shape_sets if s.walked_by_shadow_rays(self.occluders)]

    def _light_hull(self) -> tuple[np.ndarray, np.ndarray]:
        """(centres, radii): balls whose hull holds every point where a shadow ray may end: point lights, the
        corners of emitting rectangles (a disk's square), the vertices of emitting meshes, emitting spheres."""
        balls = [(light.position, 0.0) for light in self.points]
        for e in self.emitters:
            if isinstance(e, Rectangle):
                balls += [(p, 0.0) for p in corners_of([e])[0]]
            elif isinstance(e, SphereSet.kind):
                balls.append((e.center, e.radius))
            else:
                balls += [(p, 0.0) for p in np.reshape(e.vertices, (-1, 3))]
        return np.reshape([p for p, _ in balls], (-1, 3)), np.array([r for _, r in balls], float)

    # ---- ray queries ------------------------------------------------------------------------------
    @property
    def bounce_by_bounce(self) -> bool:
        """Whether the path tracer goes bounce by bounce, its mesh BVH walks batched (integrators.path)."""
        return goes_bounce_by_bounce(self.scene, self.meshes.bvh is not None or bool(self.instanced))

    @contextmanager
    def batched(self):
        """Within: a ray query evaluates its rays and walks the BVH over them in a kernel of its own, by
        persistent lanes (BVHKernel._walk_batch), instead of in the caller's kernel. The same results; for
        callers that evaluate their state between ray queries anyway (a wavefront). On the LLVM backend only
        (shapes.bvh.BATCHED_WALKS)."""
        self.batch = BATCHED_WALKS
        try:
            yield self
        finally:
            self.batch = False

    def keep(self, *values) -> None:
        """Within batched(): `values`, which code after the next ray query reads, are computed by the
        kernel that evaluates that query's rays and kept in memory (dr.schedule); the kernels after the
        query would else compute them again from their inputs (a surface's gathers, a light sample). In
        one kernel (outside batched()) nothing is computed twice: nothing to do."""
        if self.batch:
            dr.schedule(*values)

    def _candidates(self, o, d, t_min, skip, target=None, only=None):
        for shapes in self.shape_sets:
            yield from shapes.candidates(o, d, t_min, skip, target, only)

    def closest_hit(self, o: Array3f, d: Array3f, t_min, t_max, skip: UInt32) -> Hit:
        """Nearest hit along o + t d, never on primitive `skip` (the one the ray leaves)."""
        if self.batch and _recorded is not None:
            _record("closest hit", o, d, t_max)
        t_best, prim = Float(t_max), UInt32(NO_PRIM)
        b1, b2 = Float(0), Float(0)
        for i, t, u, v in self._candidates(o, d, t_min, skip):
            closer = t < t_best
            t_best = dr.select(closer, t, t_best)
            prim = dr.select(closer, i, prim)
            if u is not None:
                b1, b2 = dr.select(closer, u, b1), dr.select(closer, v, b2)
        for bvh in self.bvhs:
            t_best, prim, b1, b2 = bvh.closest_hit(o, d, t_min, t_best, prim, b1, b2, skip, self.batch)
        for group in self.instanced:
            t_best, prim, b1, b2 = group.closest_hit(o, d, t_min, t_best, prim, b1, b2, skip, self.batch)
        p = self._hit_point(o, d, t_best, prim, b1, b2)
        for group in self.instanced:
            p = group.hit_point(prim, b1, b2, p)
        return Hit(t_best, prim, b1, b2, p)

    def _hit_point(self, o, d, t, prim, b1, b2) -> Array3f:
        """o + t d, or on a rectangle or triangle the point of its local coordinates kept inside it
        (shapes.planar.inset_point), from the primitive's frame (origin, e1, e2)."""
        p = dr.fma(d, t, o)
        if not self.curved_base:
            return p
        curved_base, mesh_base = self._planar_ranges
        planar = prim < curved_base
        origin, e1, e2 = (gather_vec3(self.prim_frame, prim * 3 + k, planar) for k in range(3))
        inset = inset_point(origin, e1, e2, b1, b2, prim < mesh_base)
        return dr.select(planar, inset, p)

    @cached_property
    def _planar_ranges(self) -> tuple[UInt32, UInt32]:
        """curved_base and the meshes' first primitive, as run-time constants (jit.opaque_u32)."""
        return opaque_u32(self.curved_base), opaque_u32(self.meshes.base)

    def occluded(self, o: Array3f, d: Array3f, dist: Float, skip: UInt32, target: UInt32,
                 active: Bool = True) -> Bool:
        """Whether anything but `skip` and `target` lies on the segment o + t d, 0 < t < dist. Lanes that
        are not active may answer either way; only the BVH skips work for them."""
        if self.batch and _recorded is not None:
            _record("shadow", o, d, dist, active)
        blocked = Bool(False)
        for i, t, _, _ in self._candidates(o, d, 0.0, skip, target, self.occluders):
            blocked |= t < dist
        for bvh in self.shadow_bvhs:
            blocked |= bvh.occluded(o, d, dist, skip, target, active & ~blocked, self.batch)
        for group in self.instanced:
            blocked |= group.occluded(o, d, dist, skip, active & ~blocked, self.batch)
        return blocked

    # ---- surface data -----------------------------------------------------------------------------
    def own(self, prim: UInt32, valid: Bool) -> Bool:
        """valid where prim is one of the scene's own primitives (not an instanced triangle): the lanes
        that may read the tables of its own primitives."""
        return valid & (prim < self.n_prims) if self.instanced else valid

    def shading_row(self, prim: UInt32, active: Bool = True) -> tuple[Array3f, UInt32]:
        """A primitive's geometric normal (a curved shape's is its own, ShapeSet.normal) and material."""
        x = gather_row(self.prim_shading, 4, prim, active)
        return Array3f(x[0], x[1], x[2]), UInt32(x[3])

    def surface(self, hit: Hit) -> Surface:
        valid = self.own(hit.prim, hit.valid)
        prim = dr.select(valid, hit.prim, 0)
        n, material = self.shading_row(prim, valid)
        for shapes in self.shape_sets:
            n = shapes.normal(prim, hit.p, n)
        ns = self.meshes.shading_normal(prim, hit.b1, hit.b2, n)
        uv = None
        if self.materials.textured:
            uv = (Float(0.0), Float(0.0))
            for shapes in self.shape_sets:
                uv = shapes.uv(prim, valid, hit.p, hit.b1, hit.b2, uv)
        dpdu = None
        if self.materials.oriented:
            dpdu = Array3f(0.0)
            for shapes in self.shape_sets:
                dpdu = shapes.tangent(prim, valid, hit.p, hit.b1, hit.b2, dpdu)
        dpdv = None
        if self.materials.any_bumpmap:
            dpdv = self.meshes.cotangent(prim, valid, Array3f(0.0))
        for group in self.instanced:
            n, ns, material, uv, dpdu, dpdv = group.surface(hit.prim, hit.valid, hit.p, hit.b1, hit.b2, n, ns,
                                                            material, uv, dpdu, dpdv)
        valid = hit.valid
        bary = (hit.b1, hit.b2) if self.materials.attributed else None
        return Surface(hit.p, n, ns, material, dr.select(valid, hit.prim, NO_PRIM), valid, uv, dpdu, dpdv, bary)

    # ---- lights -----------------------------------------------------------------------------------
    def emitted(self, surf: Surface, wi: Array3f) -> Array3f:
        """Radiance an area light emits along wi (pointing away from the surface, back along the ray that
        found it): only on the side its normal faces; on a ray that hits nothing, the environment's."""
        if not self.has_lights:
            return Array3f(0.0)
        le = Array3f(0.0)
        if self.emitters:
            own = self.own(surf.prim, surf.valid)
            le = gather_vec3(self.prim_emission, surf.prim, own)
            le = dr.select(own & (dr.dot(surf.ns, wi) > 0), le, Array3f(0.0))
        if self.has_environment:
            le = dr.select(surf.valid, le, self.environment_radiance(-wi))
        return le

    def emits(self, surf: Surface) -> Bool:
        """Whether the surface hit is an area light's shape (either side)."""
        if not self.emitters:
            return Bool(False)
        own = self.own(surf.prim, surf.valid)
        if self.prim_emits is not None:     # a light never chosen (sampling_weight 0, or no power)
            return own & (dr.gather(UInt32, self.prim_emits, surf.prim, own) > 0)
        return own & (self.light_pdf_area(surf) > 0)

    def environment_radiance(self, d: Array3f) -> Array3f:
        """Radiance arriving from the environment along -d (d: the direction leaving the scene)."""
        if self.envmap is not None:
            return self.envmap.radiance(d)
        return vec3(self.environment)

    def light_pdf_area(self, surf: Surface) -> Float:
        """Area density with which sample_light picks this point (0 off the lights)."""
        return gather_row(self.prim_emission, 4, surf.prim, self.own(surf.prim, surf.valid))[3]

    def environment_pdf(self, d: Array3f):
        """Solid-angle density with which sample_light picks direction d to the environment."""
        if self.envmap is not None:
            return self.envmap.pdf(d) * self.choice.pmf(self.n_lights - 1)
        return self.choice.pdf_area(self.n_lights - 1, 4.0 * np.pi)

    def sample_light(self, u_select: Float, u1: Float, u2: Float, ref: Array3f | None = None) -> LightSample:
        """A light chosen (self.choice), then a point uniform in area on it; for the environment, a direction
        uniform on the sphere, returned as y (with n = -y, prim = NO_PRIM and pdf_area its solid-angle
        density); for a point light its position (prim = POINT_LIGHT, pdf_area the choice's probability), its
        intensity towards `ref` where it varies with direction (a spot's texture, a projector's image)."""
        index = self.choice.sample(u_select)
        samples, tabled, first = [], self._emitter_table, 0
        if tabled is not None:                # the first emitters (rectangles and disks): light `index`'s row
            samples.append(LightSample(*tabled.sample(index, u1, u2)))
            first = tabled.count - 1          # samples[k] is light first + k's (for k > 0)
        for k, e in enumerate(self.emitters[first + len(samples):], first + len(samples)):
            shapes, (lo, _) = self._set_of(e)
            y, n, prim = shapes.sample(e, lo, u1, u2, self)
            pdf_area = self.choice.pdf_area(k, e.area) if e.area > 0 else np.inf    # no area: no power
            samples.append(LightSample(y, n, opaque_vec3(e.radiance), opaque_f(pdf_area), prim))
        for k, light in enumerate(self.delta_lights, len(self.emitters)):
            samples.append(light.sample(self.choice.pmf(k), self.spots))
            if getattr(light, "varies", False) and ref is not None:
                samples[-1].radiance = samples[-1].radiance * light.profile(ref)
        if self.has_environment:
            d = self.envmap.sample(u1, u2) if self.envmap is not None else square_to_uniform_sphere(u1, u2)
            samples.append(LightSample(d, -d, self.environment_radiance(d), Float(self.environment_pdf(d)),
                                       UInt32(NO_PRIM)))
        out = samples[0] if samples else None
        for k, s in enumerate(samples[1:], first + 1):
            out = select_sample(index == k, s, out)
        return out

    @cached_property
    def _emitter_table(self) -> EmitterTable | None:
        """The emitting rectangles and disks as a table (shapes.rectangle.EmitterTable) where there are
        several: a sample then gathers the one it chose. They are the first emitters (primitive order)."""
        lights = [e for e in self.emitters if isinstance(e, Rectangle)]
        if len(lights) < 2:
            return None
        pdf = [self.choice.pdf_area(k, e.area) if e.area > 0 else np.inf for k, e in enumerate(lights)]
        return EmitterTable(lights, [self.prim_range(e)[0] for e in lights], pdf)

    def describe(self) -> list[str]:
        """What the traced kernel contains, for `tracer info`."""
        kinds = [s.describe() for s in self.shape_sets if s.count]
        lines = [f"intersection: {', '.join(kinds) or 'no shapes'}"]
        lines += [f"instancing: {group.describe()}" for group in self.instanced]
        lines.append(f"shading normals: {'interpolated on smooth meshes' if self.meshes.smooth else 'geometric only'}")
        lines.append(f"materials: {', '.join(sorted({b.kind for b in self.materials.bsdfs})) or 'none'}")
        env = " and a constant environment" if self.environment is not None else (
            " and an environment map" if self.envmap is not None else "")
        points = f", {len(self.points)} point light(s)" if self.points else ""
        points += f", {len(self.directionals)} directional light(s)" if self.directionals else ""
        lines.append(f"light sampling: {len(self.emitters)} area light(s){points}{env}, {self.choice.describe()}")
        if self.media is not None:
            lines.append(self.media.describe())
        elif self.scene.media:
            lines.append(f"media: {len(self.scene.media)}, not rendered: the {self.scene.integrator.split()[-1]} integrator "
                         "ignores them, as Mitsuba's does (volpath renders them)")
        if self.bounce_by_bounce:
            lines.append("path tracing: bounce by bounce, each bounce's rays walked through the BVH by persistent "
                         "lanes")
        return lines
