"""`validate media DIR` (validation/suites/media.py): which scenes of a miniature mitsuba-data it finds (those
declaring a medium, and the render tests' participating_media folder; not include fragments), a scene the
tracer refuses reported with its refusal, and the report's counts, detectable biases and causes. The checks
themselves are `validate check`'s (tests/test_check.py, tests/test_media_scenes.py)."""
from pathlib import Path

from validation.cli import main
from validation.suites import media
from validation.suites.media import MediaOutcome, check_scene, markdown, media_scenes

FOG = '<scene version="3.0.0"><medium type="homogeneous" id="fog"/></scene>'


def miniature(root: Path) -> None:
    for folder in ("docs/scenes/include", media.MEDIA_FOLDER + "/include", "scenes"):
        (root / folder).mkdir(parents=True)
    (root / "docs/scenes/fog.xml").write_text(FOG)
    (root / "docs/scenes/clear.xml").write_text('<scene version="3.0.0"/>')
    (root / "docs/scenes/include/part.xml").write_text(FOG)
    (root / media.MEDIA_FOLDER / "test_surface_volpath.xml").write_text('<scene version="3.0.0"/>')
    (root / media.MEDIA_FOLDER / "include/base.xml").write_text(FOG)
    (root / media.MEDIA_FOLDER / "test_rayleigh_volpath.xml").write_text(
        '<scene version="3.0.0"><integrator type="volpath"/>'
        '<medium type="homogeneous" id="air"><phase type="rayleigh"/></medium><sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/>'
        '<integer name="height" value="8"/></film></sensor></scene>')


def test_finds_the_media_scenes_and_reports_a_refusal(tmp_path):
    miniature(tmp_path)
    found = [str(p.relative_to(tmp_path)) for p in media_scenes(tmp_path)]
    assert found == ["docs/scenes/fog.xml", media.MEDIA_FOLDER + "/test_rayleigh_volpath.xml",
                     media.MEDIA_FOLDER + "/test_surface_volpath.xml"]
    out, files = check_scene(tmp_path / found[1], tmp_path, 3, {})
    assert out.verdict == "refused" and "rayleigh" in out.line and files == {}
    assert str(tmp_path) not in out.line


def test_an_interrupted_run_resumes(tmp_path, monkeypatch):
    """Outcomes are kept as they arrive: a second run of the same scenes and tracer renders nothing again."""
    miniature(tmp_path / "data")
    monkeypatch.setattr(media, "RESULTS", tmp_path / "kept")
    scene = tmp_path / "data" / media.MEDIA_FOLDER / "test_rayleigh_volpath.xml"
    first = media.survey(tmp_path / "data", paths=[scene])
    assert [o.verdict for o in first] == ["refused", "refused"] and len(list((tmp_path / "kept").glob("*.json"))) == 2

    def rendered_again(*args):
        raise AssertionError("rendered again")
    monkeypatch.setattr(media, "check_scene", rendered_again)
    assert media.survey(tmp_path / "data", paths=[scene]) == first


def test_the_report_states_verdicts_biases_and_causes(monkeypatch):
    monkeypatch.setitem(media.CAUSES, "b.xml", "the backdrop's texture")
    outcomes = [MediaOutcome("a.xml", 3, "agree", "agree a.xml ...", 3, 0.001, 0.021, 10.0),
                MediaOutcome("a.xml", None, "agree", "agree a.xml ...", 6, -0.002, 0.034, 12.0),
                MediaOutcome("b.xml", 3, "disagree", "disagree b.xml ...", 3, -0.2, 0.05, 11.0),
                MediaOutcome("c.xml", 3, "refused", "unsupported integrator plugin 'volpathmis'")]
    text = markdown(outcomes, "validate media MITSUBA_DATA_DIR")
    assert "| scenes | 3 |" in text and "| agree | 2 |" in text and "| disagree | 1 |" in text
    assert "| refused | 1 |" in text
    assert "| a.xml | 6 (own) | agree | -0.20% | 3.4% | 12 |" in text
    assert "| b.xml | 3 | disagree | -20.00% | 5.0% | 11 |" in text
    assert "could have missed: 5.0%" in text
    assert "- b.xml: the backdrop's texture" in text and "agree a.xml ..." in text
    assert "refused      c.xml [max_depth 3]: unsupported integrator plugin 'volpathmis'" in text
    assert "## Follow-up checks" in text and "--spp 256" in text


def test_the_command_refuses_a_folder_that_is_not_mitsuba_data(tmp_path, capsys):
    assert main(["media", str(tmp_path), "--scheduler", "none"]) == 2
    assert "participating_media" in capsys.readouterr().err
