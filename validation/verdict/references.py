"""Ground truth: Mitsuba 3 renders of a scene file at a high sample count, cached on disk.

A reference is K independent Mitsuba passes (validation.verdict.mitsuba_render.render_passes) reduced to what
the metrics and the statistical test need: the per-pixel mean, the per-pixel variance of that mean,
and the passes averaged over BLOCK x BLOCK tiles (validation.verdict.stats.block_means), so that Welch's test
runs on a reference without storing every full-resolution pass.

The cache key hashes the scene file, every file it names (meshes, includes, textures), the plan (size,
depth, overrides), the samples and the Mitsuba version (validation.verdict.scenefile.ScenePlan.content_key).
Files are written atomically (temporary file, then rename) and carry a SHA-256 of their arrays, checked
on load: an interrupted or damaged cache entry is rendered again, never used.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracer.imageio import atomic_write

from .mitsuba_render import version
from .protocol import BLOCK, SEED_REFERENCE as SEED
from .renderers import MitsubaRenderer
from .scenefile import ScenePlan, plan
from .stats import block_means

CACHE_VARIABLE = "VALIDATE_CACHE"     # where references are cached, if set (validate check --cache overrides it)
CACHE = Path(".cache/references")    # else: relative to the working folder


def cache_folder() -> Path:
    """The reference cache: $VALIDATE_CACHE if set, else CACHE."""
    return Path(os.environ[CACHE_VARIABLE]) if os.environ.get(CACHE_VARIABLE) else CACHE


@dataclass
class Reference:
    mean: np.ndarray        # (H, W, 3) linear radiance
    var: np.ndarray         # (H, W, 3) variance of `mean` (pass variance / K)
    blocks: np.ndarray      # (K, H // BLOCK, W // BLOCK, 3) pass means over BLOCK x BLOCK tiles
    spp: int                # total samples per pixel (passes x spp per pass)
    seconds: float          # Mitsuba's wall time to render it
    key: str


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def encode(ref: Reference) -> bytes:
    """`ref` as the bytes of its .npz file, with a checksum of its arrays."""
    arrays = {"mean": ref.mean, "var": ref.var, "blocks": ref.blocks}
    meta = json.dumps({"spp": ref.spp, "seconds": ref.seconds, "key": ref.key, "sha256": _digest(arrays)})
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(meta), **arrays)
    return buf.getvalue()


def save(path: Path, ref: Reference) -> None:
    """Writes `ref` as .npz with a checksum, atomically."""
    data = encode(ref)
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


_files: dict[str, bytes] | None = None      # in_memory's cache files, by name


@contextmanager
def in_memory(files: dict[str, bytes]) -> Iterator[dict[str, bytes]]:
    """Within it, references are read from `files` (cache files' contents by name, as a suite's process sends
    them to a worker) and those rendered are kept in the dict it yields, never written: a worker needs no
    disk, and the suite's process alone writes the cache (write_files)."""
    global _files
    rendered: dict[str, bytes] = {}
    outer, _files = _files, {**files}
    try:
        yield rendered
    finally:
        rendered.update({k: v for k, v in _files.items() if k not in files})
        _files = outer


def write_files(cache: Path, files: dict[str, bytes]) -> None:
    """Reference files a worker rendered, each written atomically unless the cache holds it already."""
    for name, data in files.items():
        if not (cache / name).exists():
            atomic_write(cache / name, lambda tmp: Path(tmp).write_bytes(data))


def load(path: Path, key: str) -> Reference | None:
    """The cached reference, or None if it is missing, unreadable, for another key, or fails its checksum."""
    try:
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {name: z[name] for name in ("mean", "var", "blocks")}
    except Exception:    # a damaged file: zipfile and NumPy raise many kinds (BadZipFile, NotImplementedError, ...)
        return None
    if not isinstance(meta, dict) or meta.get("key") != key or meta.get("sha256") != _digest(arrays):
        return None
    return Reference(arrays["mean"], arrays["var"], arrays["blocks"], meta["spp"], meta["seconds"], key)


def reference(scene_file: str | Path, max_depth: int, size: int, passes: int = 16, spp: int = 64,
              cache: Path | None = None) -> Reference:
    """Mitsuba's `path` at `max_depth`, `size` x `size`, `passes` x `spp` samples per pixel; cached."""
    scene_plan = plan(scene_file, {"width": str(size), "height": str(size)}, max_depth=max_depth)
    return mitsuba_reference(scene_plan, passes, spp, cache)


def mitsuba_reference(scene_plan: ScenePlan, passes: int, spp: int, cache: Path | None = None,
                      seed: int = SEED) -> Reference:
    """Mitsuba's `path` on the planned scene, `passes` x `spp` samples per pixel from the seed base `seed`;
    cached (in `cache`, default cache_folder()) under a key of the scene's content (every file it names), the
    plan, the samples, the seed and Mitsuba's version."""
    cache = cache_folder() if cache is None else Path(cache)
    key = scene_plan.content_key(passes=passes, spp=spp, seed=seed, block=BLOCK, mitsuba=version())
    path = cache / (f"{scene_plan.path.stem}-d{scene_plan.max_depth}-{scene_plan.width}x{scene_plan.height}"
                    f"-{passes}x{spp}-{key}.npz")
    ref = load(path if _files is None else io.BytesIO(_files.get(path.name, b"")), key)
    if ref is not None:
        return ref
    start = time.perf_counter()
    p = MitsubaRenderer().passes(scene_plan, passes, spp, seed)
    seconds = time.perf_counter() - start
    ref = Reference(p.mean(0), p.var(0, ddof=1) / passes, block_means(p, BLOCK).astype(np.float32),
                    passes * spp, seconds, key)
    if _files is None:
        save(path, ref)
    else:
        _files[path.name] = encode(ref)
    return ref
