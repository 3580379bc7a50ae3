"""`{scene_json}`: a planned scene as neutral data, for a renderer that does not read Mitsuba's XML.

The scene is the one the tracer's loader reads (tracer.load_scene), so every refusal of the loader comes
first, in one line. Written into a folder:

    scene.json        {"format": FORMAT, "camera", "film", "integrator", "materials", "shapes", "emitters"}
    shapes/NNN.ply    each shape as a world-space triangle mesh (binary PLY: x y z [nx ny nz] [u v];
                      vertex_indices), wound so that (v1 - v0) x (v2 - v0) is Mitsuba's front side; a PLY
                      mesh's attributes (a `mesh_attribute` texture's values) as properties NAME_0, NAME_1,
                      NAME_2 of the vertices (attribute vertex_NAME) or faces (face_NAME), which Mitsuba's
                      `ply` reads back under the same names

Conventions (Mitsuba's, which the check compares against):
- camera: `to_world` (4 x 4, row-major) maps camera space (looking down +z, up +y, x to the image's LEFT, as
  Mitsuba's perspective sensor) to world space; `tan_half_fov` [x, y] is the field of view already resolved
  for the film's aspect (fov and fov_axis are also given); an `orthographic` camera has to_world only (its
  scale sizes the view, as Mitsuba's);
- film: width, height, and the reconstruction filter (box radius 0.5 px, tent radius, gaussian stddev,
  cut off at 4 stddev and shifted to zero there);
- integrator: Mitsuba's `path`; max_depth counts path vertices (1: emitters seen directly; -1: unbounded);
- surfaces and area emitters are one-sided unless the material is `twosided`: an area emitter radiates
  `radiance` (W m^-2 sr^-1, linear RGB) from its front side only;
- materials carry the loader's fields (tracer.materials.BSDF) under Mitsuba's names (a conductor's tint is its
  `specular_reflectance`), textures as EXR files beside the JSON.

Curved shapes are tessellated: a sphere into TESSELLATION x TESSELLATION / 2 quads, a cylinder and a disk
into TESSELLATION segments, the vertices placed so that the mesh's area equals the shape's (their
analytic description is given too, under "analytic"). The silhouette then lies within
1 - cos(pi / TESSELLATION) = 3e-4 of the radius of the true one.
"""
from __future__ import annotations

import json
from dataclasses import fields, is_dataclass
from pathlib import Path

import numpy as np

FORMAT = "validate-scene 1"
CONDUCTORS = ("conductor", "roughconductor")
TESSELLATION = 128


def write(scene_plan, folder: Path) -> Path:
    """The planned scene as scene.json and PLY files in `folder`; returns the JSON's path."""
    from tracer.lights import ConstantEnvironment, DirectionalLight, EnvironmentMap, PointLight

    scene = scene_plan.tracer_scene()
    folder = Path(folder)
    (folder / "shapes").mkdir(parents=True, exist_ok=True)
    writer = _Writer(folder)
    materials: list = []
    shapes = []
    for i, shape in enumerate(scene.shapes + [m for g in scene.groups for m in g.copies()]):   # instances expanded
        kind, analytic, (v, f, n, uv) = _triangles(shape)
        mesh = f"shapes/{i:03d}.ply"
        _write_ply(folder / mesh, v, f, n, uv, getattr(shape, "attributes", None))
        if shape.bsdf not in materials:
            materials.append(shape.bsdf)
        shapes.append({"name": shape.name, "type": kind, "mesh": mesh, "triangles": int(len(f)),
                       "material": materials.index(shape.bsdf), "analytic": analytic,
                       "emitter": None if shape.radiance is None else {"type": "area", "radiance": _list(shape.radiance)}})
    emitters = []
    for light in scene.lights:
        if isinstance(light, PointLight):
            if light.varies:         # described by its kind only: a renderer refuses it by its type
                emitters.append({"type": "textured_point", "name": light.name, "position": _list(light.position),
                                 "note": "a projector or a textured spot: its texture is not described"})
                continue
            e = {"type": "point" if light.spot is None else "spot", "position": _list(light.position),
                 "intensity": _list(light.intensity)}
            if light.spot is not None:
                axis, cutoff, beam = light.spot
                e |= {"direction": _list(axis), "cutoff_angle": float(cutoff), "beam_width": float(beam)}
        elif isinstance(light, DirectionalLight):
            e = {"type": "directional", "direction": _list(light.direction), "irradiance": _list(light.irradiance)}
        elif isinstance(light, ConstantEnvironment):
            e = {"type": "constant", "radiance": _list(light.radiance)}
        elif isinstance(light, EnvironmentMap):
            e = {"type": "envmap", "image": writer.image(light.image), "to_world": _list(light.to_world)}
        else:
            raise TypeError(f"scene_json: no description for the emitter {type(light).__name__}")
        emitters.append(e | {"name": light.name})
    cam = scene.camera
    camera = {"type": cam.projection, "to_world": _list(cam.to_world), "near_clip": cam.near_clip,
              "far_clip": cam.far_clip, "aperture_radius": cam.aperture_radius,   # > 0: Mitsuba's thinlens
              "focus_distance": cam.focus_distance}
    if cam.projection == "perspective":
        camera |= {"fov": cam.fov, "fov_axis": cam.fov_axis, "tan_half_fov": _list(cam.tan_half_fov())}
    data = {"format": FORMAT, "source": str(scene_plan.path.resolve()), "camera": camera,
            "film": {"width": scene_plan.width, "height": scene_plan.height,
                     "filter": _filter(cam.rfilter)},
            "integrator": {"type": "volpath" if scene.volumetric else "path", "max_depth": scene_plan.max_depth,
                           "rr_depth": scene.rr_depth},
            "materials": [writer.value(m) for m in materials], "shapes": shapes, "emitters": emitters}
    path = folder / "scene.json"
    path.write_text(json.dumps(data, indent=1))
    return path


def _filter(f) -> dict:
    if f.kind == "gaussian":
        return {"type": "gaussian", "stddev": f.stddev, "radius": f.radius}
    return {"type": f.kind, "radius": f.radius}


class _Writer:
    """Materials as JSON values: dataclasses as objects (with their type), images as EXR files."""

    def __init__(self, folder: Path):
        self.folder, self.images = folder, 0

    def image(self, array: np.ndarray) -> str:
        from tracer.imageio import write_exr

        name = f"textures/{self.images:03d}.exr"
        (self.folder / "textures").mkdir(exist_ok=True)
        write_exr(self.folder / name, np.asarray(array, dtype=np.float32))
        self.images += 1
        return name

    def value(self, x):
        if is_dataclass(x):
            out = {"type": getattr(x, "kind", type(x).__name__.lower())}
            for f in fields(x):
                if f.name != "kind":
                    out[f.name] = self.image(getattr(x, f.name)) if f.name == "image" else self.value(getattr(x, f.name))
            if out["type"] in CONDUCTORS:       # the loader keeps a conductor's specular_reflectance in `reflectance`
                out["specular_reflectance"] = out.pop("reflectance")
            return out
        if isinstance(x, (tuple, list, np.ndarray)):
            return [self.value(v) for v in x]
        if isinstance(x, (np.floating, np.integer)):
            return x.item()
        return x


def _list(x) -> list:
    return np.asarray(x, dtype=float).tolist()


def _triangles(shape) -> tuple[str, dict | None, tuple]:
    """(type, analytic description, (vertices, faces, normals or None, uvs or None)) of a tracer shape."""
    from tracer.shapes import Cylinder, Mesh, Rectangle, Sphere

    if isinstance(shape, Mesh):
        return "mesh", None, (shape.vertices, shape.faces, shape.normals, shape.uvs)
    if isinstance(shape, Rectangle) and not shape.disk:
        local = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
        v = _apply(shape.to_world, local)
        return "rectangle", {"to_world": _list(shape.to_world)}, _front(v, np.array([[0, 1, 2], [0, 2, 3]]), None,
                                                                       uv, shape.normal)
    if isinstance(shape, Rectangle):
        n = TESSELLATION
        phi = 2 * np.pi * np.arange(n) / n
        r = np.sqrt(2 * np.pi / (n * np.sin(2 * np.pi / n)))        # the n-gon's area equals the disk's
        local = np.concatenate([[[0, 0, 0]], np.stack([r * np.cos(phi), r * np.sin(phi), 0 * phi], 1)])
        faces = np.stack([np.zeros(n, int), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n], 1)
        return "disk", {"to_world": _list(shape.to_world)}, _front(_apply(shape.to_world, local), faces, None, None,
                                                                   shape.normal)
    if isinstance(shape, Sphere):
        v, f, n = _sphere(shape.center, shape.radius, shape.frame)
        return "sphere", {"center": _list(shape.center), "radius": float(shape.radius)}, (v, f, n, None)
    if isinstance(shape, Cylinder):
        m = TESSELLATION
        phi = 2 * np.pi * np.arange(m) / m
        ring = np.stack([np.cos(phi), np.sin(phi), 0 * phi], 1)
        r = (np.pi / m) / np.sin(np.pi / m)              # the prism's side area equals the tube's
        local = np.concatenate([ring * r, ring * r + [0, 0, 1]])
        i, j = np.arange(m), (np.arange(m) + 1) % m
        faces = np.concatenate([np.stack([i, j, m + j], 1), np.stack([i, m + j, m + i], 1)])
        normals = np.tile(_apply_normal(shape.to_world, ring), (2, 1)) * (-1 if shape.flipped else 1)
        return "cylinder", {"to_world": _list(shape.to_world), "flipped": shape.flipped}, \
            _front(_apply(shape.to_world, local), faces, normals, None, None)
    raise TypeError(f"scene_json: no tessellation for the shape {type(shape).__name__}")


def _sphere(center, radius, frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A UV sphere of TESSELLATION segments and TESSELLATION / 2 rings, its area equal to the sphere's."""
    m, k = TESSELLATION, TESSELLATION // 2
    theta = np.pi * np.arange(k + 1) / k
    phi = 2 * np.pi * np.arange(m) / m
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3) @ frame.T
    idx = np.arange((k + 1) * m).reshape(k + 1, m)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, e = idx[1:], np.roll(idx[1:], -1, axis=1)
    faces = np.concatenate([np.stack([a, c, e], -1).reshape(-1, 3), np.stack([a, e, b], -1).reshape(-1, 3)])
    v = d * radius
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    faces = faces[area > 1e-12 * radius * radius]                      # the poles' empty triangles
    v = v * np.sqrt(4 * np.pi * radius ** 2 / area.sum())
    return _front(v + center, faces, d, None, None)[:3]


def _front(v, faces, normals, uv, normal) -> tuple:
    """Faces wound so that their geometric normal agrees with `normal` (or, where None, the vertex normals)."""
    tri = v[faces]
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ref = np.broadcast_to(normal, ng.shape) if normal is not None else normals[faces].sum(1)
    flip = np.einsum("ij,ij->i", ng, ref) < 0
    faces = np.where(flip[:, None], faces[:, ::-1], faces)
    return v, faces, normals, uv


def _apply(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


def _apply_normal(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    out = n @ np.linalg.inv(m[:3, :3])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _write_ply(path: Path, v, faces, normals, uv, attributes=None) -> None:
    """`attributes`: a PLY mesh's (tracer.ply_attributes.Attributes), those of 1 or 3 channels written."""
    from plyfile import PlyData, PlyElement

    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else []) + (["u", "v"] if uv is not None else [])
    columns = [np.asarray(v, np.float32)] + [np.asarray(a, np.float32) for a in (normals, uv) if a is not None]
    extra = {"vertex_": [], "face_": []}
    for name, values in (attributes.values.items() if attributes is not None else ()):
        kind = "vertex_" if name.startswith("vertex_") else "face_"
        if values.shape[1] in (1, 3):
            extra[kind] += [(f"{name[len(kind):]}_{k}", values[:, k]) for k in range(values.shape[1])]
    table = np.concatenate(columns, axis=1)
    vertex = np.empty(len(table), dtype=[(name, "f4") for name in names + [n for n, _ in extra["vertex_"]]])
    for i, name in enumerate(names):
        vertex[name] = table[:, i]
    face = np.empty(len(faces), dtype=[("vertex_indices", "u4", (3,))] + [(n, "f4") for n, _ in extra["face_"]])
    face["vertex_indices"] = np.asarray(faces, np.uint32)
    for element, kind in ((vertex, "vertex_"), (face, "face_")):
        for name, column in extra[kind]:
            element[name] = column
    PlyData([PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]).write(str(path))
