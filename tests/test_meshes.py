"""OBJ reading: the bulk parser gives exactly the statement-by-statement reader's mesh, and both key vertices
by (position, texture coordinate, normal) as Mitsuba does; vertex normals are those of a plain formulation."""
from pathlib import Path

import numpy as np
import pytest

from tracer.meshes import MeshError, _parse_bulk, _parse_statements, read_obj, vertex_normals
from validation.benchmark.mesh_scene import torus

from .test_mesh_formats import assert_same, mitsuba_mesh, ours
from .test_xml_features import mi  # noqa: F401  (the fixture)

SCENES = Path(__file__).resolve().parents[1] / "mitsuba_scenes"
NUMBER_FORMATS = ("%.6g", "%.17g", "%.3e", "%.7f", "%d")


def _random_obj(seed: int, n_vertices: int = 40, n_faces: int = 120) -> str:
    """Positions, texture coordinates and normals interleaved with faces that name earlier ones, in the
    corner forms p, p/t, p/t/n and p//n (only the last two in half of the files), absolute or relative, with
    1 to 6 corners; numbers in several formats; comments, blank and indented-comment lines, tabs,
    statements the reader ignores, and positions with colours."""
    rng = np.random.default_rng(seed)
    lines, counts = ["# a generated mesh", "o thing", "", "  # indented comment", " \t "], [0, 0, 0]

    def number() -> str:
        x = rng.normal() * 10.0 ** rng.integers(-3, 3)
        return str(rng.choice(NUMBER_FORMATS)) % x if rng.random() < 0.9 else str(rng.choice(["-0", ".5", "5.", "+1"]))

    def index(kind: int) -> str:
        i = int(rng.integers(counts[kind]))
        return str(i + 1) if rng.random() < 0.8 else str(i - counts[kind])

    def corner(form: str) -> str:
        return {"p": index(0), "p/t": f"{index(0)}/{index(1)}", "p/t/n": f"{index(0)}/{index(1)}/{index(2)}",
                "p//n": f"{index(0)}//{index(2)}"}[form]

    forms = [["p", "p/t", "p/t/n", "p//n"], ["p", "p/t"], ["p/t/n"], ["p/t/n", "p//n"]][seed % 4]  # some with normals
    for k in range(n_vertices):
        sep = "\t" if rng.random() < 0.1 else " "
        lines.append(sep.join(["v", number(), number(), number()] + ([number()] * 3 if rng.random() < 0.1 else [])))
        lines += [f"vt {number()} {number()}", f"vn{sep}{number()} {number()} {number()}"]
        counts = [c + 1 for c in counts]
        for _ in range(n_faces // n_vertices):
            form = str(rng.choice(forms))
            lines.append("f " + " ".join(corner(form) for _ in range(int(rng.integers(1, 7)))))
        if k % 7 == 0:
            lines += ["g part", "s off", "usemtl m", "# comment", "l 1 2", ""]
    return "\n".join(lines) + ("\n" if seed % 2 else "")


def assert_same_mesh(a, b):
    assert a is not None and b is not None
    for x, y in zip(a, b):
        assert (x is None) == (y is None)
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f")


@pytest.mark.parametrize("seed", range(12))
def test_files_parse_in_bulk_to_the_same_mesh(seed):
    text = _random_obj(seed)
    assert_same_mesh(_parse_bulk(text.encode()), _parse_statements(text, Path("x.obj")))


@pytest.mark.parametrize("form", ["{0}", "{0}//{0}", "{0}/{0}/{0}", "{0}/{0}"])
@pytest.mark.parametrize("quads", [False, True])
def test_exported_meshes_parse_in_bulk_to_the_same_mesh(form, quads):
    """A smooth torus as exporters write it: one normal and texture coordinate per position, triangles or
    quads."""
    vertices, triangles = torus(300)
    acb, bcd = np.split(triangles, 2)                 # the grid's cells (a, b, d, c) as two triangles
    faces = np.stack([acb[:, 0], acb[:, 1], bcd[:, 2], acb[:, 2]], axis=1) if quads else triangles
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}\nvt {x:.4f} {y:.4f}\nvn {z:.6f} {x:.6f} {y:.6f}" for x, y, z in vertices]
    lines += ["f " + " ".join(form.format(i) for i in face) for face in faces + 1]
    text = "\n".join(lines) + "\n"
    assert_same_mesh(_parse_bulk(text.encode()), _parse_statements(text, Path("x.obj")))



@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_windows_and_old_mac_line_ends_are_read_in_bulk_as_python_reads_text(tmp_path, monkeypatch, newline):
    import tracer.meshes

    text = _random_obj(3)
    (tmp_path / "lf.obj").write_text(text)
    (tmp_path / "other.obj").write_bytes(text.replace("\n", newline).encode())
    expected = read_obj(tmp_path / "lf.obj")
    monkeypatch.setattr(tracer.meshes, "_parse_statements", None)     # the bulk parser reads it
    assert_same_mesh(read_obj(tmp_path / "other.obj"), expected)


@pytest.mark.parametrize("change", [
    lambda t: t.replace("\nv ", "\n  v ", 1),             # an indented statement
    lambda t: t.replace("\nf ", "\nf 1.5 ", 1),           # not an integer
    lambda t: t.replace("\nf ", "\nf +1 ", 1),            # a sign Python's int reads
    lambda t: t.replace("\nf ", "\nf 1/1/1/1 ", 1),       # four indices
    lambda t: t.replace("\nf ", "\nf 1/ ", 1),            # an empty texture coordinate index
    lambda t: t.replace("\nf ", "\nf /1 ", 1),            # no position index
    lambda t: t.replace("\nf ", "\nf 1--1 ", 1),          # a misplaced sign
    lambda t: t.replace("\nf ", "\nf 0 ", 1),             # index 0
    lambda t: t.replace("\nf ", "\nf 999 ", 1),           # a vertex not (yet) defined
    lambda t: t.replace("\nf ", "\nf -999 ", 1),          # a relative index before the first
    lambda t: t.replace("\nf ", "\nf 99999999999999999999 ", 1),   # beyond 64 bits
    lambda t: t.replace("\nv ", "\nv 1_0 ", 1),           # a number Python's float reads
    lambda t: t.replace("\nv ", "\nv\n", 1),              # a keyword alone
    lambda t: t.replace("\nv ", "\nv 1 2\nv ", 1),        # two coordinates
    lambda t: t.replace("o thing", "o thing\x0cv 1 2 3"),  # a line break of Python's splitlines
    lambda t: t.replace("o thing", "o d\u00e9j\u00e0"),   # not ASCII
], ids=["indented", "float index", "plus", "four indices", "trailing slash", "leading slash", "sign", "zero",
        "undefined", "relative undefined", "huge", "underscore", "bare keyword", "two coordinates", "form feed",
        "non-ascii"])
def test_anything_else_goes_statement_by_statement(change):
    text = change(_random_obj(0))
    assert text != _random_obj(0)
    assert _parse_bulk(text.encode()) is None


MUTATIONS = list("0123456789-+/ \t\nfvnt#.eE_x") + ["\r", "\x0c", "\x1f", "\u00e9", "nan", "//", "f ", "v ", "vn ",
                                                   "vt ", "\n  ", "1e400", "-0"]


@pytest.mark.parametrize("seed", range(3))
def test_mutated_files_parse_in_bulk_to_the_same_mesh_or_not_at_all(seed):
    """Small generated files with one to three characters or words inserted, deleted or replaced: the bulk
    parser gives the statement parser's mesh, or None (always None where the statement parser refuses)."""
    rng = np.random.default_rng(seed)
    for _ in range(100):
        text = _random_obj(int(rng.integers(12)), n_vertices=8, n_faces=16)
        for _ in range(int(rng.integers(1, 4))):
            i, piece = int(rng.integers(len(text))), str(rng.choice(MUTATIONS))
            inserted, deleted, replaced = text[:i] + piece + text[i:], text[:i] + text[i + 1:], text[:i] + piece + text[i + 1:]
            text = [inserted, deleted, replaced][rng.integers(3)]
        try:
            lines = _parse_statements(text, Path("x.obj"))
        except MeshError:
            lines = None
        bulk = _parse_bulk(text.encode())
        if bulk is not None:
            assert_same_mesh(bulk, lines)


@pytest.mark.parametrize("mesh", sorted(SCENES.glob("*/*.obj")), ids=lambda p: p.name)
def test_project_meshes_parse_in_bulk_to_the_same_mesh(mesh):
    text = mesh.read_text()
    assert_same_mesh(_parse_bulk(text.encode()), _parse_statements(text, mesh))


def test_vertices_are_keyed_by_texture_coordinates_too_as_in_mitsuba(tmp_path, mi):
    """A quad whose corners share positions across a texture seam: Mitsuba makes one vertex per (position,
    texture coordinate) and smooths normals on each side of the seam separately."""
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0.5\nv 0 1 0\nv 2 0 1\n"
                                    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                                    "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\nf 2/4 5/2 3/1\n")
    mesh = ours(tmp_path, '<shape type="obj"><string name="filename" value="m.obj"/></shape>')
    assert len(mesh.vertices) == 7
    assert_same(mesh, mitsuba_mesh(mi, {"type": "obj", "filename": str(tmp_path / "m.obj")}))


def test_vertex_normals_are_the_plain_formulation():
    """Bit for bit the angle-weighted sum written per face with numpy.add.at, on a mesh with degenerate
    triangles and unused vertices."""
    rng = np.random.default_rng(5)
    vertices = rng.normal(size=(300, 3))
    faces = rng.integers(0, 290, size=(1000, 3))
    faces[:10, 1] = faces[:10, 0]                     # degenerate
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
        np.add.at(out, faces[:, i], n * np.arccos(np.clip(np.sum(d0 * d1, axis=1), -1, 1))[:, None])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    expected = np.divide(out, length, out=np.zeros_like(out), where=length > 0)
    assert np.array_equal(vertex_normals(vertices, faces), expected)


def test_a_mesh_light_of_no_area_renders_black_without_warnings():
    """Its samples have infinite density (it emits no power, as in Mitsuba): no NaN from dividing by its area."""
    import warnings

    import tracer
    from tracer.rendering import render

    scene = tracer.load_scene(Path(__file__).resolve().parents[1] / "mitsuba_scenes/stress/zero_area_light.xml")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image = render(scene, "path", spp=4, max_depth=3).image
    assert not image.any()
