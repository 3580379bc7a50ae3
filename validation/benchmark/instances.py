"""`validate bench --only instances`: the peak memory of a scene of N instances of one generated 10,000-triangle
mesh (a `shapegroup` drawn by N `instance`s), N = 1 to 10,000, against the same scene with the mesh copied
per instance (what the tracer did before it instanced meshes: N `obj` shapes, each placed by the instance's
transform). Each render is `tracer render` in a child process of its own (bench.peak_memory: its VmHWM at
exit). The instance table is what the tracer keeps per instance (tracer.shapes.instance.InstanceSet: the
top-level BVH's rows and leaf rows and the two matrices), measured on the built arrays.
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

INSTANCES = (1, 100, 1_000, 10_000)   # instanced
COPIES = (1, 10, 100)                 # copied (the mesh of 10,000 triangles each time)
GRID = (100, 50)                      # quads of the generated mesh: 2 x 100 x 50 = 10,000 triangles
SIZE, SPP = 64, 4


def write_mesh(path: Path) -> int:
    """A wavy sheet over [0, 1]^2 of GRID quads (two triangles each) as an OBJ file; its triangle count."""
    nx, ny = GRID
    x, y = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, ny + 1), indexing="ij")
    z = 0.08 * np.sin(9 * x) * np.cos(7 * y)
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    i = np.arange(nx)[:, None] * (ny + 1) + np.arange(ny)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + ny + 1, i.ravel() + ny + 2, i.ravel() + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]) + 1
    with open(path, "w") as f:
        f.write("".join(f"v {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}\n" for p in v))
        f.write("".join(f"f {t[0]} {t[1]} {t[2]}\n" for t in faces))
    return len(faces)


def placements(n: int) -> list[str]:
    """The to_world of each of n instances: on a square grid, each turned about z and scaled (seeded)."""
    rng, side = np.random.default_rng(7), math.ceil(math.sqrt(n))
    out = []
    for k in range(n):
        angle, scale = rng.uniform(0, 360), rng.uniform(0.6, 0.9)
        out.append(f'<transform name="to_world"><translate x="-0.5" y="-0.5"/><scale value="{scale:.4f}"/>'
                   f'<rotate z="1" angle="{angle:.2f}"/><translate x="{k % side}" y="{k // side}"/></transform>')
    return out


def write_scene(folder: Path, n: int, instanced: bool) -> Path:
    """The scene of n placements of folder/sheet.obj: instances of one shapegroup, or n copies."""
    side = math.ceil(math.sqrt(n))
    centre, far = (side - 1) / 2, 0.9 * side + 2
    if instanced:
        shapes = ('<shape type="shapegroup" id="sheet"><shape type="obj"><string name="filename" value="sheet.obj"/>'
                  '<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.3"/></bsdf></shape></shape>\n'
                  + "\n".join(f'<shape type="instance"><ref id="sheet"/>{t}</shape>' for t in placements(n)))
    else:
        shapes = "\n".join(f'<shape type="obj"><string name="filename" value="sheet.obj"/>{t}'
                           '<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.3"/></bsdf></shape>'
                           for t in placements(n))
    path = folder / f"{'instances' if instanced else 'copies'}_{n}.xml"
    path.write_text(f"""<scene version="3.0.0">
<integrator type="path"><integer name="max_depth" value="3"/></integrator>
<sensor type="perspective"><float name="fov" value="50"/>
  <transform name="to_world"><lookat origin="{centre}, {centre - far}, {far}" target="{centre}, {centre}, 0" up="0, 0, 1"/></transform>
  <sampler type="independent"><integer name="sample_count" value="{SPP}"/></sampler>
  <film type="hdrfilm"><integer name="width" value="{SIZE}"/><integer name="height" value="{SIZE}"/></film>
</sensor>
<emitter type="constant"><rgb name="radiance" value="1"/></emitter>
{shapes}
</scene>
""")
    return path


def table_bytes(scene_path: Path) -> int:
    """The bytes of the per-instance arrays of the scene's instanced meshes (InstanceSet: the top-level
    BVH's node rows and leaf rows, the matrices)."""
    import drjit as dr

    import tracer
    from tracer.geometry import SceneGeometry

    geo = SceneGeometry(tracer.load_scene(scene_path))
    return sum(dr.width(a) * 4 for g in geo.instanced for a in (g.top.nodes, g.top.prims, g.matrices))


def instances(progress) -> dict:
    """Peak memory of each scene (bench.peak_memory) and the instance table of the largest."""
    from .bench import peak_memory

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        triangles = write_mesh(folder / "sheet.obj")
        runs = [(n, True) for n in INSTANCES] + [(n, False) for n in COPIES]
        for n, instanced in runs:
            progress(f"instances: {n} {'instances' if instanced else 'copies'}")
            scene = write_scene(folder, n, instanced)
            row = {"n": n, "instanced": instanced, **peak_memory(scene)}
            if instanced:
                row["table_bytes"] = table_bytes(scene)
            rows.append(row)
    return {"triangles": triangles, "rows": rows}


def markdown(section: dict) -> list[str]:
    """The instances section of the report."""
    rows = section["rows"]
    inst = {r["n"]: r for r in rows if r["instanced"]}
    copies = {r["n"]: r for r in rows if not r["instanced"]}
    one, most = inst[min(inst)], inst[max(inst)]
    bound = 2 * (one["peak_mib"] + most["table_bytes"] / 2 ** 20)
    per_copy = ((copies[max(copies)]["peak_mib"] - copies[min(copies)]["peak_mib"]) / (max(copies) - min(copies))
                if len(copies) > 1 else float("nan"))
    lines = ["## Instances: one mesh drawn many times", "",
             f"A generated sheet of {section['triangles']:,} triangles in a `shapegroup`, drawn by N `instance`s "
             f"(each turned and scaled, on a grid), against N copies of it (N `obj` shapes, what the tracer held "
             f"before it instanced meshes); `tracer render`, {SIZE} x {SIZE}, {SPP} spp, path, max_depth 3, each in "
             "a process of its own, peak resident set (VmHWM) at exit, BVHs built (no cache); wall: the whole "
             "process, loading the scene's XML included, on the machine as loaded as the header says. Written by "
             "`validate bench --only instances` (validation/benchmark/instances.py).", "",
             "| scene | N | peak (MiB) | instance table (MiB) | wall (s) |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        table = f"{r['table_bytes'] / 2 ** 20:.2f}" if r["instanced"] else "–"
        lines.append(f"| {'instances' if r['instanced'] else 'copies'} | {r['n']:,} | {r['peak_mib']:.0f} | "
                     f"{table} | {r['seconds']:.1f} |")
    verdict = "within" if most["peak_mib"] <= bound else "NOT within"
    lines += ["", f"{max(inst):,} instances peak at **{most['peak_mib']:.0f} MiB**: {verdict} 2x of one instance's "
              f"peak plus the instance table (2 x ({one['peak_mib']:.0f} + {most['table_bytes'] / 2 ** 20:.2f}) = "
              f"{bound:.0f} MiB); {most['peak_mib'] - one['peak_mib']:.0f} MiB above one instance. Copies cost "
              f"{per_copy:.1f} MiB each (from {min(copies)} to {max(copies)} copies): {max(inst):,} copies would take "
              f"some {per_copy * max(inst) / 1024:.0f} GiB.", ""]
    return lines
