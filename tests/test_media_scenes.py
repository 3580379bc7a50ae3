"""volpath against Mitsuba 3 on the media scenes of mitsuba-renderer/mitsuba-data (its render tests'
participating_media folder and the docs' homogeneous scenes), each at two depths: 2 (single scattering and
direct light) and 6 (multiple scattering). Each comparison is `validate check`'s (Welch's t-test per 4 x 4
block and channel against Mitsuba's passes, family-wise false-positive rate validation.protocol.ALPHA),
at 16 pixels on the longer side. Needs a local copy of mitsuba-data named by the environment variable
MITSUBA_DATA and Mitsuba itself: skipped without them (CI has neither)."""
import os
from pathlib import Path

import pytest

from validation.verdict.check import Settings, check
from validation.verdict.scenefile import plan
from validation.verdict.renderers import TracerRenderer

DATA = Path(os.environ["MITSUBA_DATA"]) if os.environ.get("MITSUBA_DATA") else None
SCENES = ["tests/scenes/participating_media/" + name for name in (
    "test_homo_null_envmap_volpath.xml", "test_homo_area_light_volpath.xml", "test_homo_dielectric_envmap_volpath.xml",
    "test_homo_emitter_inside_medium_volpath.xml", "test_homo_obj_inside_medium_volpath.xml",
    "test_homo_roughdielectric_spot_volpath.xml", "test_hetero_sigmat_volpath.xml",
    "test_hetero_sigmat_albedo_volpath.xml", "test_hetero_spectral_sigmat_no_scattering_volpath.xml",
    "test_surf_area_light_volpath.xml", "test_hetero_spectral_sigmat_volpathmis.xml",
    "test_homo_spectral_sigmat_volpathmis.xml")] + ["docs/scenes/medium_homogeneous_sss.xml",
                                                    "docs/scenes/medium_homogeneous_sss_textured.xml"]

CASES = [pytest.param(name, depth, id=f"{Path(name).stem}-{depth}") for name in SCENES for depth in (2, 6)]


def test_the_first_default_wins_across_includes(tmp_path):
    """The check plans a scene with the first <default> of each name, its included files' coming after its own,
    as Mitsuba and the tracer read them: the docs' media scenes declare integrator=volpath before including a
    file that declares integrator=path (planned as path, the comparison rendered Mitsuba's path integrator,
    which ignores media, against the tracer's volpath)."""
    (tmp_path / "part.xml").write_text('<scene version="3.0.0"><default name="integrator" value="path"/>'
                                       '<integrator type="$integrator"/></scene>')
    (tmp_path / "main.xml").write_text(
        '<scene version="3.0.0"><default name="integrator" value="volpath"/><include filename="part.xml"/>'
        '<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/>'
        '<integer name="height" value="8"/></film></sensor></scene>')
    scene_plan = plan(tmp_path / "main.xml", None, 8, 3)
    assert scene_plan.params["integrator"] == "volpath"
    assert scene_plan.tracer_scene().integrator == "volpath"


@pytest.mark.slow
@pytest.mark.skipif(DATA is None, reason="MITSUBA_DATA (a copy of mitsuba-renderer/mitsuba-data) is not set")
@pytest.mark.parametrize("name, depth", CASES)
def test_agrees_with_mitsuba(name, depth):
    pytest.importorskip("mitsuba")
    result = check(DATA / name, TracerRenderer("path"), max_depth=depth, settings=Settings(size=16, spp=32))
    assert result.verdict == "agree", result.line()
