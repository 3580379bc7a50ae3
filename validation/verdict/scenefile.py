"""A scene file as one comparison renders it: its `<default>`s overridden (like `mitsuba -D`), and the film
size and depth set whether or not the file declares them as parameters.

Both renderers read the same settings: Mitsuba from the XML with the film and integrator properties
rewritten (loaded from a string, with the scene's folder on Mitsuba's file resolver), the tracer from the
file with its camera resized. `content_key` hashes the file, every file it names (meshes, includes,
textures) and the settings, so that a cached result is never reused for an edited scene.
"""
from __future__ import annotations

import copy
import hashlib
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

from tracer.errors import UserError

SET_ANYWHERE = ("width", "height", "max_depth", "spp")   # -D names a check applies to any scene
MITSUBA_FILM = (768, 576)      # hdrfilm's default size
MITSUBA_MAX_DEPTH = -1         # the path integrator's default
# the integrators of Mitsuba a comparison renders: each is Mitsuba's own, against the tracer's estimate of its image
COMPARED_INTEGRATORS = ("path", "volpath", "volpathmis", "direct", "ptracer")
DIRECT_DEPTH = 2               # the direct integrator's image: the path integrator's at max_depth 2


class ScenePlanError(UserError, ValueError):
    """A scene or an override a comparison cannot use (a user error: reported in one line)."""


@dataclass(frozen=True)
class ScenePlan:
    path: Path
    width: int
    height: int
    max_depth: int
    params: dict[str, str] = field(default_factory=dict)   # the scene's own <default>s, overridden
    overridden: tuple[str, ...] = ()                        # the names of params given by the check (-D)

    @property
    def integrator(self) -> str:
        """The type of the integrator both renderers render (a moment or aov wrapper's nested one; path
        where the scene declares none)."""
        node = _integrator(_with_film_size(self.path, self.width, self.height), self.params)
        return "path" if node is None else _substitute(node.get("type", ""), self.params)

    def mitsuba_xml(self) -> str:
        """The scene's XML with the film size and max_depth written into it."""
        root = _with_film_size(self.path, self.width, self.height)
        integrator = _integrator(root, self.params)
        if integrator is None:
            integrator = ET.Element("integrator", {"type": "path"})
            root.insert(0, integrator)
        else:           # a `moment` wrapper (Mitsuba's render tests) replaced by the integrator it wraps
            outer = root.find("integrator")
            root[list(root).index(outer)] = integrator
        kind = _substitute(integrator.get("type", ""), self.params)
        if kind not in COMPARED_INTEGRATORS:
            raise ScenePlanError(f"{self.path}: <integrator type=\"{kind}\">: the comparison uses Mitsuba's "
                                 f"{', '.join(COMPARED_INTEGRATORS)} integrator (or a moment or aov integrator wrapping one)")
        if kind != "direct":
            _set(integrator, "integer", "max_depth", str(self.max_depth))
        elif self.max_depth != DIRECT_DEPTH:
            raise ScenePlanError(f"{self.path}: the direct integrator renders direct light only (max_depth "
                                 f"{DIRECT_DEPTH}); it takes no max_depth {self.max_depth}")
        return ET.tostring(root, encoding="unicode")

    def resolved_xml(self, spp: int) -> str:
        """One self-contained Mitsuba XML (`{scene_resolved}`): mitsuba_xml() with every `$name` replaced by its
        value and the <default>s dropped, the samples per pass written into the sampler, and every filename
        made absolute (the <path>s dropped)."""
        root = ET.fromstring(self.mitsuba_xml())
        folders = [self.path.parent] + [self.path.parent / p.get("value", "") for p in root.iter("path")]
        for node in list(root):
            if node.tag in ("default", "path"):
                root.remove(node)
        for node in root.iter():
            for key, value in node.attrib.items():
                node.set(key, _substitute(value, self.params))
            if node.get("name") == "filename":
                found = next((d / node.get("value", "") for d in folders if (d / node.get("value", "")).is_file()), None)
                if found is not None:
                    node.set("value", str(found.resolve()))
        sensor = _first(root, "sensor", self.path)
        samplers = {n.get("id"): n for n in root.iter("sampler")}
        for ref in sensor.findall("ref"):           # a sampler declared elsewhere and referenced: copied in
            if ref.get("id") in samplers:
                sensor[list(sensor).index(ref)] = copied = copy.deepcopy(samplers[ref.get("id")])
                copied.attrib.pop("id")
        sampler = sensor.find("sampler")
        if sampler is None:
            sampler = ET.SubElement(sensor, "sampler", {"type": "independent"})
        _set(sampler, "integer", "sample_count", str(spp))
        return ET.tostring(root, encoding="unicode")

    def mitsuba_scene(self, spp: int):
        """The scene loaded by Mitsuba (the variant of validation.verdict.mitsuba_render.mitsuba())."""
        from .mitsuba_render import loading, mitsuba

        mi = mitsuba()
        saved = mi.FileResolver(mi.file_resolver())
        mi.file_resolver().prepend(str(self.path.parent.resolve()))
        text = self.mitsuba_xml()
        params = {k: v for k, v in (self.params | {"spp": str(spp)}).items() if k in _names(text)}
        try:
            with loading():
                return mi.load_string(text, **params)
        except RuntimeError as e:
            raise ScenePlanError(f"{self.path}: Mitsuba cannot load the scene: {_last_line(e)}") from None
        finally:
            mi.set_file_resolver(saved)

    def tracer_scene(self):
        """The scene loaded by the tracer, its camera at this plan's size."""
        import tracer

        scene = tracer.load_scene(self.path, **{k: v for k, v in self.params.items() if k in _names(self.path.read_text(errors="replace"))})
        return replace(scene, camera=replace(scene.camera, width=self.width, height=self.height))

    def defines(self, spp: int) -> list[str]:
        """`-D name=value` arguments that give an external renderer this plan's settings: the film size, the depth,
        the samples per pass and the scene parameters the check was given (the scene's own values are in its
        file and in the resolved scene)."""
        values = {k: self.params[k] for k in self.overridden} | {"width": self.width, "height": self.height,
                                                                  "max_depth": self.max_depth, "spp": spp}
        return [f"{k}={v}" for k, v in values.items()]

    def content_key(self, **settings) -> str:
        """SHA-256 over the scene's files, this plan and `settings` (spp, passes, seed, renderer...)."""
        h = hashlib.sha256(files_digest(self.path).encode())
        h.update(json.dumps({"width": self.width, "height": self.height, "max_depth": self.max_depth,
                             "params": self.params, **settings}, sort_keys=True, default=str).encode())
        return h.hexdigest()[:24]


def plan(path: str | Path, defines: dict[str, str] | None = None, size: int | None = None,
         max_depth: int | None = None) -> ScenePlan:
    """The settings a comparison renders `path` with.

    `defines` override the scene's `<default>`s; width, height and max_depth may be given for any scene.
    Without a width or height, the scene's film is scaled so that its longer side is `size` (None: as is).
    """
    path = Path(path)
    if not path.is_file():
        raise ScenePlanError(f"scene file '{path}' not found")
    defines = dict(defines or {})
    root = _parse(path)
    declared: dict[str, str] = {}
    for d in root.findall("default"):       # the first declaration wins (an included file's come after), as in Mitsuba
        declared.setdefault(d.get("name"), d.get("value", ""))
    unknown = sorted(set(defines) - set(declared) - set(SET_ANYWHERE))
    if unknown:
        raise ScenePlanError(f"{path}: -D {unknown[0]}: the scene declares no <default name=\"{unknown[0]}\"> "
                             f"(it declares: {', '.join(sorted(declared)) or 'none'}; any scene takes "
                             f"{', '.join(SET_ANYWHERE)})")
    params = declared | {k: v for k, v in defines.items() if k in declared}
    film = _first(root, "sensor", path).find("film")
    crop = [n for n in ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height")
            if film is not None and _value(film, n, params) is not None]
    if crop:
        raise ScenePlanError(f"{path}: the film has a crop window ({crop[0]}): a comparison renders whole films, "
                             "resized (tests/test_film_crop.py compares crops with Mitsuba)")
    width, height = _film_size(root, params, path)
    if "width" in defines or "height" in defines:
        width = _integer(defines.get("width", width), "width", path)
        height = _integer(defines.get("height", height), "height", path)
    elif size is not None:
        scale = size / max(width, height)
        width, height = max(1, round(width * scale)), max(1, round(height * scale))
    if max_depth is None:
        max_depth = _integer(defines.get("max_depth", _scene_max_depth(root, params, path)), "max_depth", path)
    if max_depth < -1 or max_depth == 0:
        raise ScenePlanError(f"max_depth must be -1 (unbounded) or at least 1, got {max_depth}")
    params |= {k: str(v) for k, v in (("width", width), ("height", height), ("max_depth", max_depth))
               if k in declared}
    return ScenePlan(path, width, height, max_depth, params, tuple(k for k in defines if k in declared))


def _with_film_size(path: Path, width: int, height: int) -> ET.Element:
    """The scene's XML tree, its includes inlined, with the film's width and height set."""
    root = _parse(path)
    sensor = _first(root, "sensor", path)
    film = sensor.find("film")
    if film is None:
        film = ET.SubElement(sensor, "film", {"type": "hdrfilm"})
    _set(film, "integer", "width", str(width))
    _set(film, "integer", "height", str(height))
    return root


def resized_xml(path: Path, width: int, height: int) -> str:
    """The scene's XML, everything else as it stands, with its film `width` x `height`."""
    return ET.tostring(_with_film_size(Path(path), width, height), encoding="unicode")


def files_digest(path: str | Path) -> str:
    """SHA-256 of a scene's content: the file and every file it names (validation.verdict.scenefile.referenced_files)."""
    h = hashlib.sha256()
    for f in referenced_files(Path(path)):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def referenced_files(path: Path) -> list[Path]:
    """`path` and every existing file it names with a `filename` (meshes, textures, includes), recursively; an
    included file's names are also looked up in the folders of the files that include it (their `<path>`s)."""
    seen: list[Path] = []
    todo: list[tuple[Path, list[Path]]] = [(Path(path), [])]
    while todo:
        f, inherited = todo.pop()
        if f in seen or not f.is_file():
            continue
        seen.append(f)
        text = f.read_text(errors="replace") if f.suffix.lower() == ".xml" else ""
        folders = [f.parent] + [f.parent / p for p in re.findall(r'<path\s+value="([^"]+)"', text)] + inherited
        for name in re.findall(r'(?:name="filename"\s+value|<include\s+filename)="([^"$]+)"', text):
            todo += [(d / name, folders) for d in folders if (d / name).is_file()][:1]
    return [seen[0]] + sorted(seen[1:])


def _parse(path: Path) -> ET.Element:
    """The scene's XML with every <include> replaced by the included file's elements (as Mitsuba reads it),
    so that a sensor or integrator declared in an included file is found and rewritten."""
    root = _read(path)
    folders = [path.parent] + [path.parent / p.get("value", "") for p in root.iter("path")]
    _inline(root, folders, depth=0)
    return root


def _read(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as e:
        raise ScenePlanError(f"{path}: malformed XML: {e}") from None
    except OSError as e:
        raise ScenePlanError(f"{path}: {e.strerror}") from None


def _inline(node: ET.Element, folders: list[Path], depth: int) -> None:
    for i, child in reversed(list(enumerate(node))):
        if child.tag != "include":
            _inline(child, folders, depth)
            continue
        name = child.get("filename", "")
        found = next((d / name for d in folders if (d / name).is_file()), None)
        if found is None or depth > 16:
            raise ScenePlanError(f"<include filename=\"{name}\">: no such file in {', '.join(map(str, folders))}"
                                 if found is None else f"<include filename=\"{name}\">: includes nested too deep")
        included = _read(found)
        _inline(included, folders + [found.parent], depth + 1)
        node[i:i + 1] = list(included)


def _first(root: ET.Element, tag: str, path: Path) -> ET.Element:
    node = root.find(tag)
    if node is None:
        raise ScenePlanError(f"{path}: the scene has no <{tag}>")
    return node


def _set(node: ET.Element, tag: str, name: str, value: str) -> None:
    prop = next((c for c in node if c.get("name") == name), None)
    if prop is None:
        prop = ET.SubElement(node, tag, {"name": name})
    prop.set("value", value)


def _value(node: ET.Element | None, name: str, params: dict[str, str]) -> str | None:
    prop = None if node is None else next((c for c in node if c.get("name") == name), None)
    if prop is None:
        return None
    return _substitute(prop.get("value", ""), params)


def _substitute(text: str, params: dict[str, str]) -> str:
    return re.sub(r"\$([A-Za-z_][A-Za-z0-9_]*)", lambda m: params.get(m.group(1), m.group(0)), text)


def _integer(text, name: str, path: Path) -> int:
    try:
        return int(text)
    except (TypeError, ValueError):
        raise ScenePlanError(f"{path}: {name} must be an integer, got '{text}'") from None


def _film_size(root: ET.Element, params: dict[str, str], path: Path) -> tuple[int, int]:
    film = _first(root, "sensor", path).find("film")
    w, h = _value(film, "width", params), _value(film, "height", params)
    return (_integer(w, "width", path) if w is not None else MITSUBA_FILM[0],
            _integer(h, "height", path) if h is not None else MITSUBA_FILM[1])


def _integrator(root: ET.Element, params: dict[str, str]) -> ET.Element | None:
    """The scene's integrator; for Mitsuba's `moment` (which adds a second-moment image to the image of the
    integrator it wraps) and `aov` (AOV channels beside its first nested integrator's image), the wrapped one."""
    node = root.find("integrator")
    while node is not None and _substitute(node.get("type", ""), params) in ("moment", "aov"):
        kind = _substitute(node.get("type", ""), params)
        nested = node.findall("integrator")
        if len(nested) != 1 and not (kind == "aov" and nested):
            raise ScenePlanError(f"<integrator type=\"{kind}\"> wraps {len(nested)} integrators; the comparison "
                                 "takes the image of exactly one")
        node = nested[0]      # an aov integrator's image is its first nested integrator's
    return node


def _scene_max_depth(root: ET.Element, params: dict[str, str], path: Path) -> int:
    integrator = _integrator(root, params)
    if integrator is not None and _substitute(integrator.get("type", ""), params) == "direct":
        return DIRECT_DEPTH
    value = _value(integrator, "max_depth", params)
    return MITSUBA_MAX_DEPTH if value is None else _integer(value, "max_depth", path)


def _last_line(e: Exception) -> str:
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return lines[-1] if lines else type(e).__name__


def _names(text: str) -> set[str]:
    """The parameters ($name) a scene's text uses."""
    return set(re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", text))
