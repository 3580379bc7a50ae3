"""Blender's Cycles (the `bpy` module) rendering a `{scene_json}` scene as an estimate of Mitsuba's `path`:
runs in the peers' Python, never in the project's (bpy needs NumPy 1.x).

    python cycles_worker.py SCENE.json --spp N --seeds S1,S2,... --outputs A.exr,B.exr,... [--mistake NAME]

The mapping (GUIDE, README "Peers"):
- bounces: Cycles counts the bounces after the first hit, so Mitsuba's max_depth d is Cycles' limit d - 2
  (0: direct light only) on every kind of bounce; max_depth -1: 1024; max_depth 1 cannot be expressed;
- samples: `spp` per pass, the seed per pass, tabulated Sobol (scrambled by the seed: the check tests the
  passes' independence), no adaptive sampling, no denoising, no clamping, light
  threshold 0, glossy filter 0, caustics on;
- pixel filter: box of 1 px (Mitsuba's box, radius 1/2); Mitsuba's gaussian (stddev s, cut at 4 s) as Cycles'
  gaussian of width 4 s (Cycles' filter table triples a gaussian's width w before exp(-2 (6 x / 3 w)^2): stddev
  w / 4, cut at 1.5 w = 6 s; the closest Cycles has);
- one-sided surfaces and emitters: the Backfacing output selects black (and no emission) behind reflection-
  only materials that are not two-sided; emission sampling from the front only;
- materials: diffuse as Diffuse BSDF (roughness 0, Lambert), a perfect-mirror conductor as a Glossy BSDF of
  roughness 0 and colour 1, other conductors as the Metallic BSDF (physical conductor, IOR eta, extinction k,
  roughness 0), dielectric as the Glass BSDF (roughness 0, IOR int_ior / ext_ior);
- camera: Mitsuba's camera looks down +z with x to the image's left, Blender's down -z with x right: the
  to_world matrix times diag(-1, 1, -1); the horizontal field of view from tan_half_fov;
- output: linear float EXR.
"""
from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np

from support import mirror, one_sided, read_mesh, worker_arguments


def main() -> None:
    args, data = worker_arguments("cycles")
    scene = build(data, args.scene.parent, args.spp, args.mistake)
    for seed, output in zip(args.seeds.split(","), args.outputs.split(",")):
        scene.cycles.seed = int(seed)
        scene.render.filepath = output
        bpy.ops.render.render(write_still=True)


def build(data: dict, folder: Path, spp: int, mistake: str | None):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    import addon_utils

    addon_utils.enable("cycles", default_set=True)
    scene = bpy.context.scene
    _settings(scene, data, spp, mistake)
    _camera(scene, data, mistake)
    _world(scene, data)
    materials = [_material(i, m) for i, m in enumerate(data["materials"])]
    for i, shape in enumerate(data["shapes"]):
        _shape(scene, i, shape, folder, materials, data["materials"][shape["material"]], mistake)
    return scene


def _settings(scene, data: dict, spp: int, mistake: str | None) -> None:
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = spp
    cy.sampling_pattern = "TABULATED_SOBOL"
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.light_sampling_threshold = 0.0
    cy.blur_glossy = 0.0
    cy.caustics_reflective = cy.caustics_refractive = True
    depth = data["integrator"]["max_depth"]
    bounces = 1024 if depth < 0 else depth - 2 + (mistake == "extra-bounce")
    cy.max_bounces = cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = bounces
    cy.transparent_max_bounces = bounces
    cy.volume_bounces = 0
    f = data["film"]["filter"]
    if mistake == "default-filter":
        cy.pixel_filter_type, cy.filter_width = "BLACKMAN_HARRIS", 1.5
    elif f["type"] == "gaussian":
        cy.pixel_filter_type, cy.filter_width = "GAUSSIAN", 4 * f["stddev"]
    else:
        cy.pixel_filter_type, cy.filter_width = "BOX", 1.0
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = data["film"]["width"], data["film"]["height"], 100
    r.film_transparent = False
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.color_mode = "RGB"
    scene.view_settings.view_transform = "Raw"        # EXR holds scene-linear values; no view transform


def _camera(scene, data: dict, mistake: str | None) -> None:
    c = data["camera"]
    cam = bpy.data.cameras.new("camera")
    tx, _ = c["tan_half_fov"]
    if mistake == "wide-fov":
        tx = math.tan(1.01 * math.atan(tx))
    cam.sensor_fit = "HORIZONTAL"
    cam.angle = 2 * math.atan(tx)
    cam.clip_start, cam.clip_end = c["near_clip"], c["far_clip"]
    obj = bpy.data.objects.new("camera", cam)
    obj.matrix_world = _matrix(np.array(c["to_world"]) @ np.diag([-1.0, 1.0, -1.0, 1.0]))
    scene.collection.objects.link(obj)
    scene.camera = obj


def _matrix(m: np.ndarray):
    from mathutils import Matrix

    return Matrix([list(row) for row in m])


def _world(scene, data: dict) -> None:
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    radiance = next((e["radiance"] for e in data["emitters"] if e["type"] == "constant"), [0.0, 0.0, 0.0])
    background.inputs["Color"].default_value = (*radiance, 1.0)
    background.inputs["Strength"].default_value = 1.0
    scene.world = world


def _material(i: int, m: dict):
    """The material's surface shader (without emission; an emitting shape gets its own copy)."""
    mat = bpy.data.materials.new(f"material{i}")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    if m["type"] == "diffuse":
        bsdf = nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Color"].default_value = (*m["reflectance"], 1.0)
        bsdf.inputs["Roughness"].default_value = 0.0
    elif m["type"] == "conductor" and mirror(m):
        bsdf = nodes.new("ShaderNodeBsdfGlossy")
        bsdf.distribution = "GGX"
        bsdf.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.0
    elif m["type"] == "conductor":
        bsdf = nodes.new("ShaderNodeBsdfMetallic")
        bsdf.fresnel_type = "PHYSICAL_CONDUCTOR"
        bsdf.distribution = "GGX"
        bsdf.inputs["IOR"].default_value = m["eta"]
        bsdf.inputs["Extinction"].default_value = m["k"]
        bsdf.inputs["Roughness"].default_value = 0.0
    else:
        bsdf = nodes.new("ShaderNodeBsdfGlass")
        bsdf.distribution = "GGX"
        bsdf.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        bsdf.inputs["IOR"].default_value = m["int_ior"] / m["ext_ior"]
        bsdf.inputs["Roughness"].default_value = 0.0
    bsdf.name = "surface"
    mat.node_tree.links.new(bsdf.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def _shape(scene, i: int, shape: dict, folder: Path, materials: list, m: dict, mistake: str | None) -> None:
    vertices, faces, normals = read_mesh(folder / shape["mesh"])
    mesh = bpy.data.meshes.new(f"shape{i}")
    mesh.from_pydata(vertices.tolist(), [], faces.tolist())
    mesh.update()
    if normals is not None:
        mesh.shade_smooth()
        mesh.normals_split_custom_set_from_vertices([tuple(n) for n in normals])
    mat = materials[shape["material"]]
    emitter = shape["emitter"]
    if emitter is not None or one_sided(m):
        mat = _sided(mat.copy(), m, emitter, mistake)
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(f"shape{i}", mesh)
    scene.collection.objects.link(obj)


def _sided(mat, m: dict, emitter: dict | None, mistake: str | None):
    """The front: the surface plus the emitter's radiance; the back: black where Mitsuba's material is one-sided
    (else the surface), and no emission (unless the injected two-sided light)."""
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    front = nodes["surface"].outputs[0]
    back = front
    if one_sided(m):
        black = nodes.new("ShaderNodeBsdfDiffuse")
        black.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        back = black.outputs[0]
    if emitter is not None:
        emission = nodes.new("ShaderNodeEmission")
        scale = 0.98 if mistake == "dim-emission" else 1.0
        emission.inputs["Color"].default_value = (*[scale * x for x in emitter["radiance"]], 1.0)
        emission.inputs["Strength"].default_value = 1.0
        add = nodes.new("ShaderNodeAddShader")
        links.new(front, add.inputs[0])
        links.new(emission.outputs[0], add.inputs[1])
        front = add.outputs[0]
        if mistake == "twosided-light":
            add_back = nodes.new("ShaderNodeAddShader")
            links.new(back, add_back.inputs[0])
            links.new(emission.outputs[0], add_back.inputs[1])
            back = add_back.outputs[0]
        mat.cycles.emission_sampling = "FRONT_BACK" if mistake == "twosided-light" else "FRONT"
    mix = nodes.new("ShaderNodeMixShader")
    links.new(nodes.new("ShaderNodeNewGeometry").outputs["Backfacing"], mix.inputs["Fac"])
    links.new(front, mix.inputs[1])
    links.new(back, mix.inputs[2])
    links.new(mix.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


if __name__ == "__main__":
    main()
