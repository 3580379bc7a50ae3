"""Reading triangle meshes (Wavefront OBJ, Stanford PLY) and computing Mitsuba's smooth vertex normals."""
from __future__ import annotations

import io
from collections.abc import Iterator
from functools import lru_cache, partial
from pathlib import Path

import numpy as np

from . import ply_attributes
from .ply_attributes import FACE_RESERVED, VERTEX_RESERVED, Attributes

BLOCK = 1 << 15   # triangles whose coordinate rows are computed at once: the temporaries stay small, where
                  # all at once they took some 200 MB of fresh memory at 1M triangles


class MeshError(ValueError):
    pass


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Vertices, triangles, per-vertex unit normals (None unless every corner names one) and texture
    coordinates (None when the file has no `vt`; NaN for a vertex whose corner names none, which Mitsuba
    leaves undefined), as read-only arrays. The texture coordinates are as written (Mitsuba's
    `flip_tex_coords` is applied by the shape).

    Vertices are keyed by their (position, texture coordinate, normal) index triple, numbered in order of
    first use, as Mitsuba does; polygons are fanned. A file that several shapes share is read once (until it
    changes).
    """
    try:
        stat = path.stat()
        return _read_obj(path.resolve(), stat.st_size, stat.st_mtime_ns)
    except OSError as e:
        raise MeshError(f"cannot read mesh {path}: {e.strerror}") from None
    except UnicodeDecodeError:
        raise MeshError(f"{path}: not a text (Wavefront OBJ) file") from None


@lru_cache(maxsize=16)
def _read_obj(path: Path, size: int, mtime_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                             np.ndarray | None]:
    data = path.read_bytes()
    if b"\r" in data:     # universal newlines, as Python's text files read them
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    vertices, faces, vn, uvs = _parse_bulk(data) or _parse_statements(data.decode(), path)
    if not len(faces):
        raise MeshError(f"{path}: the mesh has no faces")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: a vertex position is NaN or infinite")
    if vn is not None:
        length = np.linalg.norm(vn, axis=1, keepdims=True)
        if not np.all(length > 0):    # Mitsuba refuses these too
            raise MeshError(f"{path}: a vertex normal (vn) has zero length")
        vn /= length
    for a in (vertices, faces, vn, uvs):
        if a is not None:
            a.flags.writeable = False
    return vertices, faces, vn, uvs


def _parse_statements(text: str, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                      np.ndarray | None]:
    """Any OBJ, statement by statement: vertices, triangles, the normals (vn, as written) of the vertices
    when every corner names one, and their texture coordinates (vt, its first two numbers) where the file
    has any."""
    positions, normals, texcoords = [], [], []
    keys: dict[tuple[int, int, int], int] = {}
    faces = []
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            if parts[0] in ("v", "vn"):
                if len(parts) < 4:
                    raise ValueError(line)
                (positions if parts[0] == "v" else normals).append([float(x) for x in parts[1:4]])
            elif parts[0] == "vt":
                if len(parts) < 3:
                    raise ValueError(line)
                texcoords.append([float(x) for x in parts[1:3]])
            elif parts[0] == "f":
                corners = [_corner(c, len(positions), len(texcoords), len(normals)) for c in parts[1:]]
                ids = [keys.setdefault(c, len(keys)) for c in corners]
                faces += [(ids[0], ids[i], ids[i + 1]) for i in range(1, len(ids) - 1)]
        except (ValueError, IndexError):
            raise MeshError(f"{path}:{lineno}: malformed OBJ line '{line.strip()}'") from None
    order = list(keys)        # in order of first use
    vertices = np.asarray(positions, float)[[k[0] for k in order]] if order else np.zeros((0, 3))
    vn = None
    if normals and all(k[2] >= 0 for k in order):
        vn = np.asarray(normals, float)[[k[2] for k in order]]
    uvs = _texcoords(np.asarray(texcoords, float).reshape(-1, 2), np.array([k[1] for k in order], np.int64),
                     len(order))
    return vertices, np.asarray(faces, np.int64).reshape(-1, 3), vn, uvs


def _texcoords(texcoords: np.ndarray, index: np.ndarray | None, count: int) -> np.ndarray | None:
    """The `count` vertices' texture coordinates from their corners' indices into `texcoords` (NaN where -1,
    or all where `index` is None: named by none); None when the file has no texture coordinates."""
    if not len(texcoords):
        return None
    if index is None:
        return np.full((count, 2), np.nan)
    return np.where((index >= 0)[:, None], texcoords[np.maximum(index, 0)], np.nan)


def _corner(token: str, n_pos: int, n_tex: int, n_norm: int) -> tuple[int, int, int]:
    """A face corner's (position, texture coordinate, normal) indices from 0, -1 where it names none."""
    fields = token.split("/")
    if len(fields) > 3:
        raise ValueError(token)
    p = _index(fields[0], n_pos)
    t = _index(fields[1], n_tex) if len(fields) > 1 and fields[1] else -1
    n = _index(fields[2], n_norm) if len(fields) > 2 and fields[2] else -1
    return p, t, n


def _index(s: str, count: int) -> int:
    """An OBJ index (from 1, or negative: relative to the end) of one of `count` elements, from 0."""
    i = int(s)
    i = i - 1 if i > 0 else count + i
    if not 0 <= i < count:
        raise IndexError(s)
    return i


# ---- the same, in bulk --------------------------------------------------------------------------------
_ABSENT = np.iinfo(np.int64).min      # a corner's index that the corner does not name


def _parse_bulk(text: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None] | None:
    """_parse_statements' mesh (of text.decode()) in bulk, with NumPy, for the OBJ files exporters write:
    "v", "vn" and "f" statements at the start of their lines, ASCII text, face corners "p", "p/t", "p/t/n"
    or "p//n" of plain integers (negative ones relative), any number of corners, anything else ignored as
    _parse_statements ignores it. None for any other file, which _parse_statements then reads (and
    reports on) line by line."""
    if not text.isascii():
        return None
    if not text.endswith(b"\n"):
        text += b"\n"
    data = np.frombuffer(text, np.uint8)
    ends = np.flatnonzero(data == 10)
    # control characters other than tab split lines or words in Python's str methods
    if np.count_nonzero(data < 32) != len(ends) + np.count_nonzero(data == 9):
        return None
    starts = np.concatenate(([0], ends[:-1] + 1))
    length = ends - starts
    c0, c1, c2 = (np.take(data, starts + k, mode="clip") for k in range(3))   # clip: past the end, the last
    blank1, blank2 = (c1 == 32) | (c1 == 9), (c2 == 32) | (c2 == 9)
    v = (c0 == ord("v")) & blank1 & (length > 1)
    vn = (c0 == ord("v")) & (c1 == ord("n")) & blank2 & (length > 2)
    vt = (c0 == ord("v")) & (c1 == ord("t")) & blank2 & (length > 2)
    f = (c0 == ord("f")) & blank1 & (length > 1)
    bare = ((c0 == ord("v")) | (c0 == ord("f"))) & (length == 1) | (c0 == ord("v")) & np.isin(c1, list(b"nt")) \
        & (length == 2)                                      # a keyword alone
    indented = ((c0 == 32) | (c0 == 9)) & (length > 0)
    if bare.any() or not f.any() or any(text[s:e].lstrip()[:1] not in (b"", b"#")
                                        for s, e in zip(starts[indented], ends[indented])):
        return None
    lines = partial(_lines, data, starts, ends)
    try:
        positions, normals, texcoords = _coordinates(lines(v)), _coordinates(lines(vn)), _coordinates(lines(vt), 2)
    except ValueError:
        return None
    corners = _face_corners(lines(f).tobytes())
    if corners is None:
        return None
    per_face, *indices = corners
    p, t, n = (_resolve(i, kind, f, per_face) for i, kind in zip(indices, (v, vt, vn)))
    if not ((p >= 0).all() and all(i is None or (i >= -1).all() for i in (t, n))):
        return None
    vertex, first = _weld(p, t, n)
    vertices = positions[p[first]]
    vn_out = normals[n[first]] if n is not None and (n[first] >= 0).all() else None
    uvs = _texcoords(texcoords, None if t is None else t[first], len(first))
    return vertices, _fan(vertex, per_face), vn_out, uvs


def _lines(data: np.ndarray, starts: np.ndarray, ends: np.ndarray, marked: np.ndarray) -> np.ndarray:
    """The bytes of the lines marked, newlines included (a view where they follow each other)."""
    index = np.flatnonzero(marked)
    if not len(index):
        return data[:0]
    if index[-1] - index[0] + 1 == len(index):
        return data[starts[index[0]]:ends[index[-1]] + 1]
    return data[np.repeat(marked, ends - starts + 1)]


def _coordinates(lines: np.ndarray, count: int = 3) -> np.ndarray:
    """The first `count` numbers of each line (as Python's float reads them: NumPy's reader rounds as it does
    and refuses the rest, "1_0" included); ValueError for a line it cannot read."""
    if not len(lines):
        return np.zeros((0, count))
    return np.loadtxt(io.BytesIO(lines.tobytes()), usecols=tuple(range(1, count + 1)), comments=None, ndmin=2)


def _face_corners(lines: bytes) -> tuple[np.ndarray, ...] | None:
    """The face statements (whole lines) to the corners per face and each corner's OBJ indices p, t, n
    (_ABSENT where it names none; None where no corner names one), or None unless every corner is "p",
    "p/t", "p/t/n" or "p//n" of plain integers."""
    faces = np.frombuffer(lines, np.uint8)
    newlines = np.flatnonzero(faces == 10)
    if lines.translate(None, b"f0123456789-/ \t\n") or np.count_nonzero(faces == ord("f")) != len(newlines):
        return None                                            # other bytes, or "f" past the keyword
    lines = lines.replace(b"f", b" ")
    faces = np.frombuffer(lines, np.uint8)
    space = faces <= 32
    first = np.flatnonzero(space[:-1] & ~space[1:]) + 1       # each corner's first byte
    if not len(first):
        return None
    per_face = _per_line(first, newlines)
    slashes = doubled = None
    if b"/" in lines:
        slash = faces == 47
        last = np.flatnonzero(~space[:-1] & space[1:])        # each corner's last byte
        slashes, doubled = (_per_corner(m, first, last) for m in (slash, np.append(slash[1:] & slash[:-1], False)))
        if (slashes > 2).any():
            return None
        lines = lines.replace(b"/", b" ")
    if b"-" in lines:                                          # only as a number's sign
        minus = np.flatnonzero(faces == 45)
        after, before = faces[minus + 1], faces[minus - 1]
        if not (((after >= 48) & (after <= 57)).all() and ((before <= 32) | (before == 47)).all()):
            return None
    numbers = np.fromstring(lines, np.int64, sep=" ")
    if slashes is None:                                        # p only
        return (per_face, numbers, None, None) if len(numbers) == len(first) and numbers.min() > _ABSENT else None
    fields = slashes + 1 - doubled                             # p | p t | p t n | p n
    if len(numbers) != fields.sum() or (numbers == _ABSENT).any():   # fewer: an empty field ("/1", "1/")
        return None
    at = np.cumsum(fields) - fields
    p, t, n = numbers[at], None, None
    with_t, with_n = (slashes >= 1) & (doubled == 0), slashes == 2
    if with_t.any():
        t = np.where(with_t, numbers[np.minimum(at + 1, len(numbers) - 1)], _ABSENT)
    if with_n.any():
        n = np.where(with_n, numbers[at + fields - 1], _ABSENT)
    return per_face, p, t, n


def _per_line(first: np.ndarray, newlines: np.ndarray) -> np.ndarray:
    """How many corners (their first bytes, in order) each line (its newline) holds."""
    if len(first) == 3 * len(newlines) and (first[2::3] < newlines).all() and (first[3::3] > newlines[:-1]).all():
        return np.full(len(newlines), 3)                       # triangles: no search
    return np.diff(np.searchsorted(first, newlines), prepend=0)


def _per_corner(mask: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """How many bytes of each corner (from its first to its last byte) the mask marks."""
    if not mask.any():
        return np.zeros(len(first), np.int64)
    count = np.cumsum(mask, dtype=np.int64)
    return count[last] - count[first] + mask[first]


def _resolve(i: np.ndarray | None, kind: np.ndarray, faces: np.ndarray, per_face: np.ndarray) -> np.ndarray | None:
    """Corners' OBJ indices (from 1, negative: relative to the end; None: none names one) of elements
    defined on the lines marked `kind`, to indices from 0 (as _index); -1 where _ABSENT, -2 where out of
    range of the elements defined before the corner's face line (`faces` marks those, `per_face` counts their
    corners); None for None."""
    if i is None:
        return None
    before = np.cumsum(kind)[faces]
    if before[0] == before[-1]:                                # all defined first: one count
        count = before[0]
        if i.min() > 0 and i.max() <= count:                   # none relative, none absent or past the end
            return i - 1
    else:
        count = np.repeat(before, per_face)
    r = np.where(i > 0, i - 1, count + i)
    return np.where(i == _ABSENT, -1, np.where((r >= 0) & (r < count), r, -2))


def _weld(p: np.ndarray, t: np.ndarray | None, n: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Each corner's vertex, the vertices numbered in order of first use of their (p, t, n) index triple
    (t or n None: no corner names one), and the corner that first uses each vertex."""
    corner = np.arange(len(p))
    first = np.full(p.max() + 1, len(p))
    np.minimum.at(first, p, corner)
    first_use = first[p]
    if not all(i is None or np.array_equal(i[first_use], i) for i in (t, n)):
        # a position with several (t, n): key by position and the (t, n) pair's rank
        t, n = (np.full(len(p), -1) if i is None else i for i in (t, n))
        _, pair = np.unique((t + 1) * (n.max() + 2) + n + 1, return_inverse=True)
        _, key = np.unique(p * (pair.max() + 1) + pair, return_inverse=True)
        first = np.full(key.max() + 1, len(p))
        np.minimum.at(first, key, corner)
        first_use = first[key]
    is_first = first_use == corner
    return (np.cumsum(is_first) - 1)[first_use], np.flatnonzero(is_first)


def _fan(vertex: np.ndarray, per_face: np.ndarray) -> np.ndarray:
    """Triangles (c0, ci, ci+1) of each face's corners."""
    if (per_face == 3).all():
        return vertex.reshape(-1, 3)
    fan = np.maximum(per_face - 2, 0)
    face = np.repeat(np.arange(len(per_face)), fan)
    base = (np.cumsum(per_face) - per_face)[face]
    i = np.arange(len(face)) - np.repeat(np.cumsum(fan) - fan, fan) + 1
    return vertex[np.stack([base, base + i, base + i + 1], axis=1)]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted average of the adjacent face normals (Mitsuba's recompute_vertex_normals).

    Computed on coordinate rows (x, y, z of every triangle corner), BLOCK faces at a time; a vertex's sum
    runs over the faces' first corners in face order, then their second, then their third."""
    corners = np.ascontiguousarray(faces.T)
    weighted = np.empty((3, 3, len(faces)))                              # coordinate, corner, face
    for block, corner in corner_blocks(vertices, corners):
        _angle_weighted(corner, weighted[:, :, block])
    index = corners.ravel()
    out = np.stack([np.bincount(index, weighted[k].ravel(), minlength=len(vertices)) for k in range(3)])
    length = length_rows(out)
    return np.ascontiguousarray(np.divide(out, length, out=np.zeros_like(out), where=length > 0).T)


def _angle_weighted(corner: list[np.ndarray], weighted: np.ndarray) -> None:
    """Into `weighted` (coordinate, corner, face): each face's unit normal times its angle at the corner,
    from the faces' corner rows (corner_blocks)."""
    edge = [corner[(i + 1) % 3] - corner[i] for i in range(3)]           # c0 -> c1, c1 -> c2, c2 -> c0
    n = cross_rows(edge[2], edge[0])                                     # = edge[0] x -edge[2], exactly
    length = length_rows(n)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    for e in edge:                                                       # to unit vectors, in place
        np.divide(e, np.maximum(length_rows(e), 1e-30), out=e)
    # the angle at corner i, between its edges to c(i+1) and to c(i+2) (the latter is -edge[i - 1])
    for i in range(3):
        cos = dot_rows(edge[i], edge[i - 1])
        np.negative(cos, out=cos)
        np.multiply(n, np.arccos(np.clip(cos, -1, 1, out=cos), out=cos), out=weighted[:, i])


def corner_blocks(vertices: np.ndarray, corners: np.ndarray) -> Iterator[tuple[slice, list[np.ndarray]]]:
    """The triangles BLOCK at a time: (their slice, the coordinate rows (3, triangles) of their first,
    second and third corners); `corners`: the faces' vertex indices as rows (3, triangles)."""
    rows, corners = np.ascontiguousarray(vertices.T), np.ascontiguousarray(corners)
    for a in range(0, corners.shape[1], BLOCK):
        block = slice(a, a + BLOCK)
        yield block, [np.take(rows, corners[i, block], axis=1) for i in range(3)]


def dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of coordinate rows (3, n)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of coordinate rows (3, n)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), np.result_type(a, b))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):     # written into one array, not stacked
        np.subtract(a[j] * b[k], a[k] * b[j], out=out[i])
    return out


def bounding_box(points: list[np.ndarray]) -> np.ndarray:
    """(2, 3) least and greatest coordinates over arrays of points (n, 3), column by column (faster than
    reducing over axis 0 of an (n, 3) array)."""
    lo = [[p[:, k].min() for k in range(3)] for p in points]
    hi = [[p[:, k].max() for k in range(3)] for p in points]
    return np.array([np.min(lo, axis=0), np.max(hi, axis=0)])


def length_rows(a: np.ndarray) -> np.ndarray:
    """Euclidean lengths (1, n) of coordinate rows (3, n)."""
    return np.sqrt(dot_rows(a, a))[None]


# the texture coordinates' pairs Mitsuba 3.9.1's ply reads, the first present (it reads no texture_s, texture_t)
PLY_TEXCOORDS = (("u", "v"), ("texture_u", "texture_v"), ("s", "t"))


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, Attributes]:
    """Vertices, triangles, per-vertex normals (None unless the file has nx, ny, nz), texture coordinates
    (None unless it has one of PLY_TEXCOORDS' pairs) and the vertex and face attributes Mitsuba makes of the
    other properties (tracer.ply_attributes) of a PLY file, ASCII or binary (read with `plyfile`). Faces must
    be triangles, as Mitsuba requires."""
    try:
        stat = path.stat()
        return _read_ply(path.resolve(), stat.st_size, stat.st_mtime_ns)
    except OSError as e:
        raise MeshError(f"cannot read mesh {path}: {e.strerror}") from None


@lru_cache(maxsize=16)
def _read_ply(path: Path, size: int, mtime_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                             np.ndarray | None, Attributes]:
    from plyfile import PlyData, PlyParseError

    try:
        try:   # binary triangles in bulk (plyfile checks that every face has 3 corners)
            ply = PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3, "vertex_index": 3}})
        except PlyParseError:   # polygons, refused below, or a broken file, which this reports
            ply = PlyData.read(str(path))
        _check_length(path, ply)
        vertex, face = ply["vertex"], ply["face"]
        names = vertex.data.dtype.names
        vertices = np.stack([np.asarray(vertex[k], float) for k in "xyz"], axis=1)
        normals = np.stack([np.asarray(vertex[k], float) for k in ("nx", "ny", "nz")], axis=1) \
            if all(k in names for k in ("nx", "ny", "nz")) else None
        uvs = next((np.stack([np.asarray(vertex[k], float) for k in pair], axis=1) for pair in PLY_TEXCOORDS
                    if all(k in names for k in pair)), None)
        index = "vertex_indices" if "vertex_indices" in face.data.dtype.names else "vertex_index"
        rows = face[index]
        attributes = _attributes(vertex, face, index)
    except MeshError:
        raise
    except ply_attributes.Refused as e:
        raise MeshError(f"{path}: {e}") from None
    except Exception as e:    # whatever plyfile raises on a malformed file (PlyParseError, ValueError, ...)
        raise MeshError(f"{path}: not a readable PLY mesh with vertex x, y, z and face vertex_indices "
                        f"({type(e).__name__}: {e})") from None
    if rows.dtype == object:    # a list per face (ASCII files, polygons)
        if any(len(r) != 3 for r in rows):
            raise MeshError(f"{path}: only triangular faces are supported (as in Mitsuba)")
        rows = np.stack(rows) if len(rows) else np.zeros((0, 3))
    faces = np.array(rows, np.int64).reshape(-1, 3)
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
    for a in (vertices, faces, normals, uvs):
        if a is not None:
            a.flags.writeable = False
    return vertices, faces, normals, uvs, attributes


def _attributes(vertex, face, index: str) -> Attributes:
    """The vertex and face attributes of a PLY file's elements (plyfile's), as Mitsuba names them."""
    from plyfile import PlyListProperty

    names = vertex.data.dtype.names
    texcoords = next((set(pair) for pair in PLY_TEXCOORDS if all(k in names for k in pair)), set())
    out, unread = {}, []
    elements = ((vertex, "vertex_", VERTEX_RESERVED | texcoords), (face, "face_", FACE_RESERVED | {index}))
    for element, kind, reserved in elements:
        properties = [(p.name, isinstance(p, PlyListProperty)) for p in element.properties]
        found = ply_attributes.read(element.data, properties, kind, reserved)
        out.update(found.values)
        unread += [found.unread] if found.unread else []
    return Attributes(out, "; ".join(unread))


def _check_length(path: Path, ply) -> None:
    """Refuses data after the elements the header declares (a header that claims fewer faces than the file
    holds would otherwise drop the rest silently): ASCII files by their lines, binary ones by their bytes."""
    from plyfile import PlyListProperty

    with path.open("rb") as f:
        head = f.read(1 << 16)
        while b"end_header" not in head and (more := f.read(1 << 16)):
            head += more
    start = head.index(b"\n", head.index(b"end_header")) + 1          # plyfile found both
    declared = sum(len(e.data) for e in ply.elements)
    if ply.text:
        body = path.read_bytes()[start:]
        extra = len([line for line in body.splitlines() if line.strip()]) - declared
        what = f"{extra} more lines"
    else:
        size = 0
        for e in ply.elements:
            for prop in e.properties:
                if isinstance(prop, PlyListProperty):
                    length, value = (np.dtype(t).itemsize for t in prop.list_dtype())
                    column = e.data[prop.name]
                    corners = column.size if column.dtype != object else sum(len(r) for r in column)
                    size += len(e.data) * length + corners * value
                else:
                    size += len(e.data) * np.dtype(prop.dtype()).itemsize
        extra = path.stat().st_size - start - size
        what = f"{extra} more bytes"
    if extra > 0:
        counts = ", ".join(f"{len(e.data)} {e.name}" for e in ply.elements)
        raise MeshError(f"{path}: the file holds {what} than its header declares ({counts}): a header that "
                        "undercounts its elements")
