"""Mitsuba's textures: `checkerboard`, `bitmap`, `rawconstant` and `mesh_attribute`, their host description, one
table over the scene's textures and the lookups in the kernel (tracer/bitmap.py reads the images, the meshes'
attributes are tabled by shapes.mesh.AttributeTable). A material parameter
that a texture drives names it by slot (materials.bsdf.BSDF.slot_textures); the kernel evaluates it as a
colour (`eval`, Mitsuba's eval_3) or as a float (`eval_1`: the colour's luminance, as Mitsuba's eval_1 of a
three-channel texture, and the value itself for a grey one). As in Mitsuba 3.9.1, a checkerboard read as a
float shows color0 on the squares where read as a colour it shows color1 (TextureTables.eval)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import drjit as dr
import numpy as np

from ..bitmap import BitmapError, read_bitmap
from ..jit import HOST_FLOAT, Array2f, Array3f, Bool, Float, UInt32, gather_row, gather_vec3, packet_size, row_table
from ..spectra import rgb

PLUGINS = {"checkerboard": ("color0", "color1", "to_uv"),
           "bitmap": ("filename", "bitmap", "data", "raw", "filter_type", "wrap_mode", "to_uv", "format", "accel"),
           "rawconstant": ("value",),
           "mesh_attribute": ("name", "scale")}
FIELDS = 18         # per texture: kind, two colours, to_uv's two rows, a bitmap's offset, size and modes
ROW = packet_size(FIELDS)     # the rows' stride (jit.row_table)
IDENTITY_UV = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
LUMINANCE = (0.212671, 0.715160, 0.072169)   # Mitsuba's luminance() of linear sRGB (CIE Y)
CHECKERBOARD, BITMAP, CONSTANT, ATTRIBUTE = 1, 2, 3, 4     # a texture's kind in its row (0: none)
REPEAT, CLAMP, MIRROR = 0, 1, 2              # a bitmap's wrap modes


@dataclass(frozen=True)
class Checkerboard:
    """Mitsuba's `checkerboard` texture: with (u', v') = to_uv (u, v), color0 where the fractional parts of u'
    and v' are both above 1/2 or both not, color1 elsewhere. Its colours are not bounded (a reflectance's
    reader bounds them: `check_unit_interval`)."""

    color0: tuple[float, float, float] = (0.4, 0.4, 0.4)
    color1: tuple[float, float, float] = (0.2, 0.2, 0.2)
    to_uv: tuple[tuple[float, float, float], ...] = IDENTITY_UV

    def bounds(self) -> tuple[float, float]:
        return min(*self.color0, *self.color1), max(*self.color0, *self.color1)


@dataclass(frozen=True, eq=False)
class Bitmap:
    """Mitsuba's `bitmap` texture (tracer/bitmap.py): a linear RGB image looked up at to_uv (u, v)."""

    image: np.ndarray                      # (H, W, 3) float32
    to_uv: tuple[tuple[float, float, float], ...] = IDENTITY_UV
    bilinear: bool = True
    wrap: int = REPEAT

    def bounds(self) -> tuple[float, float]:
        return float(self.image.min()), float(self.image.max())


@dataclass(frozen=True)
class Constant:
    """Mitsuba's `rawconstant`: one value everywhere, taken as given (no colour conversion, no bounds)."""

    value: tuple[float, float, float]

    def bounds(self) -> tuple[float, float]:
        return min(self.value), max(self.value)


# how a parameter reads a texture, as Mitsuba's Texture methods: a spectrum (`eval`: in RGB variants a colour,
# a one-channel attribute repeated), a float (`eval_1`), a colour (`eval_3`, the normal map's)
SPECTRUM, FLOAT, COLOR3 = "spectrum", "float", "color3"
CHANNELS = {SPECTRUM: (1, 3), FLOAT: (1,), COLOR3: (3,)}   # the attribute channels each reads (Mitsuba 3.9.1
                                                           # reads 0 in its JIT variants for the others)


@dataclass(frozen=True)
class MeshAttribute:
    """Mitsuba's `mesh_attribute`: the hit mesh's attribute `name` (tracer.ply_attributes) times `scale`; a
    vertex attribute interpolated by the hit's barycentric coordinates, a face attribute the face's value.
    `read`: how the parameter holding it reads it (SPECTRUM, FLOAT, COLOR3), which the channels must fit."""

    name: str
    scale: float = 1.0
    read: str = SPECTRUM

    def check(self, channels: int) -> str:
        """Why an attribute of `channels` cannot be read as `read` ('' where it can)."""
        if channels in CHANNELS[self.read]:
            return ""
        return (f"mesh_attribute '{self.name}' has {channels} channel{'s' * (channels > 1)} where a {self.read} is "
                f"read; supported: {' or '.join(map(str, CHANNELS[self.read]))} (Mitsuba 3.9.1 reads 0 or throws)")


Texture = Checkerboard | Bitmap | Constant | MeshAttribute


def from_xml(ctx, props, node) -> Texture:
    kind = node.attrib.get("type")
    if kind == "bitmap":
        return _bitmap(ctx, node, props)
    if kind == "mesh_attribute":
        return _mesh_attribute(ctx, node, props)
    if kind == "rawconstant":
        if not props.has("value"):
            raise ctx.error(node, "rawconstant needs a 'value' (as in Mitsuba)")
        value = props.get("value", 0.0, ("float", "integer", "vector"))
        props.finish()
        return Constant(rgb(np.broadcast_to(np.asarray(value, float), 3)))
    colours = [props.colour(name, d, unbounded=True) for name, d in (("color0", 0.4), ("color1", 0.2))]
    m = props.get("to_uv", np.eye(4), ("transform",))
    props.finish()
    return Checkerboard(rgb(colours[0]), rgb(colours[1]), _to_uv(m))


ATTRIBUTE_KINDS = ("vertex_", "face_")
ATTRIBUTE_SHAPES = ("ply",)     # the shapes whose files hold attributes (Mitsuba's obj and serialized read none)


def read_as(texture: Texture, read: str) -> Texture:
    """The texture as a parameter reading it as `read` (SPECTRUM, FLOAT, COLOR3) sees it: a mesh attribute
    carries how it is read, which its mesh's channels must fit (shapes.mesh.attribute_refusal)."""
    return replace(texture, read=read) if isinstance(texture, MeshAttribute) else texture


def _mesh_attribute(ctx, node, props) -> MeshAttribute:
    name = props.get("name", None, ("string",))
    scale = props.get("scale", 1.0, ("float", "integer"))
    props.finish()
    if name is None:
        raise ctx.error(node, "mesh_attribute needs a <string name=\"name\"> (as in Mitsuba)")
    if not name.startswith(ATTRIBUTE_KINDS):
        raise ctx.error(props.values["name"], f"mesh_attribute name '{name}' unsupported; supported: a name "
                                              "starting with 'vertex_' or 'face_' (a mesh's attributes)")
    return MeshAttribute(name, float(scale))


def _to_uv(m: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    """A 4x4 transform acts on (u, v) through its x, y rows and columns and its translation (Mitsuba's
    conversion of a 4x4 to a 3x3 transform)."""
    return tuple(tuple(float(x) for x in row) for row in m[np.ix_([0, 1, 3], [0, 1, 3])])


# `format`: the texels' storage; `variant` (float32) holds exactly what `auto` holds for the 8-bit and float32
# images the tracer reads, so both are honoured; float16 and uint8 would round them and are refused
FORMATS = ("auto", "variant")


def _bitmap(ctx, node, props) -> Bitmap:
    filename = props.get("filename", None, ("string",))
    raw = props.get("raw", False, ("boolean",))
    choices = {"filter_type": ("bilinear", "nearest"), "wrap_mode": ("repeat", "clamp", "mirror"), "format": FORMATS}
    modes = {}
    for name, accepted in choices.items():
        modes[name] = props.get(name, accepted[0], ("string",)).lower()
        if modes[name] not in accepted:
            raise ctx.error(props.values[name], f"{name} '{modes[name]}' unsupported; supported: {', '.join(accepted)}")
    m = props.get("to_uv", np.eye(4), ("transform",))
    props.ignore("accel")                  # how lookups are accelerated, not their values
    props.finish()
    if filename is None:
        raise ctx.error(node, "bitmap needs a <string name=\"filename\">")
    file = ctx.resolve(filename)
    if not file.is_file():
        raise ctx.error(node, f"image '{filename}' not found (looked in {', '.join(map(str, ctx.resolver))})")
    try:
        image = read_bitmap(file, raw)
    except BitmapError as e:
        raise ctx.error(node, str(e)) from None
    return Bitmap(image, _to_uv(m), modes["filter_type"] == "bilinear",
                  choices["wrap_mode"].index(modes["wrap_mode"]))


class TextureTables:
    """One row per texture (row 0: none) and every bitmap's texels; a texture is named by its row. Rows and
    texels are each gathered in one packet load (jit.row_table). `attributes`: the meshes' attributes
    (shapes.mesh.AttributeTable), where a texture is a mesh_attribute."""

    def __init__(self, textures: list[Texture], attributes=None):
        rows = np.zeros((len(textures) + 1, FIELDS))
        texels = [np.zeros((1, 3), np.float32)]
        offset = 1
        self.attributes = attributes
        for i, t in enumerate(textures, start=1):
            if isinstance(t, Checkerboard):
                rows[i, :13] = [CHECKERBOARD, *t.color0, *t.color1, *np.asarray(t.to_uv)[:2].ravel()]
            elif isinstance(t, Constant):
                rows[i, :4] = [CONSTANT, *t.value]
            elif isinstance(t, MeshAttribute):
                rows[i, :5] = [ATTRIBUTE, *attributes.layout[t.name], t.scale]
            else:
                h, w = t.image.shape[:2]
                rows[i] = [BITMAP, 0, 0, 0, 0, 0, 0, *np.asarray(t.to_uv)[:2].ravel(), offset, w, h, t.bilinear, t.wrap]
                texels.append(t.image.reshape(-1, 3))
                offset += h * w
        self.rows = row_table(rows)
        self.texels = row_table(np.concatenate(texels))
        self.kinds = {KIND[type(t)] for t in textures}

    def _row(self, index: UInt32, active: Bool) -> list[Float]:
        return gather_row(self.rows, ROW, index, active, FIELDS)

    @staticmethod
    def _uv(t: list[Float], uv: tuple[Float, Float]) -> tuple[Float, Float]:
        u, v = uv
        return dr.fma(t[7], u, dr.fma(t[8], v, t[9])), dr.fma(t[10], u, dr.fma(t[11], v, t[12]))

    def eval(self, index: UInt32, uv: tuple[Float, Float], active: Bool, as_float: bool = False,
             hit: tuple[UInt32, Float, Float] | None = None) -> Array3f:
        """Texture `index`'s colour at texture coordinates uv (index > 0), on the mesh triangle and at the
        barycentric coordinates `hit` (its index in the meshes, b1, b2; for mesh attributes). `as_float`: the
        colour eval_1 takes the luminance of, which for a checkerboard is the other square's (Mitsuba 3.9.1's
        eval_1 picks color0 where the fractional parts of u' and v' are on different sides of 1/2, its eval
        where on the same)."""
        t = self._row(index, active)
        tu, tv = self._uv(t, uv)
        first = (tu - dr.floor(tu) > 0.5) == (tv - dr.floor(tv) > 0.5)
        if as_float:
            first = ~first
        value = Array3f(t[1], t[2], t[3])
        if CHECKERBOARD in self.kinds:
            value = dr.select(first | (t[0] != CHECKERBOARD), value, Array3f(t[4], t[5], t[6]))
        if BITMAP in self.kinds:
            bitmap = t[0] == BITMAP
            value = dr.select(bitmap, self._bitmap(t, tu, tv, active & bitmap), value)
        if ATTRIBUTE in self.kinds:
            attribute = t[0] == ATTRIBUTE
            value = dr.select(attribute, self.attributes.eval(t[1:5], hit, active & attribute), value)
        return value

    def eval_1(self, index: UInt32, uv: tuple[Float, Float], active: Bool,
               hit: tuple[UInt32, Float, Float] | None = None) -> Float:
        """Texture `index` as a float: its colour's luminance (exact for a grey one), a one-channel mesh
        attribute's value."""
        value = self.eval(index, uv, active, as_float=True, hit=hit)
        if ATTRIBUTE in self.kinds:
            kind = dr.gather(Float, self.rows, index * ROW, active)
            return dr.select(kind == ATTRIBUTE, value.x, luminance(value))
        return luminance(value)

    def grad_1(self, index: UInt32, uv: tuple[Float, Float], active: Bool) -> Array2f:
        """d eval_1 / d(u, v): as Mitsuba's eval_1_grad, the derivative of a bitmap's bilinear interpolation
        of its four texels' luminances (to_uv's linear part applied by its transpose); 0 for the other
        kinds (piecewise constant) and for nearest-neighbour lookups."""
        t = self._row(index, active)
        tu, tv = self._uv(t, uv)
        active = active & (t[0] == BITMAP) & (t[16] > 0)
        (f00, f10, f01, f11), (wx, wy) = self._fetch(t, tu, tv, active)
        f00, f10, f01, f11 = (luminance(f) for f in (f00, f10, f01, f11))
        w, h = t[14], t[15]
        dx = dr.fma(1.0 - wy, f10 - f00, wy * (f11 - f01))
        dy = dr.fma(1.0 - wx, f01 - f00, wx * (f11 - f10))
        du = (t[7] * dx + t[10] * dy) * w      # Mitsuba scales by the resolution after the transpose
        dv = (t[8] * dx + t[11] * dy) * h
        return dr.select(active, Array2f(du, dv), Array2f(0.0))

    def _fetch(self, t: list[Float], u: Float, v: Float, active: Bool):
        """A bitmap's four texels around (u, v), wrapped (x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1),
        and the bilinear weights toward the second column and row (0 for nearest lookups)."""
        offset, w, h, bilinear, wrap = t[13], t[14], t[15], t[16] > 0, t[17]

        def wrapped(i: Float, n: Float) -> tuple[UInt32, UInt32]:
            """The texels i and i + 1 of an axis of n, wrapped: repeat and mirror by i's remainder over their
            period (n; 2n, reflected in its second half), clamp by clipping."""
            period = dr.select(wrap == MIRROR, 2.0 * n, n)
            r0 = modulo(i, period)
            r1 = dr.select(r0 + 1.0 >= period, 0.0, r0 + 1.0)
            out = []
            for r, k in ((r0, i), (r1, i + 1.0)):
                folded = dr.select((wrap == MIRROR) & (r >= n), 2.0 * n - 1.0 - r, r)
                out.append(UInt32(dr.select(wrap == CLAMP, dr.clip(k, 0.0, n - 1.0), folded)))
            return out[0], out[1]

        x = dr.select(bilinear, dr.fma(u, w, -0.5), u * w)
        y = dr.select(bilinear, dr.fma(v, h, -0.5), v * h)
        x0, y0 = dr.floor(x), dr.floor(y)
        wx, wy = dr.select(bilinear, x - x0, 0.0), dr.select(bilinear, y - y0, 0.0)
        (i0, i1), (j0, j1) = wrapped(x0, w), wrapped(y0, h)

        def texel(i: UInt32, j: UInt32) -> Array3f:
            return gather_vec3(self.texels, UInt32(offset) + j * UInt32(w) + i, active)

        return (texel(i0, j0), texel(i1, j0), texel(i0, j1), texel(i1, j1)), (wx, wy)

    def _bitmap(self, t: list[Float], u: Float, v: Float, active: Bool) -> Array3f:
        """A bitmap texture's texels around (u, v), filtered and wrapped (tracer/bitmap.py)."""
        (f00, f10, f01, f11), (wx, wy) = self._fetch(t, u, v, active)
        top = f00 * (1.0 - wx) + f10 * wx
        bottom = f01 * (1.0 - wx) + f11 * wx
        return top * (1.0 - wy) + bottom * wy


KIND = {Checkerboard: CHECKERBOARD, Bitmap: BITMAP, Constant: CONSTANT, MeshAttribute: ATTRIBUTE}


# remainder passes: each leaves |r| below n + |r| 2^(1 - mantissa bits), so that these take any finite float
# to within one period (float32: 2^128 -> 2^105 -> ... -> below 2n; float64: 2^1024 likewise)
MODULO_PASSES = 20 if HOST_FLOAT == np.float64 else 6


def modulo(i: Float, n: Float) -> Float:
    """i mod n in [0, n), exactly, for integer-valued floats i of any magnitude and integers n > 0. A pass
    r - n floor(r / n) is exact in one fused multiply-add (the result is an integer far smaller than r, which
    needs no more bits than r), but floor(r / n) is off by many periods where r / n has an ulp above 1: the
    passes repeat it until r lies within one period of [0, n). (r - n * floor(r / n), with n q rounded first,
    picked other texels, or none, from |u| of about 2^24 / n.)"""
    r = i
    for _ in range(MODULO_PASSES):
        r = dr.fma(-n, dr.floor(r / n), r)
    return dr.select(r < 0.0, r + n, dr.select(r >= n, r - n, r))


def luminance(c: Array3f) -> Float:
    return c.x * LUMINANCE[0] + c.y * LUMINANCE[1] + c.z * LUMINANCE[2]
