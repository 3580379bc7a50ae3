"""Reading Mitsuba's `serialized` meshes (versions 3 and 4 of the format, as Mitsuba's own
src/shapes/serialized.cpp documents it).

A file is a sequence of meshes, each a little-endian header (uint16 0x041C, uint16 version) followed by a
zlib stream: uint32 flags (0x1 normals, 0x2 texture coordinates, 0x8 colours, 0x2000 double precision),
the shape's null-terminated name (version 4 only), uint64 vertex and triangle counts, positions, normals,
texture coordinates and colours as present, then 3 uint32 indices per triangle. The file ends with the
offset of each mesh (uint64 in version 4, uint32 in version 3) and the uint32 count of meshes.
"""
from __future__ import annotations

import struct
import zlib
from functools import lru_cache
from pathlib import Path

import numpy as np

from .meshes import MeshError

MAGIC = 0x041C
HAS_NORMALS, HAS_TEXCOORDS, HAS_COLORS, DOUBLE_PRECISION = 0x1, 0x2, 0x8, 0x2000


def read_serialized(path: Path, shape_index: int = 0):
    """Vertices, triangles, per-vertex normals and texture coordinates (None when not stored) of mesh
    `shape_index`."""
    try:
        stat = path.stat()
        return _read(path.resolve(), shape_index, stat.st_size, stat.st_mtime_ns)
    except OSError as e:
        raise MeshError(f"cannot read mesh {path}: {e.strerror}") from None


@lru_cache(maxsize=16)
def _read(path: Path, shape_index: int, size: int, mtime_ns: int):
    data = path.read_bytes()
    if len(data) < 8:
        raise MeshError(f"{path}: not a serialized mesh (too short)")
    magic, version = struct.unpack_from("<HH", data, 0)
    if magic != MAGIC:
        raise MeshError(f"{path}: not a serialized mesh (no 0x041C header)")
    if version not in (3, 4):
        raise MeshError(f"{path}: serialized format version {version} unsupported; supported: 3, 4")
    offset = _offset(path, data, version, shape_index) if shape_index else 0   # the first mesh: at 0, as Mitsuba
    try:
        body = zlib.decompressobj().decompress(data[offset + 4:])
        return _mesh(body, version, path)
    except (zlib.error, struct.error, ValueError) as e:
        raise MeshError(f"{path}: corrupt or truncated serialized mesh {shape_index} ({e})") from None


def _offset(path: Path, data: bytes, version: int, shape_index: int) -> int:
    """Where mesh `shape_index` starts, from the table at the file's end."""
    count = struct.unpack_from("<I", data, len(data) - 4)[0]
    entry = 8 if version == 4 else 4
    if count * entry + 4 > len(data):
        raise MeshError(f"{path}: corrupt or truncated serialized mesh (its table names {count} meshes, more than "
                        f"the file's {len(data)} bytes can hold)")
    if shape_index >= count:
        raise MeshError(f"{path}: shape_index {shape_index} out of range (the file holds {count} meshes)")
    offset = struct.unpack_from("<Q" if version == 4 else "<I", data, len(data) - 4 - entry * (count - shape_index))[0]
    if offset + 4 > len(data) or data[offset:offset + 4] != data[:4]:
        raise MeshError(f"{path}: corrupt or truncated serialized mesh (mesh {shape_index}'s offset {offset} "
                        "points at no mesh header)")
    return offset


def _mesh(body: bytes, version: int, path: Path):
    flags = struct.unpack_from("<I", body, 0)[0]
    pos = 4
    if version == 4:
        pos = body.index(b"\0", pos) + 1
    n_vertices, n_faces = struct.unpack_from("<QQ", body, pos)
    pos += 16
    real = np.dtype("<f8" if flags & DOUBLE_PRECISION else "<f4")

    def take(dtype, n):
        nonlocal pos
        if pos + n * np.dtype(dtype).itemsize > len(body):
            raise ValueError(f"the mesh's data ends early: {n_vertices} vertices and {n_faces} triangles announced")
        a = np.frombuffer(body, dtype, n, pos)
        pos += a.nbytes
        return a

    vertices = take(real, 3 * n_vertices).reshape(-1, 3).astype(float)
    normals = take(real, 3 * n_vertices).reshape(-1, 3).astype(float) if flags & HAS_NORMALS else None
    uvs = take(real, 2 * n_vertices).reshape(-1, 2).astype(float) if flags & HAS_TEXCOORDS else None
    if flags & HAS_COLORS:
        take(real, 3 * n_vertices)
    faces = take(np.dtype("<u4"), 3 * n_faces).reshape(-1, 3).astype(np.int64)
    if not len(faces):
        raise MeshError(f"{path}: the mesh has no faces")
    if faces.max() >= n_vertices:
        raise MeshError(f"{path}: a triangle names vertex {faces.max()} of {n_vertices}")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: a vertex position is NaN or infinite")
    for a in (vertices, faces, normals, uvs):
        if a is not None:
            a.flags.writeable = False
    return vertices, faces, normals, uvs
