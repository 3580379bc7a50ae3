"""OBJ reading: the bulk parser of plain files gives exactly the statement-by-statement reader's mesh."""
from pathlib import Path

import numpy as np
import pytest

from tracer.meshes import _parse_plain, _parse_statements

MESHES = Path(__file__).resolve().parents[1] / "mitsuba_scenes" / "meshes"


def _random_plain(seed: int, n_vertices: int = 40, n_faces: int = 120) -> str:
    """Vertices interleaved with faces that name earlier ones, in scrambled order, with comments,
    blank lines and statements the reader ignores."""
    rng = np.random.default_rng(seed)
    lines = ["# a generated mesh", "o thing", ""]
    lines += [f"v {x:.6g} {y:.6g} {z:.6g}" for x, y, z in rng.normal(size=(3, 3))]
    for k in range(3, n_vertices):
        lines.append("v  %.6g %.6g %.6g" % tuple(rng.normal(size=3)))
        for _ in range(n_faces // n_vertices):
            lines.append("f %d %d %d" % tuple(rng.choice(k + 1, 3, replace=False) + 1))
        if k % 7 == 0:
            lines += ["vt 0.5 0.5", "g part", "s off", "# comment"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("seed", range(5))
def test_plain_files_parse_in_bulk_to_the_same_mesh(seed):
    text = _random_plain(seed)
    bulk, lines = _parse_plain(text), _parse_statements(text, Path("x.obj"))
    assert bulk is not None
    for a, b in zip(bulk, lines):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("change", [
    lambda t: t.replace("f 1", "f -1", 1),                # a relative index
    lambda t: t.replace("\nf ", "\nf 1/1/1 ", 1),         # a corner with texture and normal indices
    lambda t: t + "f 1 2 3 4\n",                          # a quad, fanned
    lambda t: t.replace("\nv ", "\n  v ", 1),             # indented
    lambda t: t.replace("\nv ", "\nv\t", 1),              # a tab
    lambda t: t + "vn 0 0 1\n",                           # normals
    lambda t: t + "f 1 2 999\n",                          # a vertex not (yet) defined
    lambda t: t.replace("\nv ", "\nv 1 ", 1),             # four coordinates
    lambda t: t.replace("\nf 1 ", "\nf 1.5 ", 1),         # not an integer
], ids=["relative", "slashes", "quad", "indented", "tab", "normals", "undefined", "four", "float index"])
def test_anything_else_goes_statement_by_statement(change):
    text = change(_random_plain(0))
    assert text != _random_plain(0)
    assert _parse_plain(text) is None


@pytest.mark.parametrize("mesh", sorted(MESHES.glob("*.obj")), ids=lambda p: p.name)
def test_project_meshes_parse_in_bulk_to_the_same_mesh(mesh):
    text = mesh.read_text()
    bulk, lines = _parse_plain(text), _parse_statements(text, mesh)
    assert bulk is not None
    for a, b in zip(bulk, lines):
        np.testing.assert_array_equal(a, b)
