"""Reading triangle meshes (Wavefront OBJ, Stanford PLY) and computing Mitsuba's smooth vertex normals."""
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
    text = path.read_text()
    vertices, faces, vn = _parse_plain(text) or _parse_statements(text, path)
    if not len(faces):
        raise MeshError(f"{path}: the mesh has no faces")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: a vertex position is NaN or infinite")
    for a in (vertices, faces, vn):
        if a is not None:
            a.flags.writeable = False
    return vertices, faces, vn


def _parse_statements(text: str, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Any OBJ, statement by statement."""
    positions, normals = [], []
    keys: dict[tuple[int, int], int] = {}
    faces = []
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
    order = sorted(keys, key=keys.get)
    vertices = np.asarray(positions, float)[[k[0] for k in order]] if order else np.zeros((0, 3))
    vn = None
    if normals and all(k[1] >= 0 for k in order):
        vn = np.asarray(normals, float)[[k[1] for k in order]]
        length = np.linalg.norm(vn, axis=1, keepdims=True)
        if not np.all(length > 0):    # Mitsuba refuses these too
            raise MeshError(f"{path}: a vertex normal (vn) has zero length")
        vn /= length
    return vertices, np.asarray(faces, np.int64).reshape(-1, 3), vn


def _parse_plain(text: str) -> tuple[np.ndarray, np.ndarray, None] | None:
    """The common OBJ, parsed in bulk: only "v x y z" and "f i j k" statements (positive indices of earlier
    vertices) besides comments and statements the reader ignores. None for anything else, which
    _parse_statements then reads (and reports on) line by line; both give the same mesh."""
    v_rows, f_rows, known = [], [], []
    for line in text.splitlines():
        head = line[:2]
        if head == "v ":
            v_rows.append(line[2:].split())
        elif head == "f ":
            f_rows.append(line[2:].split())
            known.append(len(v_rows))          # the vertices a face may name
        elif line.split()[:1] in (["v"], ["vn"], ["f"]):
            return None
    if not f_rows or any(len(r) != 3 for r in v_rows) or any(len(r) != 3 for r in f_rows):
        return None
    try:
        positions, corners = np.array(v_rows, float), np.array(f_rows, np.int64)
    except ValueError:                            # "1/2/3" corners, malformed numbers
        return None
    if (corners < 1).any() or (corners > np.array(known)[:, None]).any():
        return None
    used, first = np.unique(corners.ravel() - 1, return_index=True)
    order = used[np.argsort(first)]               # vertices in order of first use, as Mitsuba keys them
    index = np.empty(len(positions), np.int64)
    index[order] = np.arange(len(order))
    return positions[order], index[corners - 1], None


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


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices, triangles and per-vertex normals (None unless the file has nx, ny, nz) of a PLY file,
    ASCII or binary (read with `plyfile`). Faces must be triangles, as Mitsuba requires."""
    try:
        stat = path.stat()
        return _read_ply(path.resolve(), stat.st_size, stat.st_mtime_ns)
    except OSError as e:
        raise MeshError(f"cannot read mesh {path}: {e.strerror}") from None


@lru_cache(maxsize=16)
def _read_ply(path: Path, size: int, mtime_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    from plyfile import PlyData, PlyParseError

    try:
        ply = PlyData.read(str(path))
        vertex, face = ply["vertex"], ply["face"]
        names = vertex.data.dtype.names
        vertices = np.stack([np.asarray(vertex[k], float) for k in "xyz"], axis=1)
        normals = np.stack([np.asarray(vertex[k], float) for k in ("nx", "ny", "nz")], axis=1) \
            if all(k in names for k in ("nx", "ny", "nz")) else None
        index = "vertex_indices" if "vertex_indices" in face.data.dtype.names else "vertex_index"
        rows = face[index]
    except (PlyParseError, KeyError, ValueError) as e:
        raise MeshError(f"{path}: not a readable PLY mesh with vertex x, y, z and face vertex_indices ({e})") \
            from None
    if any(len(r) != 3 for r in rows):
        raise MeshError(f"{path}: only triangular faces are supported (as in Mitsuba)")
    faces = np.asarray(np.stack(rows) if len(rows) else np.zeros((0, 3)), np.int64).reshape(-1, 3)
    if not len(faces):
        raise MeshError(f"{path}: the mesh has no faces")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{path}: a face names a vertex outside 0..{len(vertices) - 1}")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: a vertex position is NaN or infinite")
    if normals is not None:
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        if not np.all(length > 0):
            raise MeshError(f"{path}: a vertex normal has zero length")
        normals = normals / length
    for a in (vertices, faces, normals):
        if a is not None:
            a.flags.writeable = False
    return vertices, faces, normals
