"""Ground truth: Mitsuba 3 renders of a scene file at a high sample count, cached on disk.

A reference is K independent Mitsuba passes (validation.mitsuba_render.render_passes) reduced to what
the metrics and the statistical test need: the per-pixel mean, the per-pixel variance of that mean,
and the passes averaged over BLOCK x BLOCK tiles (validation.stats.block_means), so that Welch's test
runs on a reference without storing every full-resolution pass.

The cache key hashes the scene file, every mesh file it names, the parameters and the Mitsuba version.
Files are written atomically (temporary file, then rename) and carry a SHA-256 of their arrays, checked
on load: an interrupted or damaged cache entry is rendered again, never used.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import re
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .mitsuba_render import render_passes, version
from .stats import block_means

CACHE = Path(".cache/references")
BLOCK = 4          # tile edge of the stored block means; Welch's test then runs with block=1
SEED = 777         # Mitsuba's seeds for references; tests and sweeps use other seeds


@dataclass
class Reference:
    mean: np.ndarray        # (H, W, 3) linear radiance
    var: np.ndarray         # (H, W, 3) variance of `mean` (pass variance / K)
    blocks: np.ndarray      # (K, H // BLOCK, W // BLOCK, 3) pass means over BLOCK x BLOCK tiles
    spp: int                # total samples per pixel (passes x spp per pass)
    seconds: float          # Mitsuba's wall time to render it
    key: str


def scene_files(scene_file: Path) -> list[Path]:
    """The scene file and every file its XML names with a `filename` string (meshes)."""
    text = scene_file.read_text()
    names = re.findall(r'name="filename"\s+value="([^"]+)"', text)
    return [scene_file] + sorted(scene_file.parent / n for n in names)


def cache_key(scene_file: Path, passes: int, spp: int, params: dict) -> str:
    """SHA-256 over the scene's files, the render parameters and Mitsuba's version."""
    h = hashlib.sha256()
    for f in scene_files(scene_file):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    h.update(json.dumps({"passes": passes, "spp": spp, "seed": SEED, "block": BLOCK, "params": params,
                         "mitsuba": version()}, sort_keys=True).encode())
    return h.hexdigest()[:24]


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def save(path: Path, ref: Reference) -> None:
    """Writes `ref` as .npz with a checksum, atomically."""
    arrays = {"mean": ref.mean, "var": ref.var, "blocks": ref.blocks}
    meta = json.dumps({"spp": ref.spp, "seconds": ref.seconds, "key": ref.key, "sha256": _digest(arrays)})
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(meta), **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(buf.getvalue())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load(path: Path, key: str) -> Reference | None:
    """The cached reference, or None if it is missing, unreadable, for another key, or fails its checksum."""
    try:
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {name: z[name] for name in ("mean", "var", "blocks")}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if meta.get("key") != key or meta.get("sha256") != _digest(arrays):
        return None
    return Reference(arrays["mean"], arrays["var"], arrays["blocks"], meta["spp"], meta["seconds"], key)


def reference(scene_file: str | Path, max_depth: int, size: int, passes: int = 16, spp: int = 64,
              cache: Path = CACHE) -> Reference:
    """Mitsuba's `path` at `max_depth`, `size` x `size`, `passes` x `spp` samples per pixel; cached."""
    scene_file = Path(scene_file)
    params = {"max_depth": max_depth, "width": size, "height": size}
    key = cache_key(scene_file, passes, spp, params)
    path = cache / f"{scene_file.stem}-d{max_depth}-{size}px-{passes}x{spp}-{key}.npz"
    ref = load(path, key)
    if ref is not None:
        return ref
    start = time.perf_counter()
    p = render_passes(scene_file, passes, spp, seed=SEED, **params)
    seconds = time.perf_counter() - start
    ref = Reference(p.mean(0), p.var(0, ddof=1) / passes, block_means(p, BLOCK).astype(np.float32),
                    passes * spp, seconds, key)
    save(path, ref)
    return ref
