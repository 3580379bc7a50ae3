"""Loads the subset of Mitsuba 3's scene XML that the project's scenes use, with Mitsuba's semantics.

Stdlib parsing only (expat, for line numbers). Anything outside the subset is refused before rendering
with one line naming the file, the line, the element and what is supported.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np

from . import transform
from .meshes import MeshError, read_obj, vertex_normals
from .film import ReconstructionFilter
from .scene import BSDF, Camera, Mesh, Rectangle, Scene, SceneError, Sphere

SUPPORTED = {
    "integrator": ("path",),
    "sensor": ("perspective",),
    "film": ("hdrfilm",),
    "rfilter": ("box", "gaussian", "tent"),
    "sampler": ("independent",),
    "shape": ("rectangle", "sphere", "obj"),
    "bsdf": ("diffuse", "twosided", "conductor", "dielectric"),
    "emitter": ("area",),
}
FLOAT32_MAX = float(np.finfo(np.float32).max)
PROPERTY_TAGS = ("integer", "float", "boolean", "string", "rgb", "point", "vector", "transform")
TRANSFORM_OPS = ("translate", "scale", "rotate", "matrix", "lookat")


@dataclass
class Node:
    tag: str
    attrib: dict[str, str]
    line: int
    children: list["Node"] = field(default_factory=list)


class _Context:
    def __init__(self, path: Path, params: dict[str, str]):
        self.path = path
        self.params = dict(params)
        self.used: set[str] = set()
        self.ids: dict[str, Node] = {}

    def error(self, node: Node | None, message: str) -> SceneError:
        where = f"{self.path}:{node.line}: <{node.tag}{_type_attr(node)}>" if node else f"{self.path}"
        return SceneError(f"{where}: {message}")

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


def _type_attr(node: Node) -> str:
    return f" type=\"{node.attrib['type']}\"" if "type" in node.attrib else (
        f" name=\"{node.attrib['name']}\"" if "name" in node.attrib else "")


def parse_tree(path: Path) -> Node:
    """The XML file as a tree of Nodes that remember their line numbers."""
    stack: list[Node] = []
    root: list[Node] = []
    parser = expat.ParserCreate()

    def start(tag, attrib):
        node = Node(tag, dict(attrib), parser.CurrentLineNumber)
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
    ctx = _Context(path, {})
    if root.tag != "scene":
        raise ctx.error(root, "the root element must be <scene>")
    for node in root.children:
        if node.tag == "default":
            ctx.params[ctx.attr(node, "name")] = node.attrib.get("value", "")
    ctx.params.update({k: str(v) for k, v in overrides.items()})
    _collect_ids(ctx, root)
    scene = _build_scene(ctx, root)
    unused = [k for k in overrides if k not in ctx.used]
    if unused:
        declared = ", ".join(sorted(n for n in ctx.params if n in ctx.used)) or "none"
        raise SceneError(f"{path}: -D {unused[0]}: the scene uses no parameter of that name (it uses: {declared})")
    return scene


def _collect_ids(ctx: _Context, node: Node) -> None:
    for child in node.children:
        if "id" in child.attrib and child.tag in ("bsdf", "shape", "emitter", "texture"):
            ctx.ids[child.attrib["id"]] = child
        _collect_ids(ctx, child)


def _build_scene(ctx: _Context, root: Node) -> Scene:
    camera, sampler_props, integrator = None, {}, {}
    shapes: list[Node] = []
    for node in root.children:
        if node.tag in ("default", "bsdf"):
            continue
        if node.tag == "integrator":
            _check_type(ctx, node)
            integrator = _properties(ctx, node)
        elif node.tag == "sensor":
            _check_type(ctx, node)
            camera, sampler_props = _camera(ctx, node)
        elif node.tag == "shape":
            shapes.append(node)
        else:
            raise ctx.error(node, "unsupported element; a scene may hold default, integrator, sensor, bsdf, shape")
    if camera is None:
        raise ctx.error(root, "the scene has no <sensor type=\"perspective\">")
    scene = Scene(
        camera=camera,
        spp=int(sampler_props.get("sample_count", 4)),
        seed=int(sampler_props.get("seed", 0)),
        max_depth=int(integrator.get("max_depth", -1)),
        rr_depth=int(integrator.get("rr_depth", 5)),
        path=ctx.path,
    )
    if scene.spp < 1:
        raise ctx.error(root, f"sample_count must be >= 1, got {scene.spp}")
    for node in shapes:
        _add_shape(ctx, scene, node)
    return scene


def _check_type(ctx: _Context, node: Node) -> str:
    kind = ctx.attr(node, "type")
    if kind not in SUPPORTED[node.tag]:
        raise ctx.error(node, f"unsupported {node.tag} plugin '{kind}'; supported: {', '.join(SUPPORTED[node.tag])}")
    return kind


def _properties(ctx: _Context, node: Node, allowed_children: tuple[str, ...] = ()) -> dict:
    """Named properties of an element: numbers, strings, booleans, colours, points and transforms."""
    props: dict = {}
    for child in node.children:
        if child.tag in allowed_children:
            continue
        if child.tag not in PROPERTY_TAGS:
            raise ctx.error(child, f"unexpected element inside <{node.tag}>")
        props[ctx.attr(child, "name")] = _property_value(ctx, child)
    return props


def _property_value(ctx: _Context, node: Node):
    tag = node.tag
    if tag == "transform":
        return _transform(ctx, node)
    if tag in ("point", "vector") and "value" not in node.attrib:
        return np.array([_number(ctx, node, ctx.attr(node, k, "0")) for k in "xyz"])
    value = ctx.attr(node, "value")
    if tag == "string":
        return value
    if tag == "boolean":
        if value.lower() not in ("true", "false"):
            raise ctx.error(node, f"'{value}' is not a boolean (true or false)")
        return value.lower() == "true"
    if tag == "integer":
        try:
            return int(value)
        except ValueError:
            raise ctx.error(node, f"'{value}' is not an integer") from None
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
        return transform.rotate(axis, _number(ctx, op, ctx.attr(op, "angle")))
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


def _camera(ctx: _Context, node: Node) -> tuple[Camera, dict]:
    props = _properties(ctx, node, allowed_children=("film", "sampler"))
    film, sampler = {"width": 768, "height": 576}, {}
    for child in node.children:
        if child.tag == "film":
            _check_type(ctx, child)
            for rf in (c for c in child.children if c.tag == "rfilter"):
                film["rfilter"] = _rfilter(ctx, rf)
            film.update(_properties(ctx, child, allowed_children=("rfilter",)))
        elif child.tag == "sampler":
            _check_type(ctx, child)
            sampler = _properties(ctx, child)
    fov_axis = props.get("fov_axis", "x")
    if fov_axis not in ("x", "y", "diagonal", "smaller", "larger"):
        raise ctx.error(node, f"fov_axis '{fov_axis}' unsupported; supported: x, y, diagonal, smaller, larger")
    fov = float(props.get("fov", 90.0))
    if not 0 < fov < 180:
        raise ctx.error(node, f"fov must lie in (0, 180), got {fov}")
    w, h = int(film["width"]), int(film["height"])
    if w < 1 or h < 1:
        raise ctx.error(node, f"film size must be positive, got {w} x {h}")
    camera = Camera(props.get("to_world", np.eye(4)), fov, fov_axis, float(props.get("near_clip", 1e-2)),
                    float(props.get("far_clip", 1e4)), w, h, film.get("rfilter", ReconstructionFilter("gaussian")))
    return camera, sampler


def _rfilter(ctx: _Context, node: Node) -> ReconstructionFilter:
    kind = _check_type(ctx, node)
    props = _properties(ctx, node)
    allowed = {"box": (), "gaussian": ("stddev",), "tent": ("radius",)}[kind]
    for name in props:
        if name not in allowed:
            raise ctx.error(node, f"rfilter '{kind}' has no property '{name}'; supported: {', '.join(allowed) or 'none'}")
    value = float(props.get(allowed[0], 0.5 if kind == "gaussian" else 1.0)) if allowed else 0.0
    if allowed and not 0 < value <= 8:
        raise ctx.error(node, f"rfilter '{kind}' {allowed[0]} must lie in (0, 8] pixels, got {value}")
    if kind == "gaussian":
        return ReconstructionFilter("gaussian", stddev=value)
    return ReconstructionFilter("tent", tent_radius=value) if kind == "tent" else ReconstructionFilter("box")


def _bsdf(ctx: _Context, node: Node) -> BSDF:
    if node.tag == "ref":
        ref = ctx.ids.get(ctx.attr(node, "id"))
        if ref is None or ref.tag != "bsdf":
            raise ctx.error(node, f"no <bsdf> with id '{node.attrib.get('id')}'")
        node = ref
    kind = _check_type(ctx, node)
    if kind == "twosided":
        inner = [c for c in node.children if c.tag in ("bsdf", "ref")]
        if len(inner) != 1:
            raise ctx.error(node, "twosided wraps exactly one bsdf")
        base = _bsdf(ctx, inner[0])
        if base.kind != "diffuse":
            raise ctx.error(node, "twosided supports a diffuse bsdf only")
        return BSDF("diffuse", base.reflectance, twosided=True)
    props = _properties(ctx, node)
    if kind == "diffuse":
        rho = np.broadcast_to(np.asarray(props.get("reflectance", 0.5), float), 3)
        if np.any(rho < 0) or np.any(rho > 1):
            raise ctx.error(node, f"diffuse reflectance must lie in [0, 1], got {tuple(float(x) for x in rho)}")
        return BSDF("diffuse", tuple(float(x) for x in rho))
    if kind == "conductor":
        if props.get("material", "none") != "none":
            raise ctx.error(node, "only conductor material 'none' (a perfect mirror) is supported")
        return BSDF("conductor", (1.0, 1.0, 1.0))
    ior = {k: props.get(k, d) for k, d in (("int_ior", 1.5046), ("ext_ior", 1.000277))}
    if not all(isinstance(v, float) for v in ior.values()):
        raise ctx.error(node, "int_ior and ext_ior must be given as <float>")
    if min(ior.values()) <= 0:
        raise ctx.error(node, "indices of refraction must be positive")
    return BSDF("dielectric", (1.0, 1.0, 1.0), int_ior=ior["int_ior"], ext_ior=ior["ext_ior"])


def _add_shape(ctx: _Context, scene: Scene, node: Node) -> None:
    kind = _check_type(ctx, node)
    props = _properties(ctx, node, allowed_children=("bsdf", "ref", "emitter"))
    bsdfs = [c for c in node.children if c.tag in ("bsdf", "ref")]
    radiance = None
    for em in (c for c in node.children if c.tag == "emitter"):
        _check_type(ctx, em)
        value = _properties(ctx, em).get("radiance", np.ones(3))
        value = np.broadcast_to(np.asarray(value, float), 3)
        if np.any(value < 0):
            raise ctx.error(em, f"radiance must be non-negative, got {tuple(float(x) for x in value)}")
        radiance = tuple(float(x) for x in value)
    # Mitsuba's default: diffuse 0.5, but black on an emitter shape.
    bsdf = _bsdf(ctx, bsdfs[0]) if bsdfs else BSDF("diffuse", (0.0,) * 3 if radiance else (0.5,) * 3)
    to_world = props.get("to_world", np.eye(4))
    name = node.attrib.get("id", f"{kind}@{node.line}")
    if kind == "rectangle":
        scene.rectangles.append(Rectangle(to_world, bsdf, radiance, name))
    elif kind == "sphere":
        if radiance is not None:
            raise ctx.error(node, "area emitters are supported on rectangle and obj shapes only")
        center = transform.apply_point(to_world, props.get("center", np.zeros(3)))[0]
        radius = float(props.get("radius", 1.0)) * float(np.cbrt(abs(np.linalg.det(to_world[:3, :3]))))
        if radius <= 0:
            raise ctx.error(node, f"sphere radius must be positive, got {radius}")
        scene.spheres.append(Sphere(center, radius, bsdf, name))
    else:
        scene.meshes.append(_mesh(ctx, node, props, to_world, bsdf, radiance, name))


def _mesh(ctx, node, props, to_world, bsdf, radiance, name) -> Mesh:
    filename = props.get("filename")
    if not filename:
        raise ctx.error(node, "obj shape needs a <string name=\"filename\">")
    file = (ctx.path.parent / filename)
    if not file.is_file():
        raise ctx.error(node, f"mesh file '{filename}' not found (looked in {file.parent})")
    try:
        vertices, faces, normals = read_obj(file)
    except MeshError as e:
        raise ctx.error(node, str(e)) from None
    vertices = transform.apply_point(to_world, vertices)
    if props.get("face_normals", False):
        normals = None
    elif normals is None:
        normals = vertex_normals(vertices, faces)
    else:
        normals = transform.apply_normal(to_world, normals)
    return Mesh(vertices, faces, bsdf, normals, radiance, name)
