"""An independent Monte Carlo ray tracer on Dr.Jit that reads Mitsuba 3 scene files.

    import tracer
    scene = tracer.load_scene("scene.xml", width=200, height=200)
    result = tracer.render(scene, "path", spp=16)      # result.image: (200, 200, 3) float32

Importing the package imports neither Dr.Jit nor the loader: `tracer --help` works on any machine, and
Dr.Jit's backend is chosen (tracer.jit) when the first of these is used.
"""
from .errors import BackendError, OutputError, PlanError, SettingsError, UserError

__all__ = ["load_scene", "render", "SceneError", "UserError", "SettingsError", "PlanError", "OutputError",
           "BackendError"]


def __getattr__(name):
    if name == "render":  # the function; its module is tracer.rendering
        from .rendering import render
        return render
    if name == "load_scene":
        from .mitsuba_xml import load_scene
        return load_scene
    if name == "SceneError":
        from .scene import SceneError
        return SceneError
    raise AttributeError(f"module 'tracer' has no attribute '{name}'")
