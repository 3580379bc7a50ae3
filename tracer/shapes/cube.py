"""Mitsuba's `cube`: the mesh of the cube [-1, 1]^3 placed by to_world, as Mitsuba builds it (cube.cpp): four
vertices per face sharing its normal (flat shading), each face's corners at texture coordinates (0, 1),
(1, 1), (1, 0), (0, 0), two triangles per face. A mesh (tracer.shapes.mesh) like any other once built."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import ShapeArgs
from .mesh import Mesh, MeshFile, _place

PLUGINS = {"cube": ("to_world", "flip_normals", "silhouette_sampling_weight")}
NORMALS = ((0, -1, 0), (0, 1, 0), (1, 0, 0), (0, 0, 1), (-1, 0, 0), (0, 0, -1))   # the faces, in Mitsuba's order
CORNERS = (1, 5, 4, 0, 3, 2, 6, 7, 1, 3, 7, 5, 5, 7, 6, 4, 4, 6, 2, 0, 3, 1, 0, 2)  # corner c: bit k = axis k's sign
FACE_UV = ((0, 1), (1, 1), (1, 0), (0, 0))


def local_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (24, 3), faces (12, 3), uvs (24, 2)) of the cube in its own space."""
    corners = np.array([[1.0 if c & (1 << k) else -1.0 for k in range(3)] for c in range(8)])
    vertices = corners[list(CORNERS)]
    faces = np.array([f for s in range(6) for f in ((4 * s, 4 * s + 1, 4 * s + 2), (4 * s + 3, 4 * s, 4 * s + 2))])
    uvs = np.tile(np.array(FACE_UV, float), (6, 1))
    return vertices, faces.astype(np.uint32), uvs


def from_xml(ctx, props, a: ShapeArgs) -> Mesh:
    props.finish()
    vertices, faces, uvs = local_mesh()
    return _place(MeshFile(a, Path("cube"), 0, face_normals=True), (vertices, faces, None, uvs, None))
