"""Built BVHs kept for reuse, keyed by the triangles' content: in this process (the last few), and on disk
for meshes of DISK_MIN_TRIANGLES or more, where reading one back, the key's hash included, takes about a
tenth of building it (measured: 0.020 against 0.24 s at 249,354 triangles, 0.066 against 0.90 s at 997,534,
medians of 3). The folder is
`$TRACER_BVH_CACHE` if set (`off` keeps nothing on disk), else `$XDG_CACHE_HOME/tracer/bvh` (by default
`~/.cache/tracer/bvh`); beyond CAPACITY bytes the files least recently used are removed.

The key is a SHA-256 hash of the SHA-256 hashes of the triangle vertices' bytes (or of the meshes'
vertices and faces that determine them), their shapes and dtypes, the leaf size and this module's FORMAT,
so a mesh that changes gets a new key. A file is written to a temporary beside its target and moved into place (a reader never
sees half a file) and checked on load: its stored key, the node table's and the order's shapes and types,
and that the order is a permutation of the triangles; a file that fails is rebuilt and overwritten.
"""
from __future__ import annotations

import hashlib
import os
import zipfile
from collections import OrderedDict
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .bvh import LEAF_BIT, WIDTH, Layout, layout
from .bvh_build import LEAF_SIZE
from ..jit import CORES

FORMAT = 7            # bump when Layout or the build changes (2: SAH build, leaves of up to 4; 3: 4-wide rows;
                      # 4: splits along any of the three axes; 5: the SAH's traversal cost 2; 6: 32 bins, of
                      # every triangle below 65,536; 7: the SAH's traversal cost 1)
IN_MEMORY = 4         # layouts kept in this process
ENV = "TRACER_BVH_CACHE"
OFF = ("off", "0", "no", "none", "")
DISK_MIN_TRIANGLES = 50_000   # below, a build takes about 0.1 s or less: not worth a file
CAPACITY = 2 ** 30            # bytes on disk
_memory: OrderedDict[str, Layout] = OrderedDict()


def key(*arrays: np.ndarray) -> str:
    """The cache key of (n, 3, 3) triangle vertices, or of arrays that determine them: a hash of each
    array's hash, its shape and dtype (the arrays hashed on several threads: hashlib leaves the
    interpreter lock)."""
    arrays = [np.ascontiguousarray(a) for a in arrays]
    with ThreadPoolExecutor(CORES) as pool:
        digests = list(pool.map(lambda a: hashlib.sha256(a.data).digest(), arrays))
    h = hashlib.sha256(f"{FORMAT} {LEAF_SIZE}".encode())   # CPUs with SHA extensions: twice BLAKE2b's speed
    for a, digest in zip(arrays, digests):
        h.update(f" {a.dtype.str} {a.shape}".encode())
        h.update(digest)
    return h.hexdigest()


def disk_folder() -> Path | None:
    """Where BVHs are kept on disk: $TRACER_BVH_CACHE, else the user's cache folder; None when off."""
    value = os.environ.get(ENV)
    if value is not None:
        return None if value.strip().lower() in OFF else Path(value)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tracer" / "bvh"


def cached_layout(vertices: np.ndarray, folder: Path | str | None = None, source: Sequence[np.ndarray] = (),
                  faces: np.ndarray | None = None) -> Layout:
    """The BVH Layout of these triangles (as bvh_build.build takes them): from this process's cache, else
    from `folder` (default: disk_folder(), for meshes of DISK_MIN_TRIANGLES or more), else built (and then
    stored in both). `source`: arrays that determine the triangles (meshes' vertices and faces: half their
    bytes), keyed instead of them."""
    k = key(*source) if source else key(vertices) if faces is None else key(vertices, faces)
    if k in _memory:
        _memory.move_to_end(k)
        return _memory[k]
    triangles = len(vertices if faces is None else faces)
    if folder is None and triangles >= DISK_MIN_TRIANGLES:
        folder = disk_folder()
    path = Path(folder) / f"{k}.npz" if folder is not None else None
    tables = _load(path, k, triangles) if path is not None else None
    if tables is None:
        tables = layout(vertices, faces)
        if path is not None:
            _save(path, k, tables)
            _evict(path.parent, CAPACITY)
    else:
        _touch(path)
    _memory[k] = tables
    while len(_memory) > IN_MEMORY:
        _memory.popitem(last=False)
    return tables


def clear_memory() -> None:
    """Forgets the layouts kept in this process."""
    _memory.clear()


def _touch(path: Path) -> None:
    """Marks a file as just used (eviction removes the least recently used first)."""
    try:
        os.utime(path)
    except OSError:
        pass


def _evict(folder: Path, capacity: int) -> None:
    """Removes the least recently used BVH files until the folder holds at most `capacity` bytes."""
    try:
        files = [(f, f.stat()) for f in folder.glob("*.npz")]
    except OSError:
        return
    total = sum(st.st_size for _, st in files)
    for f, st in sorted(files, key=lambda x: x[1].st_mtime):
        if total <= capacity:
            break
        try:
            f.unlink()
            total -= st.st_size
        except OSError:
            pass


def _save(path: Path, k: str, tables: Layout) -> None:
    """Writes atomically; a folder that cannot be written only costs the cache."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            np.savez(f, key=np.array(k), nodes=tables.nodes, order=tables.order, rows=tables.rows,
                     root=tables.root, stack_size=np.array(tables.stack_size))
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)


def _load(path: Path, k: str, triangles: int) -> Layout | None:
    """The stored Layout, or None when the file is missing, unreadable or fails a check."""
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["key"]) != k:
                return None
            nodes, order, rows, root = f["nodes"], f["order"], f["rows"], f["root"]
            stack_size = int(f["stack_size"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):   # missing, truncated, not an npz
        return None
    ok = (nodes.dtype == np.uint32 and nodes.ndim == 2 and nodes.shape[1] == 4 * WIDTH and rows.shape == (len(nodes),)
          and root.shape == (2, 3) and np.isfinite(root).all() and 0 < stack_size < 64
          and order.shape == (triangles,) and order.dtype.kind == "i" and triangles > 0
          and order.min() >= 0 and order.max() < triangles and (np.bincount(order, minlength=triangles) == 1).all())
    if ok:   # every link names a node row, or a leaf within the triangles
        link = nodes[:, 3::4].astype(np.int64)
        leaf = link >= LEAF_BIT
        word = link & (LEAF_BIT - 1)
        ok = bool(np.all(np.where(leaf, (word >> 3) + (word & 7) <= triangles, link >> WIDTH < len(nodes))))
    return Layout(nodes, order, rows, root, stack_size) if ok else None
