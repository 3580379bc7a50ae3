"""LuxCoreRender (the `pyluxcore` module) rendering a `{scene_json}` scene as an estimate of Mitsuba's `path`:
runs in the peers' Python.

    python luxcore_worker.py SCENE.json --spp N --seeds S1,S2,... --outputs A.exr,B.exr,... [--mistake NAME]

The mapping (README "Peers"):
- depth: LuxCore's path.pathdepth.total counts the vertices after the camera's, as Mitsuba's max_depth less
  one (1: direct light only); diffuse, glossy and specular depths the same; max_depth -1: 1024;
- samples: PATHCPU with the RANDOM (independent) sampler, renderengine.seed per pass, batch.haltspp = spp, no
  variance clamping, no denoiser (the RGB film output, before any image pipeline);
- pixel filter: box of radius 0.5 px (Mitsuba's box); Mitsuba's gaussian (stddev s, radius 4 s, shifted to
  zero there) is LuxCore's gaussian of width 4 s and alpha 1 / (2 s^2), the same function;
- one-sided surfaces: a `twosided` LuxCore material with a black matte behind reflection-only materials that
  are not two-sided; area lights emit from the front only (LuxCore's own convention, emission.theta 90);
- materials: matte (diffuse), mirror (a perfect-mirror conductor), glass (int_ior / ext_ior); other conductors
  are refused (support.refusal: LuxCore evaluates a conductor's Fresnel term, in metal2 and in its fresnel
  textures, by an approximation that departs from the exact complex Fresnel equations where eta < 1; metal2 at
  roughness 0 renders exactly that approximation; reports/peers.md);
- camera: LuxCore's lookat camera with a field of view of 90 degrees and the screen window [-tx, tx, -ty, ty]
  of tan_half_fov, so that the image's extent is Mitsuba's whatever LuxCore's own fov convention;
- output: the RGB film output saved as a linear float EXR.
"""
from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import pyluxcore

from support import one_sided, read_mesh, worker_arguments

# pyluxcore 2.11.2's RGB film output shows the image one row lower than its camera's screen window says (on the
# Cornell box at 32 x 32: output row r + 1 equals Mitsuba's row r to within noise, 0.0009 mean absolute
# difference against 0.023 unshifted); the window is moved by this many rows to compensate
ROW_SHIFT = -1


def main() -> None:
    args, data = worker_arguments("luxcore")
    pyluxcore.Init(_quiet)
    scene = pyluxcore.Scene()
    scene.Parse(scene_properties(data, args.scene.parent, args.mistake))
    for seed, output in zip(args.seeds.split(","), args.outputs.split(",")):
        config = pyluxcore.RenderConfig(render_properties(data, args.spp, int(seed), args.mistake), scene)
        session = pyluxcore.RenderSession(config)
        session.Start()
        while not session.HasDone():          # WaitForDone blocks past batch.haltspp in this build
            time.sleep(0.05)
            session.UpdateStats()
        session.Stop()
        session.GetFilm().SaveOutput(output, pyluxcore.FilmOutputType.RGB, pyluxcore.Properties())
    sys.stdout.flush()
    os._exit(0)         # pyluxcore's log handler crashes the interpreter's finalization (Python 3.11)


def _quiet(message: str) -> None:
    pass


def render_properties(data: dict, spp: int, seed: int, mistake: str | None):
    depth = data["integrator"]["max_depth"]
    total = 1024 if depth < 0 else depth + (mistake == "extra-bounce")
    f = data["film"]["filter"]
    if mistake == "default-filter":
        rfilter = {"film.filter.type": "BLACKMANHARRIS", "film.filter.width": 1.5}
    elif f["type"] == "gaussian":
        rfilter = {"film.filter.type": "GAUSSIAN", "film.filter.width": 4 * f["stddev"],
                   "film.filter.gaussian.alpha": 1 / (2 * f["stddev"] ** 2)}
    else:
        rfilter = {"film.filter.type": "BOX", "film.filter.width": 0.5}
    values = {"renderengine.type": "PATHCPU", "sampler.type": "RANDOM", "renderengine.seed": seed,
              "batch.haltspp": spp, "batch.halttime": 0, "path.pathdepth.total": total,
              "path.pathdepth.diffuse": total, "path.pathdepth.glossy": total, "path.pathdepth.specular": total,
              "path.clamping.variance.maxvalue": 0.0, "path.forceblackbackground.enable": False,
              "film.width": data["film"]["width"], "film.height": data["film"]["height"],
              "film.outputs.0.type": "RGB", "film.outputs.0.filename": "rgb.exr",
              "film.imagepipelines.0.0.type": "NOP"} | rfilter
    return _properties(values)


def _properties(values: dict):
    props = pyluxcore.Properties()
    for key, value in values.items():
        props.Set(pyluxcore.Property(key, list(value) if isinstance(value, (list, tuple)) else [value]))
    return props


def scene_properties(data: dict, folder: Path, mistake: str | None):
    c = data["camera"]
    m = np.array(c["to_world"])
    origin, forward, up = m[:3, 3], m[:3, 2], m[:3, 1]
    tx, ty = c["tan_half_fov"]
    if mistake == "wide-fov":
        tx, ty = (math.tan(1.01 * math.atan(tx)), ty * math.tan(1.01 * math.atan(tx)) / tx)
    shift = ROW_SHIFT * 2 * ty / data["film"]["height"]
    values = {"scene.camera.type": "perspective", "scene.camera.lookat.orig": origin.tolist(),
              "scene.camera.lookat.target": (origin + forward).tolist(), "scene.camera.up": up.tolist(),
              "scene.camera.fieldofview": 90.0, "scene.camera.screenwindow": [-tx, tx, -ty + shift, ty + shift],
              "scene.camera.cliphither": c["near_clip"], "scene.camera.clipyon": c["far_clip"]}
    env = next((e["radiance"] for e in data["emitters"] if e["type"] == "constant"), None)
    if env is not None:
        values |= {"scene.lights.environment.type": "constantinfinite", "scene.lights.environment.color": env,
                   "scene.lights.environment.gain": [1.0, 1.0, 1.0]}
    values |= {"scene.materials.black.type": "matte", "scene.materials.black.kd": [0.0, 0.0, 0.0]}
    for i, shape in enumerate(data["shapes"]):
        material = data["materials"][shape["material"]]
        name = f"m{i}"
        values |= _material(name, material, shape["emitter"], mistake)
        values |= {f"scene.shapes.s{i}.type": "mesh", f"scene.shapes.s{i}.ply": str(folder / shape["mesh"]),
                   f"scene.objects.o{i}.shape": f"s{i}", f"scene.objects.o{i}.material": name}
        if shape["emitter"] is not None and mistake == "twosided-light":
            values |= _back_emitter(i, shape, folder)
    return _properties(values)


def _material(name: str, m: dict, emitter: dict | None, mistake: str | None) -> dict:
    p = f"scene.materials.{name}"
    surface = f"{name}_surface" if one_sided(m) else name
    s = f"scene.materials.{surface}"
    if m["type"] == "diffuse":
        out = {f"{s}.type": "matte", f"{s}.kd": m["reflectance"]}
    elif m["type"] == "conductor":          # a perfect mirror (support.refusal refuses the others)
        out = {f"{s}.type": "mirror", f"{s}.kr": [1.0, 1.0, 1.0]}
    else:
        out = {f"{s}.type": "glass", f"{s}.kr": [1.0, 1.0, 1.0], f"{s}.kt": [1.0, 1.0, 1.0],
               f"{s}.interiorior": m["int_ior"], f"{s}.exteriorior": m["ext_ior"]}
    if one_sided(m):
        out |= {f"{p}.type": "twosided", f"{p}.frontmaterial": surface, f"{p}.backmaterial": "black"}
    if emitter is not None:          # on the front material: LuxCore ignores a twosided wrapper's emission
        scale = 0.98 if mistake == "dim-emission" else 1.0
        out |= {f"{s}.emission": [scale * x for x in emitter["radiance"]], f"{s}.emission.gain": [1.0, 1.0, 1.0],
                f"{s}.emission.power": 0.0, f"{s}.emission.efficency": 0.0, f"{s}.emission.normalizebycolor": False}
    return out


def _back_emitter(i: int, shape: dict, folder: Path) -> dict:
    """The injected two-sided light: the emitter's triangles again, wound the other way, a hair behind."""
    from plyfile import PlyData, PlyElement

    vertices, faces, _ = read_mesh(folder / shape["mesh"])
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(0)
    offset = -1e-4 * normal / np.linalg.norm(normal) * np.ptp(vertices, 0).max()
    v = np.empty(len(vertices), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    for k, axis in enumerate("xyz"):
        v[axis] = vertices[:, k] + offset[k]
    f = np.empty(len(faces), [("vertex_indices", "i4", (3,))])
    f["vertex_indices"] = faces[:, ::-1]
    path = folder / f"back{i}.ply"
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")]).write(str(path))
    e = shape["emitter"]["radiance"]
    return {f"scene.materials.back{i}.type": "matte", f"scene.materials.back{i}.kd": [0.0, 0.0, 0.0],
            f"scene.materials.back{i}.emission": e, f"scene.materials.back{i}.emission.gain": [1.0, 1.0, 1.0],
            f"scene.materials.back{i}.emission.power": 0.0, f"scene.materials.back{i}.emission.efficency": 0.0,
            f"scene.materials.back{i}.emission.normalizebycolor": False,
            f"scene.shapes.back{i}.type": "mesh", f"scene.shapes.back{i}.ply": str(path),
            f"scene.objects.back{i}.shape": f"back{i}", f"scene.objects.back{i}.material": f"back{i}"}


if __name__ == "__main__":
    main()
