"""validate snapshot: a refactor's images compared to the bit."""
import numpy as np

from validation import cli
from validation.suites.snapshot import ROOT, compare, write

SCENES = [ROOT / "mitsuba_scenes/cornell_box.xml", ROOT / "mitsuba_scenes/stress/negative_light.xml"]


def test_a_snapshot_equals_itself_and_a_changed_image_is_found(tmp_path):
    names = write(tmp_path / "a", SCENES)
    assert names[:2] == ["mitsuba_scenes_cornell_box_path", "mitsuba_scenes_cornell_box_report"]  # refusals left out
    write(tmp_path / "b", SCENES)
    assert compare(tmp_path / "a", tmp_path / "b") == []      # one thread: deterministic
    image = np.load(tmp_path / "b" / f"{names[0]}.npy")
    image[3, 4, 1] = np.nextafter(image[3, 4, 1], np.float32(1))   # one ulp in one pixel
    np.save(tmp_path / "b" / f"{names[0]}.npy", image)
    (tmp_path / "b" / f"{names[1]}.npy").unlink()
    assert compare(tmp_path / "a", tmp_path / "b") == [f"{names[1]}.npy: only in {tmp_path / 'a'}",
                                                       f"{names[0]}.npy: differs (largest difference "
                                                       f"{np.abs(image[3, 4, 1] - np.load(tmp_path / 'a' / f'{names[0]}.npy')[3, 4, 1])})"]


def test_against_an_empty_folder_is_a_user_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert cli.main(["snapshot", str(tmp_path / "new"), "--against", str(tmp_path / "empty")]) == 2
    assert "holds no snapshot" in capsys.readouterr().err
