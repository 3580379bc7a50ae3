"""What the peers can express of a `{scene_json}` scene (validation.verdict.scenejson), and the conversion mistakes the
peers report injects. Plain Python: imported by the check (the project's Python) and by each peer's worker,
which runs in the peers' own Python (README "Peers")."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

MISTAKES = {   # name: what the adapter then does wrong (reports/peers.md shows each caught)
    "extra-bounce": "one bounce more than max_depth allows",
    "twosided-light": "area lights emit from both sides",
    "default-filter": "the peer's default pixel filter instead of the closest to the scene's",
    "dim-emission": "emitted radiance 2% too low",
    "wide-fov": "the field of view 1% wider",
}


def refusal(data: dict, peer: str) -> str | None:
    """The first thing in the scene `peer` ('cycles' or 'luxcore') cannot express as Mitsuba has it, in one
    line; None if it can express all of it."""
    if data["camera"]["type"] != "perspective":
        return f"the {data['camera']['type']} camera: the adapter converts the perspective camera only"
    if data["camera"]["aperture_radius"] > 0:
        return "the thinlens camera (a lens aperture): the adapter converts the pinhole camera only"
    if data["integrator"]["type"] != "path":
        return f"the {data['integrator']['type']} integrator: the adapter estimates Mitsuba's path only"
    depth = data["integrator"]["max_depth"]
    if depth == 1:
        return f"max_depth 1 (emitters seen directly, no lighting): {peer}'s bounce limits start at direct lighting"
    rfilter = data["film"]["filter"]["type"]
    if rfilter == "tent":
        return f"the tent reconstruction filter: {peer} has box, gaussian and Blackman-Harris filters only"
    for e in data["emitters"]:
        if e["type"] != "constant":
            return (f"the '{e['type']}' emitter: the adapter converts area emitters and the constant environment "
                    "only")
    for i, m in enumerate(data["materials"]):
        why = _material(m, peer)
        if why:
            return f"material {i} ('{m['type']}'): {why}"
    return None


def _material(m: dict, peer: str) -> str | None:
    if m["type"] not in ("diffuse", "conductor", "dielectric"):
        return "the adapter converts diffuse, conductor and dielectric materials only"
    if m["texture"] is not None or m["normalmap"] is not None:
        return "textures and normal maps are not converted"
    if m["opacity"] != 1 or m["blend"] is not None:
        return "mask and blendbsdf are not converted"
    if m["twosided"] and m["back"] is not None:
        return "a two-sided material with a different back is not converted"
    if m["type"] == "conductor" and m["specular_reflectance"] != [1.0, 1.0, 1.0]:
        return "a conductor's specular_reflectance other than 1 has no counterpart"
    if m["type"] == "conductor" and peer == "luxcore" and not mirror(m):
        return ("a conductor other than a perfect mirror: LuxCore's conductor Fresnel term (FresnelTexture::"
                "GeneralEvaluate, behind metal2 with a fresnelconst texture) is an approximation, up to 16% brighter "
                "than the exact one for gold (reports/peers.md)")
    if m["type"] == "dielectric" and (m["specular_reflectance"] != [1.0, 1.0, 1.0]
                                      or m["specular_transmittance"] != [1.0, 1.0, 1.0]):
        return "a dielectric's specular_reflectance or specular_transmittance other than 1 has no counterpart"
    return None


def mirror(m: dict) -> bool:
    """A conductor whose Fresnel reflectance is 1 at every angle (eta 0, k 1: Mitsuba's material 'none')."""
    return m["eta"] == [0.0, 0.0, 0.0] and m["k"] == [1.0, 1.0, 1.0]


def one_sided(m: dict) -> bool:
    """Black seen from behind, as Mitsuba's reflection-only materials unless two-sided."""
    return m["type"] != "dielectric" and not m["twosided"]


def read_mesh(path) -> tuple:
    """(vertices (n, 3), faces (m, 3), normals (n, 3) or None) of a scene_json PLY file."""
    import numpy as np
    from plyfile import PlyData

    ply = PlyData.read(str(path))
    v = ply["vertex"]
    vertices = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    normals = (np.stack([v["nx"], v["ny"], v["nz"]], 1).astype(np.float64)
               if "nx" in v.data.dtype.names else None)
    faces = np.stack(ply["face"]["vertex_indices"]).astype(np.int64)
    return vertices, faces, normals


def worker_arguments(peer: str) -> tuple[argparse.Namespace, dict]:
    """A peer worker's command line (scene.json, --spp, --seeds and --outputs as comma lists, --mistake) and its
    scene; exits 77 (the check's "unsupported") with the refusal on stderr where `peer` cannot express it."""
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", type=Path)
    ap.add_argument("--spp", type=int, required=True)
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--outputs", required=True)
    ap.add_argument("--mistake", choices=sorted(MISTAKES))
    args = ap.parse_args()
    data = json.loads(args.scene.read_text())
    why = refusal(data, peer)
    if why:
        print(f"{peer}: {why}", file=sys.stderr)
        sys.exit(77)
    return args, data
