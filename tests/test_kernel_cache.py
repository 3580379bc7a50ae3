"""Scenes of the same kinds and the same shapes tested one by one run the same kernels: a scene's numbers
(primitive numbers, shapes' positions and sizes, lights' radiance and densities, the count of lights in a table)
enter the kernels as run-time constants, so that a new scene's first render finds its kernels in Dr.Jit's
cache instead of compiling them (about 0.5-1 s a scene). Compared by kernel hash, whatever the disk cache holds."""
import tracer
from tracer.geometry import SceneGeometry
from tracer.rendering import render
from validation.benchmark.scene_bench import PROJECT, light_replaced, tiled_light_cornell_box
from validation.verdict.scene_variants import write_variant

from .conftest import kernel_hashes

LIGHT = ('<shape type="rectangle"><transform name="to_world"><scale x="0.15" y="0.25"/><rotate x="1" angle="90"/>'
         '<translate x="0.1" y="0.98" z="-0.05"/></transform><bsdf type="diffuse"><rgb name="reflectance" '
         'value="0"/></bsdf><emitter type="area"><rgb name="radiance" value="9.5, 12.25, 20.0"/></emitter></shape>')


def _same_kernels(paths) -> tuple[set, set]:
    """The kernel hashes of a small path-traced render of each scene, after one render of it (compiled)."""
    scenes = [tracer.load_scene(p, width=16, height=16) for p in paths]
    geos = [SceneGeometry(s) for s in scenes]
    runs = [lambda s=s, g=g: render(s, "path", spp=2, max_depth=4, geometry=g) for s, g in zip(scenes, geos)]
    for run in runs:
        run()
    return geos, [kernel_hashes(run) for run in runs]


def test_a_box_of_more_tiled_lights_compiles_no_kernel_anew(tmp_path):
    """The Cornell box with its light cut into 12 x 12 then 16 x 16 rectangles (in the rectangles' BVH, the
    lights in a table): the blocks' triangles, tested one by one, are numbered after the rectangles, and the
    lights' table has another length. The scenes bench's cold section measures this pair (0.59 s of the second's
    compile was spent on kernels anew before)."""
    geos, (first, second) = _same_kernels([tiled_light_cornell_box(tmp_path, n) for n in (12, 16)])
    assert geos[0].meshes.base != geos[1].meshes.base and geos[0].n_lights != geos[1].n_lights
    assert geos[0].rectangles.bvh.stack_size == geos[1].rectangles.bvh.stack_size
    assert first and first == second


def test_a_cornell_box_with_another_light_and_colours_compiles_no_kernel_anew(tmp_path):
    """The Cornell box and a variant whose light is smaller, elsewhere under the ceiling and of another
    colour, and whose red wall is blue: the same shapes tested one by one (the same occluders of shadow rays),
    other numbers."""
    box = PROJECT / "cornell_box.xml"
    variant = light_replaced(box, LIGHT, tmp_path, "light")
    text = variant.read_text().replace("0.570068, 0.0430135, 0.0443706", "0.2, 0.3, 0.6")
    variant = write_variant(box, text, tmp_path, "light_and_wall")
    geos, (first, second) = _same_kernels([box, variant])
    assert geos[0].occluders == geos[1].occluders
    assert first and first == second


def test_a_cornell_box_seen_from_elsewhere_compiles_no_kernel_anew(tmp_path):
    """The Cornell box from another viewpoint (off its axis, so that no axis of the camera is the world's)
    through a wider field of view: the camera's pose, field of view and clip planes are run-time constants."""
    box = PROJECT / "cornell_box.xml"
    text = box.read_text().replace('value="39.3077"', 'value="45.5"').replace(
        'origin="0, 0, 4" target="0, 0, 0"', 'origin="0.3, 0.2, 3.8" target="0, 0.1, 0"')
    geos, (first, second) = _same_kernels([box, write_variant(box, text, tmp_path, "elsewhere")])
    assert first and first == second


def test_another_sample_count_compiles_no_kernel_anew():
    """The samples per pixel are a run-time constant (the pixel of sample k is k // spp)."""
    scene = tracer.load_scene(PROJECT / "cornell_box.xml", width=16, height=16)
    geo = SceneGeometry(scene)
    first, second = (kernel_hashes(lambda spp=spp: render(scene, "path", spp=spp, max_depth=4, geometry=geo))
                     for spp in (2, 3))
    assert first and first == second
