"""Mitsuba's `shapegroup` and `instance`: a group's meshes instanced (a two-level BVH: tracer.shapes.instance),
its other shapes expanded into copies (each member's to_world preceded by the instance's).
mitsuba_scenes/instancing.xml against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA; the same test failing with the two transforms composed in the wrong
order. Instanced against expanded: the same render to float rounding, and the same hits (points, normals,
texture coordinates, materials) ray by ray under a non-uniform scale, with shading normals as Mitsuba's
instance gives them (the group's vertex normals by M^-T); both checks fail on an instance's forward
transform in place of its inverse and on normals transformed by M."""
import numpy as np
import pytest

import tracer
import tracer.mitsuba_xml as loader
import tracer.shapes.instance as instance
from tracer.cli import main
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "instancing.xml"


def compared(seed: int):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=3)
    return compare_passes(plugin_passes(SCENE, "path", 3, seed), ref, ALPHA)


def test_instances_agree_with_mitsuba():
    result = compared(9500)
    assert result.verdict == "agree", result.summary()


def test_fails_with_the_transforms_composed_the_wrong_way(monkeypatch):
    add = loader._add_shape

    def swapped(ctx, scene, node, outer=None, prefix="", group=None):
        if outer is None or group is not None:     # outside instances, and the instanced meshes: as loaded
            return add(ctx, scene, node, outer, prefix, group)
        before = len(scene.shapes)
        add(ctx, scene, node, np.eye(4), prefix)          # the member as in the group ...
        for shape in scene.shapes[before:]:               # ... then the instance's transform after it
            if hasattr(shape, "to_world"):
                shape.to_world = shape.to_world @ outer
            elif hasattr(shape, "center"):
                shape.center = (np.linalg.inv(outer) @ np.append(shape.center, 1.0))[:3]

    monkeypatch.setattr(loader, "_add_shape", swapped)
    result = compared(9600)
    assert result.verdict == "disagree", result.summary()


def test_meshes_are_instanced_the_rest_expanded_and_said_so(capsys):
    scene = tracer.load_scene(SCENES / SCENE)
    assert (scene.instances, len(scene.meshes), len(scene.spheres), len(scene.rectangles)) == (3, 0, 3, 5)
    assert [(len(g.meshes), len(g.to_world)) for g in scene.groups] == [(1, 3)]
    assert main(["info", str(SCENES / SCENE)]) == 0
    out = capsys.readouterr().out
    assert "their meshes instanced (3 instance(s) of 1 mesh(es) held once, in a two-level BVH)" in out
    assert "instancing: shapegroup 'still_life': 3 instance(s) of 12 triangles" in out


def load(path, expand: bool = False, **overrides):
    """The scene, its shapegroups' meshes instanced, or (expand) copied per instance as the loader did before."""
    saved = loader.INSTANCED
    loader.INSTANCED = () if expand else saved
    try:
        return tracer.load_scene(path, **overrides)
    finally:
        loader.INSTANCED = saved


def forward_transform(monkeypatch):
    """The mistake of walking the group's BVH with the ray moved by M instead of M^-1."""
    init = instance.InstanceBVH.__init__
    monkeypatch.setattr(instance.InstanceBVH, "__init__", lambda self, lo, hi, to_local:
                        init(self, lo, hi, np.linalg.inv(to_local)))


def normals_by_m(monkeypatch):
    """The mistake of transforming normals by M instead of its inverse transpose."""
    matrix = instance.InstanceSet._matrix
    monkeypatch.setattr(instance.InstanceSet, "_matrix", lambda self, inst, mine:
                        (lambda c: c[:4] + c[:3])(matrix(self, inst, mine)))


def rendered(path, expand: bool) -> np.ndarray:
    from tracer.rendering import render

    return render(load(path, expand, width=24, height=24), "path", spp=16, seed=3, max_depth=3).image


def close_renders(a: np.ndarray, b: np.ndarray) -> bool:
    """Images of the same samples that differ by float rounding only: every pixel within 1e-4 of the image's
    peak but for at most 1% of them (a path that rounding sends past an edge), the means within 1e-4."""
    far = np.abs(a - b).max(axis=2) > 1e-4 * a.max()
    return far.mean() <= 0.01 and abs(a.mean() - b.mean()) <= 1e-4 * a.mean()


def test_instanced_and_expanded_renders_are_the_same():
    """Measured: at 48 x 48, 64 spp, the two differ by at most 1.5e-7 (float rounding), means equal to 8 digits."""
    assert close_renders(rendered(SCENES / SCENE, False), rendered(SCENES / SCENE, True))


def test_the_render_check_fails_on_a_forward_transform(monkeypatch):
    expanded = rendered(SCENES / SCENE, True)
    forward_transform(monkeypatch)
    assert not close_renders(rendered(SCENES / SCENE, False), expanded)


STRETCHED = """
<shape type="shapegroup" id="g">
    <shape type="obj"><string name="filename" value="ball.obj"/>
        <bsdf type="diffuse"><texture type="checkerboard" name="reflectance"/></bsdf></shape>
</shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><scale x="2" y="0.5" z="1"/>
    <rotate x="1" y="1" angle="30"/><translate x="-1.5"/></transform></shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><scale x="0.6" y="1.4" z="0.8"/>
    <rotate z="1" angle="-50"/><translate x="1.5" y="0.3"/></transform></shape>
<shape type="rectangle"><transform name="to_world"><translate z="-2"/></transform></shape>
"""


def write_ball(path, n: int = 12) -> None:
    """A UV sphere of 2 n (n - 1) triangles with texture coordinates and no normals (the loader computes
    its vertex normals in the group's space, as Mitsuba's mesh)."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, n + 1), np.linspace(0, 2 * np.pi, 2 * n + 1), indexing="ij")
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    uv = np.stack([phi / (2 * np.pi), theta / np.pi], -1).reshape(-1, 2)
    k = lambda i, j: i * (2 * n + 1) + j + 1    # noqa: E731
    faces = [(k(i, j), k(i + 1, j), k(i + 1, j + 1)) for i in range(1, n) for j in range(2 * n)]
    faces += [(k(i, j), k(i + 1, j + 1), k(i, j + 1)) for i in range(n - 1) for j in range(2 * n)]
    path.write_text("".join(f"v {a:.7f} {b:.7f} {c:.7f}\n" for a, b, c in v)
                    + "".join(f"vt {a:.7f} {b:.7f}\n" for a, b in uv)
                    + "".join(f"f {a}/{a} {b}/{b} {c}/{c}\n" for a, b, c in faces))


def hits(path, expand: bool) -> dict:
    """The surfaces that 4096 rays from around the two instances find (geometry.SceneGeometry, one kernel),
    as NumPy arrays, and the geometry."""
    import drjit as dr

    from tracer.geometry import SceneGeometry
    from tracer.jit import Array3f, UInt32

    geo = SceneGeometry(load(path, expand))
    rng = np.random.default_rng(5)
    o = rng.normal(size=(4096, 3)) * [0.3, 0.3, 0.3] + [0.0, -6.0, 1.0]
    d = rng.uniform([-3.0, -1.0, -1.5], [3.0, 1.0, 1.5], (4096, 3)) - o
    hit = geo.closest_hit(Array3f(*o.T), Array3f(*d.T), 0.0, float("inf"), UInt32(0xFFFFFFFF))
    surf = geo.surface(hit)
    out = {"t": hit.t, "p": surf.p, "n": surf.n, "ns": surf.ns, "u": surf.uv[0], "v": surf.uv[1],
           "material": surf.material, "b1": hit.b1, "b2": hit.b2, "prim": hit.prim}
    dr.eval(*out.values())
    return {k: np.array(x).T if k in ("p", "n", "ns") else np.array(x) for k, x in out.items()} | {"geo": geo}


def expected_shading_normals(group, h: dict, base: int) -> np.ndarray:
    """Mitsuba's instance's shading normals at hits h of the expanded scene (primitives from `base`, instance
    after instance): the group mesh's vertex normals (in its own space) interpolated, then M^-T, renormalised."""
    mesh = group.meshes[0]
    inst, tri = np.divmod(h["prim"] - base, len(mesh.faces))
    corners = mesh.normals[mesh.faces[tri]]
    b1, b2 = h["b1"][:, None], h["b2"][:, None]
    n = corners[:, 0] * (1 - b1 - b2) + corners[:, 1] * b1 + corners[:, 2] * b2
    n = np.einsum("nji,nj->ni", np.linalg.inv(group.transforms[inst, :3, :3]), n)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def disagreements(inst: dict, expanded: dict) -> list[str]:
    """What differs between the instanced and the expanded scene's hits (beyond float rounding, 1e-4), the
    instanced shading normals checked against expected_shading_normals."""
    geo = expanded["geo"]
    ball = (expanded["prim"] >= geo.meshes.base) & (expanded["prim"] < geo.meshes.base + geo.meshes.count)
    same = np.isclose(inst["t"], expanded["t"], rtol=1e-4) | (np.isinf(inst["t"]) & np.isinf(expanded["t"]))
    out = [] if same.mean() > 0.995 else [f"distances differ on {1 - same.mean():.1%} of the rays"]
    assert ball.sum() > 1000, ball.sum()    # most rays hit the two instances
    both = ball & same
    if not both.any():
        return out
    e = {k: v[both] for k, v in expanded.items() if k != "geo"}
    i = {k: v[both] for k, v in inst.items() if k != "geo"}
    ns = expected_shading_normals(inst["geo"].scene.groups[0], e, geo.meshes.base)
    for name, a, b in (("points", i["p"], e["p"]), ("normals", i["n"], e["n"]), ("shading normals", i["ns"], ns),
                       ("u", i["u"], e["u"]), ("v", i["v"], e["v"])):
        worst = np.abs(a - b).max()
        if worst > 1e-4:
            out.append(f"{name} differ by up to {worst:.3g}")
    if not np.array_equal(i["material"], e["material"]):
        out.append("materials differ")
    return out


@pytest.fixture(scope="module")
def stretched(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stretched")
    write_ball(folder / "ball.obj")
    path = write_scene(folder, STRETCHED)
    return path, hits(path, True)


def test_instanced_hits_are_the_expanded_ones_in_world_space(stretched):
    path, expanded = stretched
    assert disagreements(hits(path, False), expanded) == []
    # the shading normals are not the expanded copies' (vertex normals of the stretched mesh): M^-T matters
    geo = expanded["geo"]
    ball = (expanded["prim"] >= geo.meshes.base) & (expanded["prim"] < geo.meshes.base + geo.meshes.count)
    e = {k: v[ball] for k, v in expanded.items() if k != "geo"}
    assert np.abs(expected_shading_normals(load(path).groups[0], e, geo.meshes.base) - e["ns"]).max() > 0.05


@pytest.mark.parametrize("mistake, words", [(forward_transform, "distances differ"),
                                            (normals_by_m, "shading normals differ")])
def test_the_hit_check_fails_on_a_realistic_mistake(stretched, monkeypatch, mistake, words):
    path, expanded = stretched
    mistake(monkeypatch)
    assert any(words in d for d in disagreements(hits(path, False), expanded))


BALLS = """<default name="spp" value="64"/><default name="width" value="24"/><default name="height" value="16"/>
<integrator type="path"><integer name="max_depth" value="2"/></integrator>
<sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, -7, 1" target="0, 0, 0" up="0, 0, 1"/></transform>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="$width"/><integer name="height" value="$height"/>
        <rfilter type="box"/></film></sensor>
<emitter type="point"><point name="position" x="3" y="-4" z="4"/><rgb name="intensity" value="60"/></emitter>
<shape type="shapegroup" id="g"><shape type="obj"><string name="filename" value="ball.obj"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape></shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><scale x="2.5" y="0.4" z="1"/>
    <rotate z="1" angle="35"/><translate x="-1.2"/></transform></shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><scale x="0.5" y="0.5" z="1.8"/>
    <rotate x="1" angle="40"/><translate x="1.8"/></transform></shape>
"""


def test_stretched_smooth_instances_agree_with_mitsuba(tmp_path):
    """Two instances of a coarse smooth ball under strongly non-uniform scales, lit by a point light: the
    shading normals decide the image. Measured with validate check (48 x 32, 16 x 64 spp): the instanced
    tracer agrees (0/123 blocks rejected); the copies the tracer made before (vertex normals of the stretched
    triangles) disagree (33/123 rejected, image mean -0.50%), and so they do here (24/75 rejected, -0.60%)."""
    from tracer.rendering import render
    from validation.verdict.mitsuba_render import render_passes

    write_ball(tmp_path / "ball.obj", 8)
    path = write_scene(tmp_path, BALLS, header='<scene version="3.0.0">')
    scene = load(path)
    ours = np.stack([render(scene, "path", spp=SPP, seed=9700 + k, max_depth=2).image for k in range(PASSES)])
    result = compare_passes(ours, render_passes(path, PASSES, SPP, seed=12345), ALPHA)
    assert result.verdict == "agree", result.summary()


GROUP = '<shape type="shapegroup" id="g"><shape type="sphere"/></shape>'


@pytest.mark.parametrize("body, words", [
    ('<shape type="shapegroup" id="g"><shape type="sphere"><emitter type="area"/></shape></shape>'
     '<shape type="instance"><ref id="g"/></shape>', "emitter on a shape inside a shapegroup"),
    ('<shape type="sphere" id="s"/><shape type="instance"><ref id="s"/></shape>', "exactly one shapegroup"),
    (GROUP + '<shape type="shapegroup" id="h"><shape type="instance"><ref id="g"/></shape></shape>',
     "inside a shapegroup"),
    (GROUP + '<shape type="instance"><ref id="g"/><float name="scale" value="2"/></shape>', "unreferenced"),
    ('<shape type="shapegroup" id="g"><shape type="cube"><medium type="homogeneous" name="interior"/></shape>'
     '</shape><shape type="instance"><ref id="g"/></shape>', "a medium on a cube inside a shapegroup"),
])
def test_bad_instancing_is_refused(tmp_path, body, words):
    errors = scene_errors(write_scene(tmp_path, body))
    assert any(words in e for e in errors), errors


def test_the_instances_bench_generates_its_mesh_and_states_its_verdict(tmp_path):
    from validation.benchmark import instances as bench

    assert bench.write_mesh(tmp_path / "sheet.obj") == 10_000
    scene = tracer.load_scene(bench.write_scene(tmp_path, 5, True))
    assert [(g.triangles, len(g.to_world)) for g in scene.groups] == [(10_000, 5)]
    rows = [{"n": 1, "instanced": True, "peak_mib": 500.0, "table_bytes": 2000, "seconds": 1.0},
            {"n": 10_000, "instanced": True, "peak_mib": 1100.0, "table_bytes": 2 ** 21, "seconds": 2.0},
            {"n": 1, "instanced": False, "peak_mib": 500.0, "seconds": 1.0},
            {"n": 100, "instanced": False, "peak_mib": 1094.0, "seconds": 9.0}]
    text = "\n".join(bench.markdown({"triangles": 10_000, "rows": rows}))
    assert "NOT within 2x of one instance's peak plus the instance table (2 x (500 + 2.00) = 1004 MiB)" in text
    assert "Copies cost 6.0 MiB each" in text
