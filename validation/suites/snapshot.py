"""`validate snapshot DIR [--against OLD]`: how a refactor shows that it kept every image bit-identical.

Renders every scene of mitsuba_scenes/ and mitsuba_scenes/stress/ (path tracer; the report's estimator where
it renders the scene) and a generated three-mesh scene traced through the BVH, small and with a fixed seed,
plus adaptive sampling and the Gaussian filter on the room, with one Dr.Jit thread (float atomics from
several threads add in a varying order), and saves each image as .npy in DIR. With --against, compares
them with an earlier snapshot: exit 0 when every image is equal to the bit, 1 otherwise.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
WIDTH, HEIGHT = 20, 16
MESH_TRIANGLES = 3000       # above the BVH threshold


def scenes(folder: Path) -> list[Path]:
    """The scenes rendered: the project's, its stress cases and a mesh scene generated into `folder`."""
    from ..benchmark.mesh_scene import write_mesh_scene

    found = sorted((ROOT / "mitsuba_scenes").glob("*.xml")) + sorted((ROOT / "mitsuba_scenes/stress").glob("*.xml"))
    return found + [write_mesh_scene(folder / "meshes", MESH_TRIANGLES)]


def jobs(paths: list[Path]) -> Iterator[tuple[str, Callable[[], np.ndarray]]]:
    """(name, render) per image; scenes the loader refuses (stress cases that test refusals) are left out."""
    import tracer
    from tracer.adaptive import render_adaptive
    from tracer.rendering import render

    for path in paths:
        try:
            scene = tracer.load_scene(path, width=WIDTH, height=HEIGHT)
        except tracer.SceneError:
            continue
        name = f"{path.parent.name}_{path.stem}"
        yield f"{name}_path", lambda s=scene: render(s, "path", spp=4, seed=3, max_depth=6).image
        if not scene.estimator_refusals("report"):
            yield f"{name}_report", lambda s=scene: render(s, "report", spp=1, seed=3, max_depth=4, direct=2,
                                                           indirect=2).image
    room = tracer.load_scene(ROOT / "mitsuba_scenes/hexagon_room.xml", width=WIDTH, height=HEIGHT)
    yield "room_adaptive", lambda: render_adaptive(room, spp=4, seed=2, max_depth=4).image
    yield "room_gaussian", lambda: render(room, "path", spp=4, seed=3, max_depth=5, rfilter="gaussian").image


def write(folder: Path, paths: list[Path] | None = None) -> list[str]:
    """Renders the images into `folder` (one Dr.Jit thread); returns their names."""
    import drjit as dr

    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        names = []
        for name, image in jobs(scenes(folder) if paths is None else paths):
            np.save(folder / f"{name}.npy", image())
            names.append(name)
        return names
    finally:
        dr.set_thread_count(threads)


def compare(new: Path, old: Path) -> list[str]:
    """One line per image that differs (or is missing on either side); empty when all are bit-identical."""
    a, b = ({p.name for p in f.glob("*.npy")} for f in (new, old))
    out = [f"{n}: only in {old}" for n in sorted(b - a)] + [f"{n}: only in {new}" for n in sorted(a - b)]
    for n in sorted(a & b):
        x, y = np.load(new / n), np.load(old / n)
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
            diff = np.nanmax(np.abs(x - y)) if x.shape == y.shape else f"shape {x.shape} vs {y.shape}"
            out.append(f"{n}: differs (largest difference {diff})")
    return out
