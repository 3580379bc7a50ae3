"""A multi-mesh scene of the project's own for `validate bench`: the Cornell box's walls and light around
three smooth meshes of mixed materials (a diffuse torus, a mirror (conductor) blob, a glass (dielectric)
ellipsoid), written as OBJ files and a Mitsuba XML scene that both renderers read.

Meshes are generated, never committed: `write_mesh_scene` writes them into a folder (the bench uses
.cache/bench) and reuses files it wrote before for the same triangle count.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "mitsuba_scenes" / "cornell_box.xml"
# (name, share of the triangles, BSDF XML, to_world XML)
MESHES = (
    ("torus", 0.4, '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.3, 0.7"/></bsdf>',
     '<rotate x="1" angle="60"/><translate x="-0.45" y="-0.75" z="0.0"/>'),
    ("blob", 0.4, '<bsdf type="conductor"><string name="material" value="none"/></bsdf>',
     '<scale value="0.33"/><translate x="0.4" y="-0.6" z="-0.3"/>'),
    ("ellipsoid", 0.2, '<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>',
     '<scale x="0.22" y="0.3" z="0.22"/><translate x="0.05" y="-0.7" z="0.5"/>'),
)


def grid_faces(rings: int, segments: int, closed_rings: bool) -> np.ndarray:
    """Triangles (2 per quad) of a (rings + 1 or rings) x segments vertex grid, wrapping around segments
    (and around rings where closed_rings)."""
    r, s = np.meshgrid(np.arange(rings), np.arange(segments), indexing="ij")
    rows = rings if closed_rings else rings + 1
    a, b = r * segments + s, r * segments + (s + 1) % segments
    c, d = ((r + 1) % rows) * segments + s, ((r + 1) % rows) * segments + (s + 1) % segments
    return np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])


def torus(n: int, major: float = 0.3, minor: float = 0.12) -> tuple[np.ndarray, np.ndarray]:
    """A torus of about n triangles around the z axis."""
    rings = max(3, int(np.sqrt(n / 2 * major / minor)))
    seg = max(3, n // (2 * rings))
    u, w = np.meshgrid(np.linspace(0, 2 * np.pi, rings, endpoint=False),
                       np.linspace(0, 2 * np.pi, seg, endpoint=False), indexing="ij")
    radius = major + minor * np.cos(w)
    v = np.stack([radius * np.cos(u), radius * np.sin(u), minor * np.sin(w)], -1).reshape(-1, 3)
    return v, grid_faces(rings, seg, closed_rings=True)


def sphere(n: int, bumps: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A unit UV sphere of about n triangles (poles as rings of coincident vertices, degenerate triangles
    included, as a UV sphere has them), its radius modulated by smooth bumps of relative height `bumps`."""
    seg = max(4, int(np.sqrt(n)))
    rings = max(2, n // (2 * seg))
    theta, phi = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, seg, endpoint=False),
                             indexing="ij")
    radius = 1 + bumps * np.sin(3 * theta) ** 2 * np.cos(4 * phi)
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1) * radius[..., None]
    return v.reshape(-1, 3), grid_faces(rings, seg, closed_rings=False)


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A plain OBJ ("v x y z", "f i j k"), written to a temporary and moved into place."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        np.savetxt(f, vertices, fmt="v %.7f %.7f %.7f")
        np.savetxt(f, faces + 1, fmt="f %d %d %d")
    os.replace(tmp, path)


def write_mesh_scene(folder: Path, triangles: int) -> Path:
    """The scene with about `triangles` triangles in its three meshes; returns its XML file."""
    folder.mkdir(parents=True, exist_ok=True)
    shapes = []
    for name, share, bsdf, to_world in MESHES:
        n = int(triangles * share)
        obj = folder / f"{name}_{triangles}.obj"
        if not obj.exists():
            v, f = torus(n) if name == "torus" else sphere(n, bumps=0.12 if name == "blob" else 0.0)
            write_obj(obj, v, f)
        shapes.append(f'    <shape type="obj" id="{name}">\n        <string name="filename" value="{obj.name}"/>\n'
                      f'        <transform name="to_world">{to_world}</transform>\n        {bsdf}\n    </shape>\n')
    text = CORNELL.read_text()
    start = text.index('<shape type="obj" id="short_block">')
    end = text.index("</shape>", text.index('<shape type="obj" id="tall_block">')) + len("</shape>")
    text = text[:start] + "".join(shapes).strip() + text[end:]
    scene = folder / f"meshes_{triangles}.xml"
    tmp = scene.with_name(f".{scene.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, scene)
    return scene
