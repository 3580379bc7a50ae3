"""Reading triangle meshes (Wavefront OBJ) and computing Mitsuba's smooth vertex normals."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np


class MeshError(ValueError):
    pass


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices, triangles and per-vertex normals (None when the file has none), as read-only arrays.

    Vertices are keyed by their (position, normal) index pair as Mitsuba does; polygons are fanned. A file
    that several shapes share is read once (until it changes).
    """
    try:
        stat = path.stat()
        return _read_obj(path.resolve(), stat.st_size, stat.st_mtime_ns)
    except OSError as e:
        raise MeshError(f"cannot read mesh {path}: {e.strerror}") from None
    except UnicodeDecodeError:
        raise MeshError(f"{path}: not a text (Wavefront OBJ) file") from None


@lru_cache(maxsize=16)
def _read_obj(path: Path, size: int, mtime_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    positions, normals = [], []
    keys: dict[tuple[int, int], int] = {}
    faces = []
    text = path.read_text()
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            if parts[0] == "v":
                positions.append([float(x) for x in parts[1:4]])
            elif parts[0] == "vn":
                normals.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                corners = [_corner(c, len(positions), len(normals)) for c in parts[1:]]
                ids = [keys.setdefault(c, len(keys)) for c in corners]
                faces += [(ids[0], ids[i], ids[i + 1]) for i in range(1, len(ids) - 1)]
        except (ValueError, IndexError):
            raise MeshError(f"{path}:{lineno}: malformed OBJ line '{line.strip()}'") from None
    if not faces:
        raise MeshError(f"{path}: the mesh has no faces")
    pos = np.asarray(positions, float)
    order = sorted(keys, key=keys.get)
    vertices = pos[[k[0] for k in order]]
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: a vertex position is NaN or infinite")
    vn = None
    if normals and all(k[1] >= 0 for k in order):
        vn = np.asarray(normals, float)[[k[1] for k in order]]
        vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    out = vertices, np.asarray(faces, np.int64), vn
    for a in out:
        if a is not None:
            a.flags.writeable = False
    return out


def _corner(token: str, n_pos: int, n_norm: int) -> tuple[int, int]:
    fields = token.split("/")
    p = _index(fields[0], n_pos)
    n = _index(fields[2], n_norm) if len(fields) > 2 and fields[2] else -1
    return p, n


def _index(s: str, count: int) -> int:
    i = int(s)
    i = i - 1 if i > 0 else count + i
    if not 0 <= i < count:
        raise IndexError(s)
    return i


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted average of the adjacent face normals (Mitsuba's recompute_vertex_normals)."""
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    out = np.zeros_like(vertices)
    for i in range(3):
        d0 = v[:, (i + 1) % 3] - v[:, i]
        d1 = v[:, (i + 2) % 3] - v[:, i]
        d0 /= np.maximum(np.linalg.norm(d0, axis=1, keepdims=True), 1e-30)
        d1 /= np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), 1e-30)
        angle = np.arccos(np.clip(np.sum(d0 * d1, axis=1), -1, 1))
        np.add.at(out, faces[:, i], n * angle[:, None])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, length, out=np.zeros_like(out), where=length > 0)
