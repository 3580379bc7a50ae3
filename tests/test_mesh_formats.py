"""`ply` (through plyfile) and `serialized` (Mitsuba's zlib-compressed format) shapes: the same vertices,
triangles and normals as Mitsuba loads from the same files, and broken files refused with their name."""
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from tracer import load_scene

from .test_xml_loader import assert_located, line_of, write_scene
from .test_xml_features import mi, scene_errors  # noqa: F401  (mi: the fixture)

RNG = np.random.default_rng(3)
VERTICES = RNG.normal(size=(6, 3))
FACES = np.array([[0, 1, 2], [2, 1, 3], [3, 4, 5], [0, 2, 5]])
NORMALS = RNG.normal(size=(6, 3))


def write_ply(path: Path, text: bool, normals: bool = False, faces=FACES, extra: dict | None = None) -> Path:
    """`extra`: more float32 vertex properties by name."""
    extra = extra or {}
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")] + ([("nx", "f4"), ("ny", "f4"), ("nz", "f4")] if normals else [])
    vertex = np.empty(len(VERTICES), fields + [(k, "f4") for k in extra])
    for i, k in enumerate("xyz"):
        vertex[k] = VERTICES[:, i]
        if normals:
            vertex["n" + k] = NORMALS[:, i]
    for k, v in extra.items():
        vertex[k] = v
    face = np.empty(len(faces), [("vertex_indices", "i4", (len(faces[0]),))])
    face["vertex_indices"] = faces
    PlyData([PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")], text=text).write(str(path))
    return path


def serialized_mesh(vertices, faces, normals=None, version=4, name=b"part") -> bytes:
    """One mesh in the layout Mitsuba documents (single precision)."""
    flags = 0x1000 | (0x1 if normals is not None else 0)
    body = struct.pack("<I", flags) + (name + b"\0" if version == 4 else b"")
    body += struct.pack("<QQ", len(vertices), len(faces)) + np.asarray(vertices, "<f4").tobytes()
    if normals is not None:
        body += np.asarray(normals, "<f4").tobytes()
    body += np.asarray(faces, "<u4").tobytes()
    return struct.pack("<HH", 0x041C, version) + zlib.compress(body)


def write_serialized(path: Path, meshes: list[bytes], version=4) -> Path:
    offsets, data = [], b""
    for m in meshes:
        offsets.append(len(data))
        data += m
    data += b"".join(struct.pack("<Q" if version == 4 else "<I", o) for o in offsets)
    path.write_bytes(data + struct.pack("<I", len(meshes)))
    return path


def mitsuba_mesh(mi, props: dict) -> dict:
    params = mi.traverse(mi.load_dict(props))
    return {k: np.array(params[k]) for k in ("vertex_positions", "faces", "vertex_normals")}


def ours(tmp_path, shape: str):
    return load_scene(write_scene(tmp_path, shape, name="mesh.xml")).meshes[0]


def assert_same(mesh, ref):
    assert np.allclose(mesh.vertices.ravel(), ref["vertex_positions"], atol=1e-6)
    assert np.array_equal(mesh.faces.ravel(), ref["faces"])
    assert np.allclose(mesh.normals.ravel(), ref["vertex_normals"], atol=1e-5)


@pytest.mark.parametrize("text", [True, False])
@pytest.mark.parametrize("normals", [True, False])
def test_ply_as_mitsuba(tmp_path, text, normals, mi):
    write_ply(tmp_path / "m.ply", text, normals)
    mesh = ours(tmp_path, '<shape type="ply"><string name="filename" value="m.ply"/></shape>')
    assert_same(mesh, mitsuba_mesh(mi, {"type": "ply", "filename": str(tmp_path / "m.ply")}))


@pytest.mark.parametrize("version", [3, 4])
@pytest.mark.parametrize("index", [0, 1])
def test_serialized_as_mitsuba(tmp_path, version, index, mi):
    parts = [serialized_mesh(VERTICES, FACES, None, version), serialized_mesh(VERTICES[::-1], FACES, NORMALS, version)]
    path = write_serialized(tmp_path / "m.serialized", parts, version)
    mesh = ours(tmp_path, f'<shape type="serialized"><string name="filename" value="m.serialized"/>'
                          f'<integer name="shape_index" value="{index}"/></shape>')
    ref = mitsuba_mesh(mi, {"type": "serialized", "filename": str(path), "shape_index": index})
    assert_same(mesh, ref)
    if index == 1:       # the stored normals, normalised
        assert np.allclose(mesh.normals, NORMALS / np.linalg.norm(NORMALS, axis=1, keepdims=True), atol=1e-6)


@pytest.mark.parametrize("make, words", [
    (lambda p: write_ply(p / "m.ply", True, faces=np.array([[0, 1, 2, 3]])), "triangular"),
    (lambda p: write_ply(p / "m.ply", False, faces=np.array([[0, 1, 2, 3]])), "triangular"),
    (lambda p: (p / "m.ply").write_text("ply\nformat ascii 1.0\nbogus\n"), "PLY"),
])
def test_bad_ply_is_located(tmp_path, make, words):
    make(tmp_path)
    path = write_scene(tmp_path, '\n    <shape type="ply"><string name="filename" value="m.ply"/></shape>')
    (error,) = scene_errors(path)
    assert_located(error, path, line_of(path, 'type="ply"'))
    assert "m.ply" in error and words in error


@pytest.mark.parametrize("data, index, words", [
    (b"\x1c\x04\x05\x00" + b"\0" * 16, 0, "version 5"),
    (b"PK\x03\x04" + b"\0" * 16, 0, "0x041C"),
    (None, 2, "out of range"),
])
def test_bad_serialized_is_located(tmp_path, data, index, words):
    file = tmp_path / "m.serialized"
    if data is None:
        write_serialized(file, [serialized_mesh(VERTICES, FACES)])
    else:
        file.write_bytes(data)
    path = write_scene(tmp_path, f'\n    <shape type="serialized"><string name="filename" value="m.serialized"/>'
                                 f'<integer name="shape_index" value="{index}"/></shape>')
    (error,) = scene_errors(path)
    assert_located(error, path, line_of(path, 'type="serialized"'))
    assert words in error
