"""Triangle meshes (Mitsuba's `obj`, `ply`, `serialized`): tested one by one when few, else through the BVH
(tracer.shapes.bvh); interpolated shading normals and texture coordinates; area sampling."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from .. import transform
from .bvh import BVHKernel, triangle_frames
from .bvh_cache import cached_layout
from ..ply_attributes import Attributes
from ..meshes import (MeshError, bounding_box, corner_blocks, cross_rows, length_rows, read_obj, read_ply,
                      vertex_normals)
from ..serialized import read_serialized
from ..jit import CORES, HOST_FLOAT, INF, Array3f, Bool, Float, UInt32, aligned_zeros, gather_row, gather_vec3, \
    host_array, row_buffer, row_table, vec3
from ..sampling import GuidedCDF, square_to_uniform_triangle
from .base import ShapeArgs, ShapeSet, exclude
from .triangle import ray_triangle

from ..materials.textures import MeshAttribute

if TYPE_CHECKING:
    from ..materials import BSDF

PLUGINS = {"obj": ("filename", "face_normals", "flip_normals", "flip_tex_coords", "to_world", "silhouette_sampling_weight"),
           "ply": ("filename", "face_normals", "flip_normals", "flip_tex_coords", "to_world", "silhouette_sampling_weight"),
           "serialized": ("filename", "shape_index", "face_normals", "flip_normals", "to_world",
                          "silhouette_sampling_weight")}
LOAD_THREADS = CORES     # threads that read a scene's mesh files
BVH_THRESHOLD = 56  # triangles above which a BVH beats the unrolled brute-force tests (measured: brute force wins at 48, the BVH at 64)


@dataclass(eq=False)
class Mesh:
    """A triangle mesh in world space; `normals` are per-vertex shading normals, None for face normals."""

    vertices: np.ndarray
    faces: np.ndarray
    bsdf: BSDF
    normals: np.ndarray | None = None
    radiance: tuple[float, float, float] | None = None
    name: str = ""
    uvs: np.ndarray | None = None        # per-vertex texture coordinates; None: a triangle's (b1, b2)
    attributes: Attributes | None = None   # a PLY file's vertex and face attributes (None: the format has none)
    sampling_weight: float = 1.0         # an area emitter's (tracer.lights.choice)

    @cached_property
    def triangle_areas(self) -> np.ndarray:
        v = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)

    @cached_property
    def area(self) -> float:
        return self.triangle_areas.sum()

    def extent_points(self) -> list[np.ndarray]:
        return [self.vertices]


@dataclass(eq=False)
class MeshFile:
    """A mesh shape as its XML element gives it, its file not yet read: the loader reads all of a scene's
    (`load`, in parallel) once every element is checked."""

    args: ShapeArgs
    file: Path
    shape_index: int     # serialized only
    face_normals: bool
    flip_tex_coords: bool = False   # v -> 1 - v (Mitsuba's default on OBJ files)


def from_xml(ctx, props, a: ShapeArgs) -> MeshFile:
    node, kind, bsdf = a.node, a.kind, a.bsdf
    filename = props.get("filename", None, ("string",))
    face_normals = props.get("face_normals", False, ("boolean",))
    shape_index = props.get("shape_index", 0, ("integer",)) if kind == "serialized" else 0
    flip_tex_coords = props.get("flip_tex_coords", kind == "obj", ("boolean",)) if kind != "serialized" else False
    props.finish()
    if not filename:
        raise ctx.error(node, f"{kind} shape needs a <string name=\"filename\">")
    file = ctx.resolve(filename)
    if not file.is_file():
        raise ctx.error(node, f"mesh file '{filename}' not found (looked in {', '.join(map(str, ctx.resolver))})")
    if shape_index < 0:
        raise ctx.error(node, f"shape_index must be non-negative, got {shape_index}")
    return MeshFile(a, file, shape_index, face_normals, flip_tex_coords)


def load(requests: list[MeshFile]) -> list[Mesh | MeshError]:
    """The meshes of `requests` (or why one cannot be read): each file read once and its meshes placed in
    the world with their vertex normals, files on up to LOAD_THREADS threads, the largest first. The
    readers' bulk passes and NumPy's release the interpreter lock for much of their time (measured on 2
    cores: the three files of 997,534 triangles of validate bench's mesh scene in 0.78-0.84 s against
    0.97-1.06 s on one thread)."""
    files: dict[tuple[str, Path, int], list[MeshFile]] = {}
    for r in requests:
        files.setdefault((r.args.kind, r.file, r.shape_index), []).append(r)
    order = sorted(files, key=lambda f: -_size(f[1]))
    with ThreadPoolExecutor(min(LOAD_THREADS, max(len(files), 1))) as pool:
        placed = pool.map(lambda f: _read_and_place(f, files[f]), order)
        meshes = dict(zip((r for f in order for r in files[f]), (m for group in placed for m in group)))
    return [meshes[r] for r in requests]


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:      # _read reports it
        return 0


def _read_and_place(file: tuple[str, Path, int], requests: list[MeshFile]) -> list[Mesh | MeshError]:
    read = _read(file)
    return [_place(r, read) for r in requests]


def _read(file: tuple[str, Path, int]) -> tuple | MeshError:
    """(vertices, faces, normals, uvs, attributes) of a mesh file, as its reader gives them (attributes None
    for the formats without), or the reader's error."""
    kind, path, shape_index = file
    try:
        if kind == "serialized":
            return (*read_serialized(path, shape_index), None)
        return read_ply(path) if kind == "ply" else (*read_obj(path), None)
    except MeshError as e:
        return e


def _place(r: MeshFile, read: tuple | MeshError) -> Mesh | MeshError:
    """The mesh in world space, with Mitsuba's vertex normals where the file gives none (and face normals
    not asked for)."""
    if isinstance(read, MeshError):
        return read
    vertices, faces, normals, uvs, attributes = read
    a = r.args
    if why := attribute_refusal(a.bsdf, attributes):
        return MeshError(why)
    textured = any(not isinstance(t, MeshAttribute) for t in a.bsdf.every_texture())   # read at texture coordinates
    if a.flip and textured and uvs is None:
        return MeshError("flip_normals with a texture on a mesh without texture coordinates is unsupported")
    if textured and uvs is not None and np.isnan(uvs[np.unique(faces)]).any():
        return MeshError("a texture on a mesh whose faces name texture coordinates for some corners only (Mitsuba "
                         "leaves the others undefined)")
    if uvs is not None and r.flip_tex_coords:
        uvs = uvs * [1.0, -1.0] + [0.0, 1.0]
    vertices = transform.apply_point(a.to_world, vertices)
    if a.flip:     # reversed winding flips the face normals
        faces = faces[:, ::-1]
    if r.face_normals:
        normals = None
    elif normals is None:
        normals = vertex_normals(vertices, faces)
    else:
        normals = transform.apply_normal(a.to_world, normals) * (-1.0 if a.flip else 1.0)
    return Mesh(vertices, faces, a.bsdf, normals, a.radiance, a.name, uvs, attributes, a.sampling_weight)


def attribute_refusal(bsdf: BSDF, attributes: Attributes | None) -> str:
    """Why the material's mesh_attribute textures cannot be read on a mesh of these attributes ('' where
    they can): a name it lacks, channels the parameter cannot read, attributes Mitsuba reads astray."""
    wanted = [t for t in bsdf.every_texture() if isinstance(t, MeshAttribute)]
    if not wanted:
        return ""
    if attributes is None:
        return "mesh_attribute on a mesh format without attributes; supported: ply"
    if attributes.unread:
        return f"mesh_attribute on a PLY file whose properties Mitsuba 3.9.1 groups astray: {attributes.unread}"
    for t in wanted:
        values = attributes.values.get(t.name)
        if values is None:
            return f"mesh_attribute '{t.name}': the mesh has no such attribute; its attributes: {attributes.describe()}"
        if why := t.check(values.shape[1]):
            return why
    return ""


class MeshSet(ShapeSet):
    """Every mesh's triangles, in the order of the meshes; `bvh_threshold`: triangles above which they go
    into a BVH."""
    kind = Mesh
    planar = True

    def __init__(self, meshes: list[Mesh], base: int, bvh_threshold: int = BVH_THRESHOLD):
        super().__init__(meshes, base)
        # every mesh's vertices, and faces numbering them
        first_vertex = np.cumsum([0] + [len(m.vertices) for m in meshes])
        first_face = np.cumsum([0] + [len(m.faces) for m in meshes])
        vertices = [m.vertices for m in meshes]
        self._vertices = np.concatenate(vertices, out=aligned_zeros((first_vertex[-1], 3), np.result_type(*vertices))) \
            if meshes else np.zeros((0, 3))    # on a cache line: the BVH build's kernels read it as it is
        self._faces = np.concatenate([m.faces for m in meshes], dtype=np.int64) if meshes \
            else np.zeros((0, 3), np.int64)
        for m, k, lo in zip(meshes, first_vertex, first_face):
            self._faces[lo:lo + len(m.faces)] += k    # in place: a copy of all faces per mesh took longer
        self.smooth = any(m.normals is not None for m in meshes)
        source = [a for m in meshes for a in (m.vertices, m.faces)]   # what the triangles are made of
        self.bvh = self._bvh(source) if self.uses_bvh(self.count, bvh_threshold) else None
        self.corner_normals = host_array(Float, self._corner_normals()) if self.smooth else None   # read there only
        self.corner_uvs = None
        self.tangents = None
        self._emitter_tables: dict[int, tuple[GuidedCDF, Float]] = {}

    @staticmethod
    def uses_bvh(triangles: int, bvh_threshold: int = BVH_THRESHOLD) -> bool:
        """Whether a MeshSet of this many triangles puts them into a BVH."""
        return triangles > bvh_threshold

    def _bvh(self, source: list[np.ndarray]) -> BVHKernel:
        """The BVH over the triangles; their frames are computed (NumPy, mostly without the GIL) on a second
        thread while the build runs, whose kernels leave a core idle between them."""
        with ThreadPoolExecutor(1) as pool:
            frames = pool.submit(self.frames)
            tables = cached_layout(self._vertices, source=source, faces=self._faces)
            return BVHKernel(tables, frames.result(), self.base)

    @property
    def count(self) -> int:
        return len(self._faces)

    @cached_property
    def tri_vertices(self) -> np.ndarray:
        """(triangles, 3, 3) each triangle's corners."""
        return np.take(self._vertices, self._faces, axis=0)

    def shape_primitives(self):
        lo = self.base
        for m in self.shapes:
            yield m, lo, len(m.faces)
            lo += len(m.faces)

    @cached_property
    def _frames_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """The triangles' frames (bvh.triangle_frames) and unit geometric normals (right-handed in the
        corners' order), from their corners' coordinate rows, a block at a time (meshes.corner_blocks;
        measured: 0.16-0.21 s against 0.27-0.36 s all at once at 997,534 triangles, a fresh process each)."""
        frames, normals = np.empty((self.count, 3, 3), HOST_FLOAT), np.empty((self.count, 3))
        for block, (c0, c1, c2) in corner_blocks(self._vertices, self._faces.T):
            e1, e2 = c1 - c0, c2 - c0
            n = cross_rows(e1, e2)
            frames[block], normals[block] = triangle_frames(c0, e1, e2), (n / np.maximum(length_rows(n), 1e-300)).T
        return frames, normals

    def normals(self) -> np.ndarray:
        """(triangles, 3) unit geometric normals (right-handed in the corners' order)."""
        return self._frames_normals[1]

    @cached_property
    def _corners(self) -> np.ndarray:
        """The vertices the triangles use, each once (the triangles' hull for shadow-ray culling)."""
        used = []
        for m in self.shapes:
            mask = np.zeros(len(m.vertices), bool)
            mask[m.faces] = True
            used.append(m.vertices[mask])
        return np.concatenate(used) if used else np.zeros((0, 3))

    def _corner_normals(self) -> np.ndarray:
        """(triangles, 3) rows (jit.row_buffer) of the shading normals at each triangle's corners (its face normal
        on flat meshes)."""
        out = row_buffer((max(self.count, 1), 3), 3)
        for m, lo, n in self.shape_primitives():
            tri = slice(lo - self.base, lo - self.base + n)
            out[tri, :, :3] = np.take(m.normals.astype(HOST_FLOAT), m.faces, axis=0) if m.normals is not None \
                else self.normals()[tri][:, None, :]
        return out

    def build_uvs(self) -> None:
        """Per triangle corner texture coordinates (a triangle's own (0,0), (1,0), (0,1) where its mesh has
        none, so that interpolation gives (b1, b2) as Mitsuba); for scenes with textures."""
        uvs = np.zeros((max(self.count, 1), 3, 2))
        for m, lo, n in self.shape_primitives():
            uvs[lo - self.base:lo - self.base + n] = m.uvs[m.faces] if m.uvs is not None else [[0, 0], [1, 0], [0, 1]]
        self.corner_uvs = row_table(uvs.reshape(-1, 6))

    def build_tangents(self) -> None:
        """Per triangle dp/du as Mitsuba's mesh computes it: from the corners' texture coordinates (the
        edges p1 - p0, p2 - p0 against the uv edges), p1 - p0 where the mesh has none, and the first tangent
        of Mitsuba's coordinate system around the face normal where the uv edges are degenerate; for scenes
        whose materials depend on it."""
        out, out_v = np.zeros((max(self.count, 1), 3)), np.zeros((max(self.count, 1), 3))
        for m, lo, n in self.shape_primitives():
            c = m.vertices[m.faces].astype(np.float64)
            dp0, dp1 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
            tri = slice(lo - self.base, lo - self.base + n)
            if m.uvs is None:
                out[tri], out_v[tri] = dp0, dp1
                continue
            uv = m.uvs[m.faces].astype(np.float64)
            duv0, duv1 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
            det = duv0[:, 0] * duv1[:, 1] - duv0[:, 1] * duv1[:, 0]
            ok = det != 0
            dpdu = (duv1[:, 1, None] * dp0 - duv0[:, 1, None] * dp1) / np.where(ok, det, 1.0)[:, None]
            dpdv = (duv0[:, 0, None] * dp1 - duv1[:, 0, None] * dp0) / np.where(ok, det, 1.0)[:, None]
            s, t = coordinate_system_rows(self.normals()[tri], both=True)
            out[tri], out_v[tri] = np.where(ok[:, None], dpdu, s), np.where(ok[:, None], dpdv, t)
        self.tangents, self.cotangents = row_table(out), row_table(out_v)

    def attribute_table(self, names: set[str]) -> AttributeTable:
        """The meshes' attributes `names` per triangle: a face attribute's value, a vertex attribute's at
        each corner; a name's channels are the most any mesh gives it (a mesh of one channel repeated)."""
        blocks, layout, offset = [], {}, 0
        for name in sorted(names):
            have = [m.attributes.values[name] for m in self.shapes if m.attributes and name in m.attributes.values]
            channels = max((a.shape[1] for a in have), default=1)
            per_vertex = name.startswith("vertex_")
            block = np.zeros((max(self.count, 1), 3 if per_vertex else 1, channels), np.float32)
            for m, lo, n in self.shape_primitives():
                a = m.attributes.values.get(name) if m.attributes else None
                if a is not None:
                    block[lo - self.base:lo - self.base + n] = (a[m.faces] if per_vertex else a[:, None])
            blocks.append(block.ravel())
            layout[name] = (offset, channels, per_vertex)
            offset += block.size
        return AttributeTable(Float(np.concatenate(blocks)), layout, self.first, self.size)

    def tangent(self, prim, valid, p, b1, b2, dpdu):
        if not self.count:
            return dpdu
        tri, is_tri = self._triangle(prim, valid)
        return dr.select(is_tri, gather_vec3(self.tangents, tri, is_tri), dpdu)

    def cotangent(self, prim, valid, dpdv):
        """Mitsuba's dp/dv (true length) where prim is a triangle (`dpdv` elsewhere); built by build_tangents."""
        if not self.count:
            return dpdv
        tri, is_tri = self._triangle(prim, valid)
        return dr.select(is_tri, gather_vec3(self.cotangents, tri, is_tri), dpdv)

    def frames(self) -> np.ndarray:
        return self._frames_normals[0]

    def culling_planes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        if self.bvh is not None:   # BVH triangles are all tested; only the unrolled ones are worth culling
            return []
        return [(self.base + j, v[0], n) for j, (v, n) in enumerate(zip(self.tri_vertices, self.normals()))]

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return (self._corners - p0) @ n

    def side_bounds(self, p0: np.ndarray, n: np.ndarray) -> tuple[float, float]:
        """Bounds on sides(p0, n) from the vertices' bounding box, without computing them: widened by far more
        than sides' rounding error (a few ulp of the terms' magnitudes), so decisions on them are sides' own."""
        d = (self._box - p0) * n                   # each coordinate's extreme terms
        margin = 1e-12 * np.abs(d).max(0).sum()
        return d.min(0).sum() - margin, d.max(0).sum() + margin

    @cached_property
    def _box(self) -> np.ndarray:
        """(2, 3) least and greatest coordinates of the meshes' vertices."""
        return bounding_box([m.vertices for m in self.shapes])

    def describe(self) -> str:
        return f"{self.count} triangles (Moeller-Trumbore, {'in a BVH' if self.bvh is not None else 'brute force'})"

    # ---- kernel side -------------------------------------------------------------------------------
    def candidates(self, o, d, t_min, skip, target, only):
        skip, target = self.local_ends(skip, target)
        for j in range(self.count if self.bvh is None else 0):
            if only is not None and self.base + j not in only:
                continue
            t, b1, b2 = ray_triangle(o, d, *self._constants(j), t_min, INF)
            yield self.prim(j), exclude(t, j, skip, target), b1, b2

    def _constants(self, j: int) -> tuple[Array3f, Array3f, Array3f]:
        """Triangle j's first corner and two edges, as literals: read from memory (jit.opaque_vec3), the Cornell
        box's 24 block triangles made its render take 1.16x the CPU time (600 x 600, 16 spp, median of 8,
        interleaved, load 3.2-3.8; 1.06x with literals), so a scene whose small meshes differ compiles anew;
        their primitive numbers stay run-time constants (first + j)."""
        v = self.tri_vertices[j]
        return vec3(v[0]), vec3(v[1] - v[0]), vec3(v[2] - v[0])

    def _triangle(self, prim: UInt32, valid: Bool) -> tuple[UInt32, Bool]:
        tri = self.local(prim)
        return tri, valid & (prim >= self.first) & (tri < self.size)

    def shading_normal(self, prim: UInt32, b1: Float, b2: Float, n: Array3f) -> Array3f:
        """The normal interpolated from the corners where prim is a triangle of a smooth mesh (n elsewhere)."""
        if not self.smooth:
            return n
        tri, is_tri = self._triangle(prim, True)
        b0 = 1.0 - b1 - b2
        interp = (gather_vec3(self.corner_normals, tri * 3, is_tri) * b0
                  + gather_vec3(self.corner_normals, tri * 3 + 1, is_tri) * b1
                  + gather_vec3(self.corner_normals, tri * 3 + 2, is_tri) * b2)
        return dr.select(is_tri, dr.normalize(interp), n)

    def uv(self, prim, valid, p, b1, b2, uv):
        """Texture coordinates interpolated from the corners where prim is a triangle (`uv` elsewhere)."""
        if not self.count:
            return uv
        u, v = uv
        tri, is_tri = self._triangle(prim, valid)
        b0 = 1.0 - b1 - b2
        c = gather_row(self.corner_uvs, 8, tri, is_tri, 6)
        return (dr.select(is_tri, c[0] * b0 + c[2] * b1 + c[4] * b2, u),
                dr.select(is_tri, c[1] * b0 + c[3] * b1 + c[5] * b2, v))

    def _emitter_table(self, m: Mesh) -> tuple[GuidedCDF, Float]:
        """An emitting mesh's cumulative triangle areas (normalised) and its triangles' corners, built on its
        first light sample and kept: every bounce of every launch samples it."""
        if id(m) not in self._emitter_tables:
            areas = m.triangle_areas
            # a mesh of no area emits nothing (its samples' density is infinite): any points will do
            cdf = np.cumsum(areas) / m.area if m.area > 0 else np.arange(1, len(areas) + 1) / len(areas)
            self._emitter_tables[id(m)] = GuidedCDF(cdf), row_table(m.vertices[m.faces])
        return self._emitter_tables[id(m)]

    def sample(self, m: Mesh, lo: int, u1: Float, u2: Float, geo) -> tuple[Array3f, Array3f, UInt32]:
        """A triangle chosen by area, then a point uniform on it (u1 reused: rescaled within the chosen
        triangle's share); the normal is the shading normal on smooth meshes."""
        cdf, corners = self._emitter_table(m)
        tri, u1 = cdf.sample(u1)
        b1, b2 = square_to_uniform_triangle(u1, u2)
        prim = self.prim(lo - self.base) + tri
        v = [gather_vec3(corners, tri * 3 + c) for c in range(3)]
        y = v[0] * (1.0 - b1 - b2) + v[1] * b1 + v[2] * b2
        n = geo.shading_row(prim)[0]
        if m.normals is not None:
            cn = [gather_vec3(self.corner_normals, (prim - self.base) * 3 + c) for c in range(3)]
            n = dr.normalize(cn[0] * (1.0 - b1 - b2) + cn[1] * b1 + cn[2] * b2)
        return y, n, prim


@dataclass(eq=False)
class AttributeTable:
    """The meshes' attributes (MeshSet.attribute_table) as the kernel reads them: `layout` gives each name's
    offset in `values`, its channels and whether it is a vertex attribute (3 corners per triangle)."""

    values: Float
    layout: dict[str, tuple[int, int, bool]]
    base: UInt32            # the meshes' first primitive and triangle count
    count: UInt32

    def eval(self, row: list[Float], hit: tuple[UInt32, Float, Float], active: Bool) -> Array3f:
        """The attribute of a texture row (offset, channels, per vertex, scale) at `hit` (a primitive and its
        barycentric b1, b2): a vertex attribute's corners v0, v1, v2 weighted by b0 = 1 - b1 - b2, b1, b2, a
        face attribute's one value, times the scale; a one-channel attribute in all three channels."""
        prim, b1, b2 = hit
        tri = prim - self.base
        active = active & (prim >= self.base) & (tri < self.count)
        offset, channels, per_vertex, scale = UInt32(row[0]), UInt32(row[1]), row[2] > 0, row[3]
        channel = [dr.minimum(UInt32(k), channels - 1) for k in range(3)]

        def corner(first: UInt32, on: Bool) -> Array3f:
            return Array3f(*(dr.gather(Float, self.values, first + c, on) for c in channel))

        face = corner(offset + tri * channels, active & ~per_vertex)
        v0, v1, v2 = (corner(offset + (tri * 3 + k) * channels, active & per_vertex) for k in range(3))
        vertex = dr.fma(v0, 1.0 - b1 - b2, dr.fma(v1, b1, v2 * b2))
        return dr.select(active, dr.select(per_vertex, vertex, face) * scale, Array3f(0.0))


def coordinate_system_rows(n: np.ndarray, both: bool = False):
    """(rows, 3) the first tangent of sampling.coordinate_system (Duff et al. 2017) for unit normals n (and
    the second, where `both`)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0]], axis=1)
    return (s, np.stack([b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], axis=1)) if both else s
