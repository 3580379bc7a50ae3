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
from validation.verdict.renderers import TracerRenderer

DATA = Path(os.environ["MITSUBA_DATA"]) if os.environ.get("MITSUBA_DATA") else None
SCENES = ["tests/scenes/participating_media/" + name for name in (
    "test_homo_null_envmap_volpath.xml", "test_homo_area_light_volpath.xml", "test_homo_dielectric_envmap_volpath.xml",
    "test_homo_emitter_inside_medium_volpath.xml", "test_homo_obj_inside_medium_volpath.xml",
    "test_homo_roughdielectric_spot_volpath.xml", "test_hetero_sigmat_volpath.xml",
    "test_hetero_sigmat_albedo_volpath.xml", "test_hetero_spectral_sigmat_no_scattering_volpath.xml",
    "test_surf_area_light_volpath.xml")] + ["docs/scenes/medium_homogeneous_sss.xml",
                                            "docs/scenes/medium_homogeneous_sss_textured.xml"]


# Known disagreement: at max_depth 6 the tracer renders the docs' subsurface bunnies 26% (plain) and 19% (textured)
# darker than Mitsuba (they agree at depth 2). Bisected on copies of the scene: they agree once the backdrop (the
# matpreview mesh) is removed, replaced by a flat rectangle through the bunny, given face normals, or left
# untextured, and with the medium removed; the tracer's own bunny turns dark only with the smooth, textured
# backdrop, so the fault is the tracer's. Already at max_depth 4 (single scattering, then out through the glass)
# the tracer's bunny is 10x darker than with the backdrop untextured, also with a checkerboard of one colour
# (0.3, 0.3) against a plain 0.3 (the texture's code, not its values), also with SymbolicLoops off and in one
# kernel; a textured object elsewhere in the scene does not darken it. Its cause is not found yet.
KNOWN = pytest.mark.xfail(strict=True, reason="volpath: the docs' subsurface bunnies on their smooth textured backdrop")
CASES = [pytest.param(name, depth, id=f"{Path(name).stem}-{depth}",
                      marks=[KNOWN] if depth == 6 and "medium_homogeneous_sss" in name else [])
         for name in SCENES for depth in (2, 6)]


@pytest.mark.slow
@pytest.mark.skipif(DATA is None, reason="MITSUBA_DATA (a copy of mitsuba-renderer/mitsuba-data) is not set")
@pytest.mark.parametrize("name, depth", CASES)
def test_agrees_with_mitsuba(name, depth):
    pytest.importorskip("mitsuba")
    result = check(DATA / name, TracerRenderer("path"), max_depth=depth, settings=Settings(size=16, spp=32))
    assert result.verdict == "agree", result.line()
