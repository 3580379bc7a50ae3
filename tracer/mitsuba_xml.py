"""Loads the subset of Mitsuba 3's scene XML that the tracer renders, with Mitsuba's semantics.

Stdlib parsing only (expat, for line numbers). `<include>` inlines another file, `<path>` adds a folder
that files are looked up in, `<default>` declares a parameter (the first declaration wins; `-D` beats
all), any plugin may be declared with an `id` and used through `<ref>`. Every property of every plugin
is either honoured or refused by name: a property Mitsuba reads but the tracer does not implement is
refused as unsupported, one that no plugin reads as unreferenced (Mitsuba refuses those too). Every
refusal in a scene is reported at once, one line each naming the file, the line, the element and what
is supported.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np

from . import media, spectra, transform
from .errors import clip, shorten
from .film import ReconstructionFilter
from .integrators import ptracer
from .lights import PLUGINS as LIGHT_PLUGINS
from .materials import BSDF, bumpmap, textures
from .materials import PLUGINS as BSDF_PLUGINS
from .meshes import MeshError
from .scene import Camera, Scene, SceneError
from .shapes import PLUGINS as SHAPE_PLUGINS
from .shapes.base import ShapeArgs
from .shapes.instance import KINDS as INSTANCED, ShapeGroup
from .shapes.mesh import MeshFile, load as load_meshes
from .spectra import rgb

def _square_at_least(n: int, accept) -> int:
    """The smallest r * r >= n with accept(r), r >= 1 (r = 1 taken only where accept(1))."""
    r = 1
    while r * r < n or not accept(r):
        r += 1
    return r * r


# Mitsuba's samplers other than `independent` place their samples in a pattern that changes the noise, not the
# expected image: the tracer renders them with its independent sampler (`tracer info` says so), at the sample
# count the sampler rounds `sample_count` up to (src/samplers/*.cpp, set_sample_count).
SAMPLE_COUNTS = {
    "stratified": lambda n: _square_at_least(n, lambda r: True),
    "multijitter": lambda n: (n + int(math.sqrt(n)) - 1) // int(math.sqrt(n)) * int(math.sqrt(n)),
    "orthogonal": lambda n: _square_at_least(n, lambda r: r >= 2 and all(r % i for i in range(2, r // 2 + 1))),
    "ldsampler": lambda n: _square_at_least(n, lambda r: r >= 2 and r & (r - 1) == 0),
}
SUPPORTED = {
    "integrator": ("path", "moment", "volpath", "volpathmis", "direct", "aov", "ptracer"),
    "sensor": ("perspective", "thinlens", "orthographic"),
    "film": ("hdrfilm",),
    "rfilter": ("box", "gaussian", "tent"),
    "sampler": ("independent", *SAMPLE_COUNTS),
    "shape": (*SHAPE_PLUGINS, "shapegroup", "instance"),
    "bsdf": tuple(BSDF_PLUGINS),
    "emitter": ("area", *LIGHT_PLUGINS),
    "texture": tuple(textures.PLUGINS),
    "medium": media.KINDS,
    "phase": tuple(media.phases.PLUGINS),
    "volume": tuple(media.volumes.PLUGINS),
}
PLUGIN_TAGS = ("integrator", "sensor", "film", "rfilter", "sampler", "shape", "bsdf", "emitter", "texture",
               "medium", "phase", "volume", "spectrum")
PROPERTY_TAGS = ("integer", "float", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform")
COLOUR_TAGS = ("float", "integer", "rgb", "spectrum")
TRANSFORM_OPS = ("translate", "scale", "rotate", "matrix", "lookat")
MAX_INCLUDE_DEPTH = 32
MAX_ANGLE = 1e10            # degrees: Mitsuba 3.9.1 rotates meshes by 1e10, gives NaN positions from 3e11 on
MAX_INCLUDES = 10_000       # includes in one scene (each file may include several: the count can grow exponentially)
# The attributes Mitsuba's parser accepts on each element (it refuses any other as unexpected).
ATTRIBUTES: dict[str, tuple[str, ...]] = {
    "scene": ("version", "type", "id", "name"),
    "default": ("name", "value"), "path": ("value",), "include": ("filename", "name"), "ref": ("id", "name"),
    **{tag: ("type", "id", "name") for tag in PLUGIN_TAGS if tag != "spectrum"},
    **{tag: ("name", "value") for tag in ("integer", "float", "boolean", "string", "rgb")},
    "spectrum": ("name", "value", "filename", "type", "id"),
    "point": ("name", "value", "x", "y", "z"), "vector": ("name", "value", "x", "y", "z"), "transform": ("name",),
    "translate": ("value", "x", "y", "z"), "scale": ("value", "x", "y", "z"),
    "rotate": ("value", "x", "y", "z", "angle"), "matrix": ("value",), "lookat": ("origin", "target", "up"),
}
# Integer properties are 32-bit in Mitsuba's plugins: these unsigned, the others signed (properties.h's bounds).
UNSIGNED = ("sample_count", "seed", "width", "height", "crop_offset_x", "crop_offset_y", "crop_width",
            "crop_height", "shape_index")
INT32, UINT32, INT64 = (-2 ** 31, 2 ** 31 - 1), (0, 2 ** 32 - 1), (-2 ** 63, 2 ** 63 - 1)
VERSION = re.compile(r"\s*[+-]?(\d{1,25})")   # the start of each of a version's three parts, as stoul reads it

# The parameters each supported plugin reads in Mitsuba 3 (its plugin source and documentation), so that a
# parameter the tracer does not implement is refused as such rather than as a misspelling.
MITSUBA_PARAMETERS: dict[tuple[str, str], tuple[str, ...]] = {
    ("integrator", "path"): ("max_depth", "rr_depth", "hide_emitters", "block_size", "samples_per_pass",
                             "timeout"),
    ("integrator", "moment"): ("hide_emitters", "block_size", "samples_per_pass", "timeout"),
    ("integrator", "volpath"): ("max_depth", "rr_depth", "hide_emitters", "block_size", "samples_per_pass",
                                "timeout"),
    ("integrator", "volpathmis"): ("max_depth", "rr_depth", "hide_emitters", "use_spectral_mis", "block_size",
                                   "samples_per_pass", "timeout"),
    ("integrator", "ptracer"): ("max_depth", "rr_depth", "hide_emitters", "samples_per_pass", "timeout"),
    **{("medium", name): media.PARAMETERS for name in media.KINDS},
    **{("phase", name): params for name, params in media.phases.PLUGINS.items()},
    **{("volume", name): params for name, params in media.volumes.PLUGINS.items()},
    ("integrator", "aov"): ("aovs",),
    ("integrator", "direct"): ("shading_samples", "emitter_samples", "bsdf_samples", "hide_emitters", "block_size",
                               "samples_per_pass", "timeout"),
    ("sensor", "perspective"): ("to_world", "fov", "fov_axis", "focal_length", "near_clip", "far_clip",
                                "focus_distance", "principal_point_offset_x", "principal_point_offset_y",
                                "shutter_open", "shutter_close", "srf"),
    ("sensor", "thinlens"): ("to_world", "fov", "fov_axis", "focal_length", "near_clip", "far_clip", "focus_distance",
                             "aperture_radius", "shutter_open", "shutter_close", "srf"),
    ("sensor", "orthographic"): ("to_world", "near_clip", "far_clip", "shutter_open", "shutter_close", "srf"),
    ("film", "hdrfilm"): ("width", "height", "crop_offset_x", "crop_offset_y", "crop_width", "crop_height",
                          "sample_border", "pixel_format", "component_format", "file_format", "compensate",
                          "banner"),
    ("rfilter", "box"): (),
    ("rfilter", "gaussian"): ("stddev",),
    ("rfilter", "tent"): ("radius",),
    ("sampler", "independent"): ("sample_count", "seed"),
    ("sampler", "stratified"): ("sample_count", "seed", "jitter"),
    ("sampler", "multijitter"): ("sample_count", "seed", "jitter"),
    ("sampler", "orthogonal"): ("sample_count", "seed", "jitter", "strength"),
    ("sampler", "ldsampler"): ("sample_count", "seed"),
    **{("shape", name): module.PLUGINS[name] for name, module in SHAPE_PLUGINS.items()},
    ("shape", "shapegroup"): (), ("shape", "instance"): ("to_world",),
    **{("bsdf", name): module.PLUGINS[name] for name, module in BSDF_PLUGINS.items()},
    **{("texture", name): params for name, params in textures.PLUGINS.items()},
    ("emitter", "area"): ("radiance", "sampling_weight"),
    **{("emitter", name): module.PLUGINS[name] for name, module in LIGHT_PLUGINS.items()},
}
FLOAT32_MAX = float(np.finfo(np.float32).max)
DEFAULT_FILM = {"width": 768, "height": 576, "rfilter": ReconstructionFilter("gaussian")}   # Mitsuba's hdrfilm


@dataclass
class Node:
    tag: str
    attrib: dict[str, str]
    line: int
    children: list["Node"] = field(default_factory=list)
    file: Path | None = None
    chain: tuple[Path, ...] = ()      # the files whose includes led here, this node's file last (resolved)


class _Reported(SceneError):
    """A failure already recorded in the context's error list (a shared object used a second time)."""


class _Context:
    def __init__(self, path: Path, params: dict[str, str], resolver: list[Path] | None = None):
        self.path = path
        self.params = dict(params)
        self.used: set[str] = set()
        self.ids: dict[str, Node] = {}
        self.resolver = resolver if resolver is not None else [path.parent]
        self.errors: list[str] = []
        self.built: dict[int, object] = {}
        self.includes = 0
        self.emitter_shapes: dict[int, Node] = {}     # an area emitter's node -> the shape it is attached to
        self.shape_media: dict[int, tuple] = {}       # a shape's index in Scene.shapes -> (interior, exterior)
        self.sensor_medium = None                     # the medium the camera sits in
        self.shape_groups: dict[int, ShapeGroup] = {}  # a shapegroup's node -> its instanced meshes
        self.expanded: set[int] = set()               # the meshes of shapegroups copied per instance instead

    def error(self, node: Node | None, message: str) -> SceneError:
        if node is None:
            return SceneError(shorten(f"{self.path}: {message}"))
        return SceneError(shorten(f"{node.file or self.path}:{node.line}: <{node.tag}{_type_attr(node)}>: {message}"))

    def attr(self, node: Node, key: str, default: str | None = None) -> str:
        if key not in node.attrib:
            if default is not None:
                return default
            raise self.error(node, f"missing attribute '{key}'")
        return self.substitute(node, node.attrib[key])

    def substitute(self, node: Node, value: str) -> str:
        def repl(m: re.Match) -> str:
            name = m.group(1)
            if name not in self.params:
                raise self.error(node, f"parameter ${name} has no value (add <default name=\"{name}\" .../> or -D {name}=...)")
            self.used.add(name)
            return self.params[name]

        return re.sub(r"\$([A-Za-z_][A-Za-z0-9_]*)", repl, value)

    def resolve(self, name: str, first: Path | None = None) -> Path:
        """A file named in the scene, looked up like Mitsuba's file resolver: in `first`, then in the
        folders of the scene's <path> elements (latest first), then beside the scene file."""
        p = Path(name)
        if p.is_absolute():
            return p
        for folder in ([first] if first else []) + self.resolver:
            if (folder / p).exists():
                return folder / p
        return (first or self.resolver[-1]) / p

    def attempt(self, build, *args, default=None):
        """build(*args), recording a refusal instead of raising it, so that all are reported at once. A file
        the element names that the system cannot look up (a name too long, a loop of links) is refused with
        the element."""
        try:
            return build(*args)
        except _Reported:
            return default
        except SceneError as e:
            self.errors.append(str(e))
            return default
        except OSError as e:
            node = next((a for a in args if isinstance(a, Node)), None)
            name = f" '{e.filename}'" if e.filename else ""
            self.errors.append(str(self.error(node, f"cannot look up file{name}: {e.strerror or e}")))
            return default

    def bsdf(self, node: Node) -> BSDF:
        """The BSDF of a <bsdf> element (nested in another, or given by <ref>), built once."""
        return self.built_once(node, lambda n: _bsdf(self, n))

    def texture(self, node: Node):
        """The texture of a <texture> element (materials.textures), built once."""
        return self.built_once(node, lambda n: _texture(self, n))

    def built_once(self, node: Node, build):
        """An object declared once and used by several others is built (and refused) once."""
        key = id(node)
        if key not in self.built:
            try:
                self.built[key] = build(node)
            except SceneError as e:
                self.built[key] = e
                raise
        value = self.built[key]
        if isinstance(value, SceneError):
            raise _Reported(str(value))
        return value


def _type_attr(node: Node) -> str:
    return f" type=\"{clip(node.attrib['type'])}\"" if "type" in node.attrib else (
        f" name=\"{clip(node.attrib['name'])}\"" if "name" in node.attrib else "")


def parse_tree(path: Path, included_by: tuple[Path, ...] = ()) -> Node:
    """The XML file as a tree of Nodes that remember their file and line numbers (and the chain of files
    whose includes led to it: `included_by`)."""
    stack: list[Node] = []
    root: list[Node] = []
    parser = expat.ParserCreate()
    chain = included_by + (path.resolve(),)

    def start(tag, attrib):
        node = Node(tag, dict(attrib), parser.CurrentLineNumber, file=path, chain=chain)
        (stack[-1].children if stack else root).append(node)
        stack.append(node)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    try:
        data = path.read_bytes()
    except OSError as e:
        raise SceneError(f"{path}: cannot read scene file: {e.strerror}") from None
    try:
        parser.Parse(data, True)
    except expat.ExpatError as e:
        raise SceneError(f"{path}:{e.lineno}: malformed XML: {expat.ErrorString(e.code)}") from None
    except LookupError as e:  # an unknown encoding in the XML declaration
        raise SceneError(f"{path}:1: malformed XML: {e}") from None
    return root[0]


def load_scene(path: str | Path, **overrides) -> Scene:
    """Reads a Mitsuba scene file; `overrides` replace `<default>` values exactly like `mitsuba -D`."""
    path = Path(path)
    root = parse_tree(path)
    ctx = _Context(path, {k: str(v) for k, v in overrides.items()})
    if root.tag != "scene":
        raise ctx.error(root, "the root element must be <scene>")
    _check_element(ctx, root)
    _expand(ctx, root, ctx.resolver, depth=0, top=True)
    if ctx.errors:
        raise SceneError("\n".join(ctx.errors))
    _collect_ids(ctx, root)
    scene = _build_scene(ctx, root)
    used = ctx.used | _names_in(root)     # a parameter inside a refused element is used all the same
    unused = [k for k in overrides if k not in used]
    if unused:
        declared = ", ".join(sorted(n for n in ctx.params if n in used)) or "none"
        ctx.errors.append(f"{path}: -D {unused[0]}: the scene uses no parameter of that name (it uses: {declared})")
    if ctx.errors:
        raise SceneError("\n".join(dict.fromkeys(ctx.errors)))
    return scene


def _names_in(node: Node) -> set[str]:
    """The parameters ($name) in the attributes of `node` and its descendants, <default>s aside."""
    names = set() if node.tag == "default" else {
        m for value in node.attrib.values() for m in re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", value)}
    for child in node.children:
        names |= _names_in(child)
    return names


# ---- <default>, <path>, <include> ---------------------------------------------------------------------
def _expand(ctx: _Context, node: Node, resolver: list[Path], depth: int, top: bool) -> None:
    """Processes `node`'s <default>, <path> and <include> children in document order: defaults declare
    parameters, paths extend `resolver` (only as children of a file's <scene>: `top`), includes are replaced
    by the included file's elements (`depth`: how many includes deep `node` lies)."""
    children: list[Node] = []
    for child in node.children:
        _check_element(ctx, child, node)
        if child.tag in ("default", "path", "include"):
            for inner in child.children:
                _check_element(ctx, inner, child)
        if child.tag == "default":
            ctx.attempt(_default, ctx, child)
        elif child.tag == "path":
            if not top:
                ctx.errors.append(str(ctx.error(child, "<path> may only be a child of <scene>")))
            else:
                ctx.attempt(_path, ctx, child, resolver)
        elif child.tag == "include":
            children += ctx.attempt(_include, ctx, child, node, resolver, depth, default=[])
        else:
            _check_declared(ctx, child)
            if child.tag not in TRANSFORM_OPS:      # what a transform operation holds Mitsuba ignores, <default> too
                _expand(ctx, child, resolver, depth, top=False)
            children.append(child)
    node.children = children


def _check_element(ctx: _Context, node: Node, parent: Node | None = None) -> None:
    """What Mitsuba's parser refuses of an element wherever it stands: an attribute it does not know, a
    child inside a property (only a <transform> holds elements: its operations), a <scene> without a
    version of three parts."""
    allowed = ATTRIBUTES.get(node.tag, tuple(node.attrib)) + (("version",) if parent is None else ())  # a file's root
    unknown = [a for a in node.attrib if a not in allowed]
    if unknown:
        ctx.errors.append(str(ctx.error(node, f"unexpected attribute '{unknown[0]}' (as Mitsuba); <{node.tag}> takes "
                                              f"{', '.join(ATTRIBUTES[node.tag])}")))
    if parent is not None and parent.tag in PROPERTY_TAGS + ("default", "path", "include", "ref") \
            and parent.tag != "transform" and not (parent.tag == "spectrum" and "type" in parent.attrib):
        ctx.errors.append(str(ctx.error(node, f"<{node.tag}> cannot be a child of <{parent.tag}> (line {parent.line}), "
                                              "a property or directive (as in Mitsuba)")))
    if parent is not None and parent.tag == "transform" and node.tag not in TRANSFORM_OPS:
        ctx.errors.append(str(ctx.error(node, f"unexpected <{node.tag}> inside <transform> (as Mitsuba); "
                                              f"supported: {', '.join(TRANSFORM_OPS)}")))
    if node.tag in ("point", "vector", *TRANSFORM_OPS) and "value" in node.attrib \
            and any(k in node.attrib for k in "xyz"):
        ctx.errors.append(str(ctx.error(node, "cannot mix 'value' and 'x'/'y'/'z' attributes (as Mitsuba)")))
    if node.tag == "scene" and parent is None and (problem := _version_problem(node)):
        ctx.errors.append(str(ctx.error(node, problem)))


def _version_problem(scene: Node) -> str:
    """Why a <scene>'s version is one Mitsuba refuses, or ''."""
    version = scene.attrib.get("version")
    if version is None:
        return "missing attribute 'version' (as Mitsuba: e.g. version=\"3.0.0\")"
    parts = [p for p in re.split("[ .]", version) if p]        # Mitsuba's util::Version: tokens, then stoul each
    if len(parts) != 3 or not all((m := VERSION.match(p)) and int(m[1]) < 2 ** 64 for p in parts):
        return f"invalid version '{version}' (as Mitsuba: major.minor.patch, e.g. 3.0.0)"
    return ""


def _check_declared(ctx: _Context, node: Node) -> None:
    """Mitsuba substitutes $name while it reads the file: a parameter must be declared (by -D or a <default>)
    before the element that uses it."""
    for value in node.attrib.values():
        for name in re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", value):
            if name not in ctx.params:
                ctx.errors.append(str(ctx.error(node, f"parameter ${name} is used before a <default> declares it "
                                                      f"(add <default name=\"{name}\" .../> above, or -D {name}=...)")))


def _default(ctx: _Context, node: Node) -> None:
    name = ctx.attr(node, "name")
    if not name:
        raise ctx.error(node, "name must be non-empty")
    ctx.params.setdefault(name, ctx.attr(node, "value"))


def _path(ctx: _Context, node: Node, resolver: list[Path]) -> None:
    value = ctx.attr(node, "value")
    folder = Path(value)
    if not folder.is_absolute():
        folder = node.file.parent / value if (node.file.parent / value).exists() else ctx.resolve(value)
    if not folder.is_dir():
        raise ctx.error(node, f"folder '{value}' not found")
    resolver.insert(0, folder)


def _include(ctx: _Context, node: Node, parent: Node, resolver: list[Path], depth: int) -> list[Node]:
    if depth >= MAX_INCLUDE_DEPTH:
        raise ctx.error(node, f"includes nested deeper than {MAX_INCLUDE_DEPTH} (does a file include itself?)")
    name = ctx.attr(node, "filename")
    local = [node.file.parent] + resolver
    file = next((f / name for f in local if (f / name).is_file()), None) if not Path(name).is_absolute() \
        else Path(name)
    folder = next((f / name for f in local if (f / name).is_dir()), None) if not Path(name).is_absolute() \
        else Path(name)
    if file is None and folder is not None and folder.is_dir():
        raise ctx.error(node, f"included file '{name}' is a folder ({folder}), not a file")
    if file is None or not file.is_file():
        raise ctx.error(node, f"included file '{name}' not found (looked in {', '.join(map(str, local))})")
    if file.resolve() in node.chain:
        raise ctx.error(node, f"'{name}' includes itself ({' -> '.join(p.name for p in node.chain + (file,))})")
    ctx.includes += 1
    if ctx.includes > MAX_INCLUDES:
        raise ctx.error(node, f"more than {MAX_INCLUDES} includes in one scene")
    try:
        root = parse_tree(file, node.chain)
    except SceneError as e:
        raise ctx.error(node, f"while reading the included file: {e}") from None
    if root.tag == "scene" and (problem := _version_problem(root)):
        raise ctx.error(node, f"the included file {file}: {problem}")
    _check_element(ctx, root)
    if root.tag != "scene":
        if "name" in node.attrib:
            root.attrib.setdefault("name", node.attrib["name"])
        _expand(ctx, root, list(local), depth + 1, top=False)
        return [root]
    _expand(ctx, root, list(local), depth + 1, top=True)
    return root.children


def _collect_ids(ctx: _Context, node: Node) -> None:
    for child in node.children:
        if "id" in child.attrib and child.tag in PLUGIN_TAGS:
            name = child.attrib["id"]
            if name in ctx.ids:
                first = ctx.ids[name]
                again = " (the file is included twice)" if (first.file, first.line) == (child.file, child.line) else ""
                ctx.errors.append(str(ctx.error(child, f"duplicate id '{name}' (first declared at "
                                                       f"{first.file}:{first.line}){again}")))
            else:
                ctx.ids[name] = child
        if child.tag in PLUGIN_TAGS:      # an object inside a transform operation is no object (Mitsuba ignores it)
            _collect_ids(ctx, child)


# ---- properties -------------------------------------------------------------------------------------
class _Props:
    """A plugin's properties and child objects. Reading one marks it used; finish() refuses the rest by
    name, as Mitsuba refuses unreferenced properties."""

    def __init__(self, ctx: _Context, node: Node, kind: str, emitter: bool = False):
        self.ctx, self.node, self.kind, self.emitter = ctx, node, kind, emitter
        self.values: dict[str, Node] = {}
        self.objects: list[Node] = []
        self.read: set[str] = set()
        self.taken: set[int] = set()
        for child in node.children:
            if child.tag in PROPERTY_TAGS:
                name = ctx.attr(child, "name")
                if name in self.values:
                    raise ctx.error(child, f"property '{name}' is given twice")
                self.values[name] = child
            elif child.tag in PLUGIN_TAGS or child.tag == "ref":
                self.objects.append(child)
            else:
                raise ctx.error(child, f"unexpected element inside <{node.tag}>")

    def has(self, name: str) -> bool:
        return name in self.values

    def get(self, name: str, default=None, tags: tuple[str, ...] | None = None):
        """The value of property `name` (`default` when absent); `tags`: the element types accepted."""
        child = self.values.get(name)
        self.read.add(name)
        if child is None:
            return default
        if tags is not None and child.tag not in tags:
            raise self.ctx.error(child, f"property '{name}' must be given as <{'> or <'.join(tags)}>")
        value = _property_value(self.ctx, child, self.emitter)
        if child.tag == "integer" and tags == ("integer",):    # a plugin's integer parameter: 32 bits
            lo, hi = UINT32 if name in UNSIGNED else INT32
            if not lo <= value <= hi:
                raise self.ctx.error(child, f"{name} = {value} is out of bounds [{lo}, {hi}] (as Mitsuba)")
        return value

    def colour(self, name: str, default: float, unbounded: bool = False, textured: bool = False):
        """A reflectance, a radiance (on an emitter) or an `unbounded` quantity such as a conductor's eta:
        <rgb>, <spectrum>, <float>; where `textured`, also a `checkerboard` texture (inline or by <ref>)."""
        refs = [o for o in self.objects if o.attrib.get("name") == name]
        if refs:
            if textured and (texture := self.texture(name)) is not None:
                return texture
            self.taken.add(id(refs[0]))
            node = _resolve_ref(self.ctx, refs[0]) if refs[0].tag == "ref" else refs[0]
            where = "supported: <rgb>, <spectrum>, <float>" + (", a <texture>" if textured else "")
            raise self.ctx.error(refs[0], f"'{name}' given by a <{node.tag}{_type_attr(node)}>: unsupported; {where}")
        child = self.values.get(name)
        if child is not None and child.tag == "spectrum" and unbounded:
            self.read.add(name)
            return _property_value(self.ctx, child, emitter=False, unbounded=True)
        value = self.get(name, default, COLOUR_TAGS)
        return np.broadcast_to(np.asarray(value, float), 3).copy()

    def texture(self, name: str):
        """The texture (materials.textures) given for parameter `name` (inline or by <ref>), built once and
        marked used; None where the parameter is not given by a <texture>."""
        refs = [o for o in self.objects if o.attrib.get("name") == name]
        node = (_resolve_ref(self.ctx, refs[0]) if refs[0].tag == "ref" else refs[0]) if refs else None
        if node is None or node.tag != "texture":
            return None
        self.taken.add(id(refs[0]))
        return self.ctx.built_once(node, lambda n: _texture(self.ctx, n))

    def scalar(self, name: str, default: float, textured: bool = True):
        """A float parameter (<float> or <integer>) or, where `textured`, a <texture> that gives it per point:
        (value, texture or None); a texture's value is `default`."""
        texture = self.texture(name) if textured else None
        if texture is not None:
            self.read.add(name)
            return float(default), textures.read_as(texture, textures.FLOAT)
        return float(self.get(name, default, ("float", "integer"))), None

    def sampling_weight(self) -> float:
        """An emitter's `sampling_weight` (default 1): how often it is chosen relative to the other lights
        (tracer.lights.choice); non-negative and finite, as Mitsuba requires."""
        weight = float(self.get("sampling_weight", 1.0, ("float", "integer")))
        if not (np.isfinite(weight) and weight >= 0):
            raise self.ctx.error(self.values["sampling_weight"],
                                 f"sampling_weight must be finite and non-negative, got {weight:g} (as Mitsuba)")
        return weight

    def fov(self) -> tuple[float, str]:
        """A projection's field of view (degrees) and its axis, as Mitsuba's parse_fov reads them: `fov` and
        `fov_axis`, or `focal_length` on a 35 mm film (36 x 24 mm; Mitsuba's default 50mm, diagonal)."""
        ctx, node, props = self.ctx, self.node, self
        if props.has("fov") and props.has("focal_length"):
            raise ctx.error(node, "give either fov or focal_length, not both (as in Mitsuba)")
        if props.has("fov"):
            fov = props.get("fov", tags=("float", "integer"))
            fov_axis = props.get("fov_axis", "x", ("string",)).lower()
            if fov_axis not in ("x", "y", "diagonal", "smaller", "larger"):
                raise ctx.error(node, f"fov_axis '{fov_axis}' unsupported; supported: x, y, diagonal, smaller, larger")
        else:   # a 35 mm film (36 x 24 mm) behind a lens of this focal length; Mitsuba's default: 50mm
            text = props.get("focal_length", "50mm", ("string",))
            try:
                f = float(text[:-2] if text.endswith("mm") else text)
            except ValueError:
                raise ctx.error(node, f"focal_length '{text}' is not of the form <x>mm") from None
            if not f > 0:
                raise ctx.error(node, f"focal_length must be positive, got {text}")
            fov, fov_axis = 2.0 * math.degrees(math.atan(math.hypot(36.0, 24.0) / (2.0 * f))), "diagonal"
        if not 0 < fov < 180:
            raise ctx.error(node, f"fov must lie in (0, 180), got {fov}")
        return fov, fov_axis

    def children(self, *tags: str) -> list[Node]:
        """Child objects of the given element types, references resolved; marked used."""
        out = []
        for o in self.objects:
            target = _resolve_ref(self.ctx, o) if o.tag == "ref" else o
            if target.tag in tags:
                self.taken.add(id(o))
                out.append(target)
        return out

    def ignore(self, *names: str) -> None:
        """Parameters that cannot change the image (scheduling, metadata, differentiable rendering)."""
        self.read.update(names)

    def finish(self) -> None:
        documented = MITSUBA_PARAMETERS.get((self.node.tag, self.kind), ())
        honoured = [n for n in documented if n in self.read]
        for name, child in self.values.items():
            if name in self.read:
                continue
            if name in documented:
                message = f"'{name}' is not supported by the tracer"
            else:
                message = f"unreferenced property '{name}' (Mitsuba refuses it too)"
            self.ctx.errors.append(str(self.ctx.error(
                child, f"{message}; {self.node.tag} '{self.kind}' supported: {', '.join(honoured) or 'none'}")))
        for o in self.objects:
            if id(o) not in self.taken:
                target = self.ctx.ids.get(o.attrib.get("id", ""), o) if o.tag == "ref" else o
                what = f"<{target.tag}{_type_attr(target)}>" + (f" as '{o.attrib['name']}'" if "name" in o.attrib else "")
                self.ctx.errors.append(str(self.ctx.error(
                    o, f"{what} inside <{self.node.tag} type=\"{self.kind}\"> is unsupported")))


def _resolve_ref(ctx: _Context, node: Node) -> Node:
    name = ctx.attr(node, "id")
    target = ctx.ids.get(name)
    if target is None:
        raise ctx.error(node, f"no object with id '{name}'")
    return target


def _property_value(ctx: _Context, node: Node, emitter: bool = False, unbounded: bool = False):
    tag = node.tag
    if tag == "transform":
        return _transform(ctx, node)
    if tag in ("point", "vector") and "value" not in node.attrib:
        return np.array([_number(ctx, node, ctx.attr(node, k, "0")) for k in "xyz"])
    if tag == "spectrum":
        if "filename" in node.attrib or "type" in node.attrib:
            raise ctx.error(node, "spectra from files or plugins are unsupported; supported: value=\"...\"")
        try:
            return spectra.to_rgb(ctx.attr(node, "value"), emitter, unbounded)
        except spectra.SpectrumError as e:
            raise ctx.error(node, str(e)) from None
    value = ctx.attr(node, "value")
    if tag == "string":
        return value
    if tag == "boolean":
        if value.lower() not in ("true", "false"):
            raise ctx.error(node, f"'{value}' is not a boolean (true or false)")
        return value.lower() == "true"
    if tag == "integer":    # as Mitsuba's parser: a 64-bit integer, digits with an optional minus
        if not re.fullmatch(r"\s*-?[0-9]{1,19}\s*", value) or not INT64[0] <= int(value) <= INT64[1]:
            raise ctx.error(node, f"'{value}' is not an integer (of 64 bits, as Mitsuba reads them)")
        return int(value)
    if tag == "float":
        return _number(ctx, node, value)
    vec = _numbers(ctx, node, value)
    if tag == "rgb" and len(vec) == 1:
        vec = vec * 3
    if len(vec) != 3:
        raise ctx.error(node, f"expected 3 numbers, got '{value}'")
    return np.array(vec)


def _number(ctx: _Context, node: Node, text: str) -> float:
    try:
        if "_" in text:     # Python reads 1_0 as 10; Mitsuba refuses it
            raise ValueError(text)
        x = float(text)
    except ValueError:
        raise ctx.error(node, f"'{text}' is not a number") from None
    if not math.isfinite(x):
        raise ctx.error(node, f"'{text}' is not a finite number")
    if abs(x) > FLOAT32_MAX:  # the kernels compute in float32: this would become infinity there
        raise ctx.error(node, f"'{text}' is out of the float32 range (|x| <= {FLOAT32_MAX:.4g})")
    return x


def _numbers(ctx: _Context, node: Node, text: str) -> list[float]:
    return [_number(ctx, node, t) for t in text.replace(",", " ").split()]


# ---- transforms -------------------------------------------------------------------------------------
def _transform(ctx: _Context, node: Node) -> np.ndarray:
    m = np.eye(4)
    for op in node.children:
        if op.tag not in TRANSFORM_OPS:
            raise ctx.error(op, f"unsupported transform operation; supported: {', '.join(TRANSFORM_OPS)}")
        m = _transform_op(ctx, op) @ m
    if not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:3, :3])) < 1e-300:
        raise ctx.error(node, "the transform is singular or not finite")
    return m


def _xyz(ctx: _Context, op: Node, default: str) -> np.ndarray:
    if "value" in op.attrib:
        v = _numbers(ctx, op, ctx.attr(op, "value"))
        if len(v) == 1:
            return np.array(v * 3)
        if len(v) == 3:
            return np.array(v)
        raise ctx.error(op, "value must hold 1 or 3 numbers")
    return np.array([_number(ctx, op, ctx.attr(op, k, default)) for k in "xyz"])


def _transform_op(ctx: _Context, op: Node) -> np.ndarray:
    if op.tag == "translate":
        return transform.translate(_xyz(ctx, op, "0"))
    if op.tag == "scale":
        return transform.scale(_xyz(ctx, op, "1"))
    if op.tag == "rotate":
        axis = _xyz(ctx, op, "0")
        if not np.any(axis):
            raise ctx.error(op, "rotation axis is zero")
        angle = _number(ctx, op, ctx.attr(op, "angle"))
        if abs(angle) > MAX_ANGLE:
            raise ctx.error(op, f"angle {angle:g} is beyond +-{MAX_ANGLE:g} degrees, where Mitsuba's float32 sine "
                                "fails (a mesh's positions become NaN)")
        return transform.rotate(axis, angle)
    if op.tag == "matrix":
        v = _numbers(ctx, op, ctx.attr(op, "value"))
        if len(v) == 16:
            return np.array(v).reshape(4, 4)
        if len(v) == 9:
            m = np.eye(4)
            m[:3, :3] = np.array(v).reshape(3, 3)
            return m
        raise ctx.error(op, f"a matrix needs 9 or 16 numbers, got {len(v)}")
    pts = [_numbers(ctx, op, ctx.attr(op, k, d)) for k, d in (("origin", None), ("target", None), ("up", "0 1 0"))]
    if any(len(p) != 3 for p in pts):
        raise ctx.error(op, "origin, target and up need 3 numbers each")
    o, t, u = (np.array(p) for p in pts)
    if not np.any(t - o) or np.linalg.norm(np.cross(t - o, u)) == 0:  # exact: allclose is relative
        raise ctx.error(op, "degenerate lookat (origin equals target, or up is parallel to the view)")
    return transform.lookat(o, t, u)


# ---- the scene ----------------------------------------------------------------------------------------
def _check_type(ctx: _Context, node: Node) -> str:
    kind = ctx.attr(node, "type")
    if kind not in SUPPORTED.get(node.tag, ()):
        supported = ", ".join(SUPPORTED.get(node.tag, ())) or "none"
        raise ctx.error(node, f"unsupported {node.tag} plugin '{kind}'; supported: {supported}")
    return kind


def _build_scene(ctx: _Context, root: Node) -> Scene | None:
    integrators, sensors, shapes, lights = [], [], [], []
    for node in root.children:
        if node.tag == "integrator":
            integrators.append(node)
        elif node.tag == "sensor":
            sensors.append(node)
        elif node.tag == "shape":
            shapes.append(node)
        elif node.tag in ("bsdf", "film", "rfilter", "sampler", "texture", "spectrum", "medium", "phase",
                          "volume") and "id" in node.attrib:
            ctx.attempt(_declared, ctx, node)        # used through <ref>; built (and checked) on their own
        elif node.tag == "emitter" and "id" in node.attrib and _emitter_type(node) == "area":
            ctx.attempt(_declared, ctx, node)        # an area light declared for a shape's <ref>
        elif node.tag == "emitter" and _emitter_type(node) in LIGHT_PLUGINS:
            lights.append(node)
        elif node.tag in PLUGIN_TAGS:
            if ctx.attempt(_check_type, ctx, node) is not None:
                ctx.errors.append(str(ctx.error(node, f"a top-level <{node.tag}> is unsupported; supported at the "
                                                      "top level: integrator, sensor, shape, and plugins with an id")))
        else:
            ctx.errors.append(str(ctx.error(node, "unsupported element; a scene may hold default, path, include, "
                                                  "integrator, sensor, shape and plugins with an id")))
    for extra in integrators[1:]:
        ctx.errors.append(str(ctx.error(extra, "only one integrator may be specified per scene (as in Mitsuba)")))
    environments = [n for n in lights if LIGHT_PLUGINS[_emitter_type(n)].ENVIRONMENT]
    for extra in environments[1:]:
        ctx.errors.append(str(ctx.error(extra, "only one environment emitter may be specified per scene (as in Mitsuba)")))
    for extra in sensors[1:]:
        ctx.errors.append(str(ctx.error(extra, "a second sensor: the tracer renders scenes with one sensor")))
    integrator = ctx.attempt(_integrator, ctx, integrators[0], default={}) if integrators else {}
    if not sensors:
        ctx.errors.append(str(ctx.error(root, "the scene has no <sensor> (perspective or orthographic)")))
        camera, sampler = None, {}
    else:
        camera, sampler = ctx.attempt(_camera, ctx, sensors[0], default=(None, {}))
    scene = Scene(
        camera=camera,
        spp=int(sampler.get("sample_count", 4)),
        seed=int(sampler.get("seed", 0)),
        max_depth=int(integrator.get("max_depth", -1)),
        rr_depth=int(integrator.get("rr_depth", 5)),
        integrator=integrator.get("name", "path"),
        shading_samples=integrator.get("shading_samples", (1, 1)),
        spectral_mis=bool(integrator.get("spectral_mis", False)),
        sampler=sampler.get("kind", "independent"),
        path=ctx.path,
        hide_emitters=HIDING.get(integrator.get("name", "path").split()[-1]) if integrator.get("hide_emitters") else None,
    )
    for node in lights:
        if node not in environments[1:]:
            light = ctx.attempt(_light, ctx, node)
            if light is not None:
                scene.lights.append(light)
    for node in shapes:
        ctx.attempt(_add_shape, ctx, scene, node)
    _read_meshes(ctx, scene)
    _place_media(ctx, scene)
    if scene.shading_samples[0] > 1 and scene.delta_lights:
        ctx.errors.append(str(ctx.error(integrators[0], DELTA_SAMPLES.format(n=scene.shading_samples[0]))))
    passing = next((b for b in scene.bsdfs if ptracer.passes_through(b)), None)
    if scene.hide_emitters == "pass" and passing is not None and not ctx.errors:
        ctx.errors.append(str(ctx.error(integrators[0], f"hide_emitters = true with a surface rays pass through "
                                                        f"(bsdf '{passing.kind}'): Mitsuba 3.9.1 then hides what is "
                                                        "seen through it by rules the tracer does not follow")))
    if scene.integrator.endswith("ptracer") and not ctx.errors:
        node = integrators[0]
        while [n for n in node.children if n.tag == "integrator"]:    # inside a moment or an aov: the nested one
            node = next(n for n in node.children if n.tag == "integrator")
        for reason in ptracer.differences(scene):
            ctx.errors.append(str(ctx.error(node, f"ptracer's image differs from path's here: {reason}; "
                                                            "the tracer renders ptracer where they are the same "
                                                            "(README 'ptracer')")))
    return scene


def _place_media(ctx: _Context, scene: Scene) -> None:
    """Scene.media (those of shapes and the sensor, in order of first use) and each shape's and the
    sensor's medium code (0: none, k: Scene.media[k - 1])."""
    codes: dict[int, int] = {}

    def code(medium) -> int:
        if medium is None:
            return media.VACUUM
        if id(medium) not in codes:
            scene.media.append(medium)
            codes[id(medium)] = len(scene.media)
        return codes[id(medium)]

    scene.camera_medium = code(ctx.sensor_medium)
    if ctx.errors:          # shapes may be missing: their indices no longer match
        return
    for index, (inside, outside) in ctx.shape_media.items():
        scene.shape_media[scene.shapes[index]] = (code(inside), code(outside))


def _read_meshes(ctx: _Context, scene: Scene) -> None:
    """Replaces the mesh shapes' MeshFile by their meshes, all read at once (in parallel)."""
    held = [scene.shapes] + [g.meshes for g in scene.groups]
    requests = [s for shapes in held for s in shapes if isinstance(s, MeshFile)]
    meshes = dict(zip(requests, load_meshes(requests)))
    for r, m in meshes.items():
        if isinstance(m, MeshError):
            ctx.errors.append(str(ctx.error(r.args.node, str(m))))
    for shapes in held:
        shapes[:] = [s for s in (meshes[s] if isinstance(s, MeshFile) else s for s in shapes)
                     if not isinstance(s, MeshError)]


def _light(ctx: _Context, node: Node):
    props = _Props(ctx, node, _check_type(ctx, node), emitter=True)
    return LIGHT_PLUGINS[_emitter_type(node)].from_xml(ctx, props, node)


def _emitter_type(node: Node) -> str:
    return node.attrib.get("type", "")


def _declared(ctx: _Context, node: Node) -> None:
    build = {"bsdf": _bsdf, "film": _film, "rfilter": _rfilter, "sampler": _sampler, "emitter": _area_light,
             "texture": _texture, "medium": _medium, "phase": _plugin_props, "volume": _plugin_props}
    if node.tag not in build:
        _check_type(ctx, node)
        raise ctx.error(node, f"<{node.tag}> is unsupported")
    ctx.built_once(node, lambda n: build[n.tag](ctx, n))


def _integrator(ctx: _Context, node: Node) -> dict:
    kind = _check_type(ctx, node)
    props = _Props(ctx, node, kind)
    if kind == "moment":
        return _moment(ctx, node, props)
    if kind == "direct":
        return _direct(ctx, node, props)
    if kind == "aov":
        return _aov(ctx, node, props)
    out = {"max_depth": props.get("max_depth", -1, ("integer",)), "rr_depth": props.get("rr_depth", 5, ("integer",)),
           "hide_emitters": props.get("hide_emitters", False, ("boolean",))}
    props.ignore("block_size", "samples_per_pass")        # how work is scheduled: not the estimate
    out["spectral_mis"] = kind == "volpathmis" and props.get("use_spectral_mis", True, ("boolean",))
    props.finish()
    if out["hide_emitters"] and kind not in HIDING:
        raise ctx.error(props.values["hide_emitters"], f"hide_emitters = true with {kind}: the tracer hides emitters "
                                                       f"with {', '.join(HIDING)}")
    if out["max_depth"] < -1:
        raise ctx.error(node, f"max_depth must be -1 (unbounded) or >= 0, got {out['max_depth']}")
    if out["rr_depth"] < 1:
        raise ctx.error(node, f"rr_depth must be >= 1, got {out['rr_depth']}")
    out["name"] = kind
    return out


def _moment(ctx: _Context, node: Node, props: _Props) -> dict:
    """Mitsuba's `moment`: its nested integrator's image plus the samples' second moment as extra images.
    The image is the nested integrator's, so the tracer renders that one (the second moment is not written)."""
    hide = props.get("hide_emitters", False, ("boolean",))
    props.ignore("block_size", "samples_per_pass")
    nested = props.children("integrator")
    props.finish()
    if hide:
        raise ctx.error(props.values["hide_emitters"], "hide_emitters = true is not supported by the tracer")
    if len(nested) != 1:
        raise ctx.error(node, f"a moment integrator with {len(nested)} nested integrators; the tracer renders "
                              "a moment around exactly one (its image is that integrator's)")
    out = _wrapped(ctx, node, nested[0])
    return {**out, "name": f"moment around {out['name']}"}


# The integrators whose hide_emitters the tracer honours, and how (Scene.hide_emitters): Mitsuba 3.9.1's path and
# direct let camera rays pass through emitting shapes and show no environment to them; its ptracer only leaves out
# the light it connects from emitters straight to the camera (the emitting shapes still reflect and occlude).
HIDING = {"path": "pass", "direct": "pass", "ptracer": "dark"}


AOV_TYPES = ("albedo", "depth", "position", "uv", "geo_normal", "sh_normal", "dp_du", "dp_dv", "duv_dx", "duv_dy",
             "prim_index", "shape_index")     # Mitsuba 3.9's aov integrator (src/integrators/aov.cpp)


def _aov(ctx: _Context, node: Node, props: _Props) -> dict:
    """Mitsuba's `aov`: its image is its first nested integrator's; the AOVs (`aovs`, "name:type, ...") and
    further nested integrators' images are extra channels, which the tracer does not write (`tracer info`)."""
    spec = props.get("aovs", "", ("string",))
    nested = props.children("integrator")
    props.finish()
    for token in (t.strip() for t in re.split(r"[,\s]+", spec) if t.strip()):
        name, _, kind = token.partition(":")
        if not name or kind not in AOV_TYPES:
            raise ctx.error(props.values["aovs"], f"invalid AOV '{token}': need name:type, type one of "
                                                  f"{', '.join(AOV_TYPES)} (as Mitsuba)")
    if not nested:
        raise ctx.error(node, "an aov integrator without a nested integrator: its image holds no colour; the "
                              "tracer renders the image of the first nested integrator")
    out = _wrapped(ctx, node, nested[0])
    return {**out, "name": f"aov around {out['name']}"}


def _wrapped(ctx: _Context, node: Node, nested: Node) -> dict:
    """The integrator a moment or an aov wraps: Mitsuba's wrap sampling integrators only, not its ptracer."""
    out = _integrator(ctx, nested)
    if out["name"].endswith("ptracer"):
        raise ctx.error(node, f"a {_check_type(ctx, node)} around ptracer: Mitsuba's wraps sampling integrators "
                              "only (path, volpath, volpathmis, direct), not its particle tracer")
    return out


def _direct(ctx: _Context, node: Node, props: _Props) -> dict:
    """Mitsuba's `direct`: the emission seen by the camera plus direct light at the first surface, from
    `emitter_samples` light samples and `bsdf_samples` BSDF samples (both default to `shading_samples`, 1)
    combined by the power heuristic: the path tracer at max_depth 2 drawing its strategies in those
    proportions (integrators.path.Strategies)."""
    if props.has("shading_samples") and (props.has("emitter_samples") or props.has("bsdf_samples")):
        raise ctx.error(node, "give either shading_samples or emitter_samples/bsdf_samples, not both (as Mitsuba)")
    shading = props.get("shading_samples", 1, ("integer",))
    counts = (props.get("emitter_samples", shading, ("integer",)), props.get("bsdf_samples", shading, ("integer",)))
    hide = props.get("hide_emitters", False, ("boolean",))
    props.ignore("block_size", "samples_per_pass")
    props.finish()
    if min(counts) < 0 or sum(counts) == 0:
        raise ctx.error(node, f"emitter_samples and bsdf_samples must be >= 0, at least one of them positive "
                              f"(as Mitsuba), got {counts[0]} and {counts[1]}")
    return {"max_depth": 2, "rr_depth": 5, "name": "direct", "shading_samples": counts, "hide_emitters": hide}


# Mitsuba 3.9.1's direct integrator weights each emitter sample of a delta light 1, not 1 / emitter_samples
# (src/integrators/direct.cpp): such a light comes out emitter_samples times too bright. Neither copied nor
# silently corrected: refused.
DELTA_SAMPLES = ("emitter_samples = {n} with a point, spot or directional light: Mitsuba weights each sample of a "
                 "delta light 1 (not 1/{n}), making it {n}x too bright; the tracer renders direct with "
                 "emitter_samples <= 1 in such scenes")


def _camera(ctx: _Context, node: Node) -> tuple[Camera, dict]:
    kind = _check_type(ctx, node)
    props = _Props(ctx, node, kind)
    films = props.children("film")
    samplers = props.children("sampler")
    ctx.sensor_medium = _media(ctx, props, ("medium",)).get("medium")
    for what, objects in (("film", films), ("sampler", samplers)):
        if len(objects) > 1:
            raise ctx.error(objects[1], f"a second {what} in a sensor (Mitsuba allows one)")
    film = ctx.built_once(films[0], lambda n: _film(ctx, n)) if films else dict(DEFAULT_FILM)
    sampler = ctx.built_once(samplers[0], lambda n: _sampler(ctx, n)) if samplers else {}
    w, h = film["width"], film["height"]
    fov, fov_axis = props.fov() if kind != "orthographic" else (90.0, "x")   # orthographic: none
    near, far = props.get("near_clip", 1e-2, ("float", "integer")), props.get("far_clip", 1e4, ("float", "integer"))
    if not 0 < near < far:
        raise ctx.error(node, f"near_clip must be positive and smaller than far_clip, got {near} and {far}")
    lens = {}
    if kind == "thinlens":
        if not props.has("aperture_radius"):
            raise ctx.error(node, "a thinlens sensor needs aperture_radius (as Mitsuba)")
        lens = {"aperture_radius": float(props.get("aperture_radius", tags=("float", "integer"))),
                "focus_distance": float(props.get("focus_distance", far, ("float", "integer")))}
        if not lens["aperture_radius"] > 0 or not lens["focus_distance"] > 0:
            raise ctx.error(node, f"aperture_radius and focus_distance must be positive, got "
                                  f"{lens['aperture_radius']} and {lens['focus_distance']}")
    if kind == "perspective":
        props.get("focus_distance", tags=("float", "integer"))   # read by Mitsuba's projective cameras; a pinhole has no focus
        for name in ("principal_point_offset_x", "principal_point_offset_y"):
            if props.get(name, 0.0, ("float", "integer")) != 0:
                raise ctx.error(props.values[name], f"{name} other than 0 is not supported by the tracer")
    shutter = [props.get(k, 0.0, ("float", "integer")) for k in ("shutter_open", "shutter_close")]
    if shutter[0] > shutter[1]:           # nothing in the scene moves: only Mitsuba's own check matters
        raise ctx.error(node, f"shutter_open ({shutter[0]}) must not exceed shutter_close ({shutter[1]}), as in Mitsuba")
    to_world = props.get("to_world", np.eye(4), ("transform",))
    props.finish()
    linear = to_world[:3, :3]
    rigid = np.allclose(linear.T @ linear, np.eye(3), atol=1e-3) and np.allclose(linear @ linear.T, np.eye(3), atol=1e-3)
    if kind != "orthographic" and not rigid:
        raise ctx.error(props.values["to_world"], "a camera's to_world may not scale or shear (as Mitsuba): "
                                                  "translate, rotate, lookat")
    window = {}
    if (film.get("crop_width", w), film.get("crop_height", h)) != (w, h):
        window = {"film_width": w, "film_height": h, "crop_x": film["crop_offset_x"], "crop_y": film["crop_offset_y"]}
        w, h = film["crop_width"], film["crop_height"]
    camera = Camera(to_world, float(fov), fov_axis, float(near), float(far), w, h, film["rfilter"],
                    "orthographic" if kind == "orthographic" else "perspective", **lens, **window,
                    sample_border=film.get("sample_border", False))
    return camera, sampler


def _film(ctx: _Context, node: Node) -> dict:
    kind = _check_type(ctx, node)
    props = _Props(ctx, node, kind)
    rfilters = props.children("rfilter")
    if len(rfilters) > 1:
        raise ctx.error(rfilters[1], "a second rfilter in a film (Mitsuba allows one)")
    rfilter = ctx.built_once(rfilters[0], lambda n: _rfilter(ctx, n)) if rfilters else ReconstructionFilter("gaussian")
    w, h = props.get("width", 768, ("integer",)), props.get("height", 576, ("integer",))
    if w < 1 or h < 1:
        raise ctx.error(node, f"film size must be positive, got {w} x {h}")
    # the crop window (Mitsuba's Film::set_crop_window): the image is this part of the film
    crop = {"crop_offset_x": props.get("crop_offset_x", 0, ("integer",)),
            "crop_offset_y": props.get("crop_offset_y", 0, ("integer",)),
            "crop_width": props.get("crop_width", w, ("integer",)), "crop_height": props.get("crop_height", h, ("integer",))}
    if crop["crop_width"] < 1 or crop["crop_height"] < 1:
        raise ctx.error(node, f"the crop window must be at least 1 x 1 pixels, got {crop['crop_width']} x "
                              f"{crop['crop_height']}")
    if crop["crop_offset_x"] + crop["crop_width"] > w or crop["crop_offset_y"] + crop["crop_height"] > h:
        window = ", ".join(f"{k} {v}" for k, v in crop.items())
        raise ctx.error(node, f"the crop window ({window}) does not fit the {w} x {h} film (as Mitsuba)")
    sample_border = props.get("sample_border", False, ("boolean",))
    # The tracer writes the film's RGB as float32 OpenEXR: formats that store the same RGB are accepted.
    for name, accepted in (("pixel_format", ("rgb", "rgba")), ("component_format", ("float32",)),
                           ("file_format", ("openexr", "exr"))):
        value = props.get(name, accepted[0], ("string",))
        if value.lower() not in accepted:
            raise ctx.error(props.values[name], f"{name} '{value}' is not supported; supported: {', '.join(accepted)}")
    props.ignore("banner", "compensate")     # metadata in the file; summation accuracy of the film
    props.finish()
    return {"width": w, "height": h, "rfilter": rfilter, "sample_border": sample_border, **crop}


def _sampler(ctx: _Context, node: Node) -> dict:
    kind = _check_type(ctx, node)
    props = _Props(ctx, node, kind)
    out = {"sample_count": props.get("sample_count", 4, ("integer",)), "seed": props.get("seed", 0, ("integer",)),
           "kind": kind}
    props.ignore("jitter", "strength")        # where the pattern places its samples: the noise, not the image
    props.finish()
    if out["sample_count"] < 1:
        raise ctx.error(node, f"sample_count must be >= 1, got {out['sample_count']}")
    if kind in SAMPLE_COUNTS:
        out["sample_count"] = SAMPLE_COUNTS[kind](out["sample_count"])
    return out


def _rfilter(ctx: _Context, node: Node) -> ReconstructionFilter:
    kind = _check_type(ctx, node)
    props = _Props(ctx, node, kind)
    if kind == "box":
        props.finish()
        return ReconstructionFilter("box")
    name = "stddev" if kind == "gaussian" else "radius"
    value = float(props.get(name, 0.5 if kind == "gaussian" else 1.0, ("float", "integer")))
    props.finish()
    if not 0 < value <= 8:
        raise ctx.error(node, f"rfilter '{kind}' {name} must lie in (0, 8] pixels, got {value}")
    if kind == "gaussian":
        return ReconstructionFilter("gaussian", stddev=value)
    return ReconstructionFilter("tent", tent_radius=value)


def _bsdf(ctx: _Context, node: Node) -> BSDF:
    kind = _check_type(ctx, node)
    return BSDF_PLUGINS[kind].from_xml(ctx, _Props(ctx, node, kind), node)


def _texture(ctx: _Context, node: Node) -> textures.Texture:
    return textures.from_xml(ctx, _Props(ctx, node, _check_type(ctx, node)), node)


def _area_light(ctx: _Context, node: Node) -> tuple[tuple[float, float, float], float]:
    kind = _check_type(ctx, node)
    if kind != "area":
        raise ctx.error(node, "a shape's emitter must be an 'area' light")
    props = _Props(ctx, node, kind, emitter=True)
    if props.has("to_world"):
        raise ctx.error(props.values["to_world"], "an area light takes its shape's transform (Mitsuba refuses to_world)")
    value = props.colour("radiance", 1.0)
    weight = props.sampling_weight()
    props.finish()
    if np.any(value < 0):
        raise ctx.error(node, f"radiance must be non-negative, got {rgb(value)}")
    return rgb(value), weight


def _add_shape(ctx: _Context, scene: Scene, node: Node, outer: np.ndarray | None = None, prefix: str = "",
               group: ShapeGroup | None = None) -> None:
    """The shape of a <shape> element (placed by `outer` and named after `prefix` inside an instance; a mesh
    of `group` kept in the group's space, for its instances)."""
    kind = _check_type(ctx, node)
    if kind in GROUPING:
        if outer is not None:
            raise ctx.error(node, f"a {kind} inside a shapegroup (Mitsuba allows shapes only)")
        GROUPING[kind](ctx, scene, node)
        return
    props = _Props(ctx, node, kind)
    emitters = props.children("emitter")
    bsdfs = props.children("bsdf")
    if len(emitters) > 1 or len(bsdfs) > 1:
        raise ctx.error(node, "a shape holds at most one bsdf and one emitter")
    if emitters and ctx.emitter_shapes.setdefault(id(emitters[0]), node) is not node:
        first = ctx.emitter_shapes[id(emitters[0])]
        raise ctx.error(node, f"the area emitter '{emitters[0].attrib.get('id', '')}' is attached to the shape at "
                              f"{first.file}:{first.line} already; an emitter attaches to one shape (as Mitsuba)")
    light = ctx.attempt(ctx.built_once, emitters[0], lambda n: _area_light(ctx, n)) if emitters else None
    radiance, weight = light if light is not None else (None, 1.0)
    bsdf = ctx.attempt(ctx.bsdf, bsdfs[0]) if bsdfs else None
    if bsdf is not None and kind not in textures.ATTRIBUTE_SHAPES and any(
            isinstance(t, textures.MeshAttribute) for t in bsdf.every_texture()):
        raise ctx.error(bsdfs[0], f"a mesh_attribute texture on a '{kind}' (Mitsuba reads 0 there); supported "
                                  f"shapes: {', '.join(textures.ATTRIBUTE_SHAPES)} (the meshes with attributes)")
    if bsdf is not None and group is not None and any(
            isinstance(t, textures.MeshAttribute) for t in bsdf.every_texture()):
        ctx.expanded.add(id(node))   # the attributes are read by primitive: such a mesh is copied per instance
        group = None
    if bsdf is not None and bsdf.texture_of("bumpmap") is not None and kind not in bumpmap.SHAPES:
        raise ctx.error(bsdfs[0], f"a bumpmap on a '{kind}' is not supported (the tracer computes dp/dv on "
                                  f"meshes only); supported shapes: {', '.join(bumpmap.SHAPES)}")
    if bsdf is None:  # Mitsuba's default: diffuse 0.5, but black on an emitter shape
        bsdf = BSDF("diffuse", (0.0,) * 3 if emitters else (0.5,) * 3)
    to_world = props.get("to_world", np.eye(4), ("transform",))
    if outer is not None:
        if emitters:
            raise ctx.error(emitters[0], "an area emitter on a shape inside a shapegroup (Mitsuba refuses it)")
        if group is None:
            to_world = outer @ to_world
    flip = props.get("flip_normals", False, ("boolean",))
    props.ignore("silhouette_sampling_weight")   # differentiable rendering
    name = (f"{group.name}/" if group is not None else prefix) + node.attrib.get("id", f"{kind}@{node.line}")
    module = SHAPE_PLUGINS[kind]
    held = _media(ctx, props, ("interior", "exterior"))
    if group is not None and held:
        raise ctx.error(node, f"a medium on a {kind} inside a shapegroup is not supported (the tracer instances "
                              "meshes without media; a sphere, rectangle, disk or cylinder there may hold one)")
    shape = module.from_xml(ctx, props, ShapeArgs(node, kind, to_world, flip, bsdf, radiance, name, weight))
    (group.meshes if group is not None else scene.shapes).append(shape)
    if held:
        ctx.shape_media[len(scene.shapes) - 1] = (held.get("interior"), held.get("exterior"))


def _medium(ctx: _Context, node: Node):
    props = _Props(ctx, node, _check_type(ctx, node))
    return media.medium_from_xml(ctx, props, node, lambda n: _Props(ctx, n, _check_type(ctx, n)))


def _plugin_props(ctx: _Context, node: Node):
    """A phase function or volume declared with an id: built (and checked) where a medium uses it."""
    kind = _check_type(ctx, node)
    if node.tag == "phase":
        return media.phases.from_xml(ctx, _Props(ctx, node, kind), node)
    return media.volume_from_xml(ctx, _Props(ctx, node, kind), node)


def _media(ctx: _Context, props: _Props, names: tuple[str, ...]) -> dict:
    """The media a shape (`interior`, `exterior`) or a sensor (`medium`) holds, by name, each built once."""
    out = {}
    for o in props.objects:
        target = _resolve_ref(ctx, o) if o.tag == "ref" else o
        if target.tag != "medium":
            continue
        props.taken.add(id(o))
        name = o.attrib.get("name", "")
        if name not in names:
            raise ctx.error(o, f"a <medium> named '{name}' in a <{props.node.tag}>; supported names: {', '.join(names)}")
        if name in out:
            raise ctx.error(o, f"a second '{name}' medium in one <{props.node.tag}>")
        out[name] = ctx.built_once(target, lambda n: _medium(ctx, n))
    return out


def _shapegroup(ctx: _Context, scene: Scene, node: Node) -> None:
    """Mitsuba's `shapegroup`: shapes drawn only through `instance`s; here its members are checked."""
    props = _Props(ctx, node, "shapegroup")
    members = props.children("shape")
    props.finish()
    if "id" not in node.attrib:
        raise ctx.error(node, "a shapegroup needs an id for instances to refer to")
    for member in members:
        kind = ctx.attempt(_check_type, ctx, member)
        if kind in GROUPING:
            ctx.errors.append(str(ctx.error(member, f"a {kind} inside a shapegroup (Mitsuba allows shapes only)")))


def _instance(ctx: _Context, scene: Scene, node: Node) -> None:
    """Mitsuba's `instance` of a shapegroup, placed by its to_world. The group's meshes are instanced: held
    once in the group's space (its ShapeGroup, built at its first instance) and drawn by each instance's
    transform (tracer.shapes.instance). Its other members are expanded: each becomes a shape of its own with
    to_world = the instance's times the member's (the image Mitsuba's instancing gives)."""
    props = _Props(ctx, node, "instance")
    groups = props.children("shape")
    to_world = props.get("to_world", np.eye(4), ("transform",))
    props.finish()
    if len(groups) != 1 or groups[0].attrib.get("type") != "shapegroup":
        raise ctx.error(node, "an instance refers to exactly one shapegroup (as in Mitsuba)")
    group = groups[0]
    scene.instances += 1
    name = group.attrib.get('id', 'shapegroup')
    prefix = f"{name}#{scene.instances}/"
    instanced = ctx.shape_groups.get(id(group))
    first = instanced is None
    if first:
        instanced = ctx.shape_groups[id(group)] = ShapeGroup(name)
        scene.groups.append(instanced)
    instanced.to_world.append(to_world)
    for member in group.children:
        if member.tag == "ref":
            member = ctx.ids.get(member.attrib.get("id", ""), member)
        kind = member.attrib.get("type")
        if member.tag != "shape" or kind in GROUPING:
            continue
        if kind in INSTANCED and id(member) not in ctx.expanded:
            if first:      # kept once in the group's space (or, with mesh attributes, copied: ctx.expanded)
                ctx.attempt(_add_shape, ctx, scene, member, to_world, prefix, instanced)
        else:
            ctx.attempt(_add_shape, ctx, scene, member, to_world, prefix)


GROUPING = {"shapegroup": _shapegroup, "instance": _instance}
