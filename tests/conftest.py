import functools
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "mitsuba_scenes"


@functools.lru_cache(maxsize=None)
def mitsuba_passes(scene: str, passes: int, spp: int, **params) -> np.ndarray:
    """Mitsuba's independent passes of a scene, shared by all tests of a session."""
    from validation.mitsuba_render import render_passes

    return render_passes(SCENES / scene, passes, spp, seed=12345, **params)


@pytest.fixture
def scenes() -> Path:
    return SCENES
