"""An independent Monte Carlo ray tracer on Dr.Jit that reads Mitsuba 3 scene files."""
from .mitsuba_xml import load_scene
from .scene import SceneError

__all__ = ["load_scene", "SceneError", "render"]


def __getattr__(name):
    if name == "render":  # imports Dr.Jit lazily, so that loading a scene stays cheap
        from .rendering import render
        return render
    raise AttributeError(name)
