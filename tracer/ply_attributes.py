"""A PLY file's extra vertex and face properties as named mesh attributes, grouped as Mitsuba 3.9.1's `ply`
shape groups them (its documentation of the plugin; its `mesh_attribute` texture reads them):

- `r`, `g`, `b` (or `red`, `green`, `blue`, then with `alpha`), with `a` if present: the attribute
  `{vertex|face}_color` of 3 (or 4) channels;
- consecutive properties `{prefix}_{postfix}` with one prefix and the postfixes in order along one of the rows
  x y z w, r g b a, 0 1 2 3, 1 2 3 4: the attribute `{vertex|face}_{prefix}` (`..._{prefix}_color` for
  r g b a) of as many channels, kept when 1 or 3 (Mitsuba warns and drops the others);
- properties without `_`, with a postfix longer than one letter, or whose first postfix starts no row, are
  dropped (and end the group being read).

Where Mitsuba 3.9.1's reader goes astray (a prefix met again after its group closed, postfixes out of
order, a fifth field: it then skips fields past the offending ones, and the next group's channel count is
off), the file's attributes are not trusted: `Attributes.unread` says why, and a scene that reads them is
refused. Values are float32, as Mitsuba stores them (integers converted, not normalised)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ROWS = ("xyzw", "rgba", "0123", "1234")   # the postfix sequences, by category
VERTEX_RESERVED = frozenset({"x", "y", "z", "nx", "ny", "nz", "u", "v"})
FACE_RESERVED = frozenset({"i0", "i1", "i2"})    # Mitsuba's names of a face's indices (a property so named: refused)


@dataclass(frozen=True)
class Attributes:
    """A mesh's attributes by name: (vertices or faces, channels) float32 arrays, read-only."""

    values: dict[str, np.ndarray] = field(default_factory=dict)
    unread: str = ""       # why the file's attributes are not trusted ('' where they are)

    def describe(self) -> str:
        return ", ".join(f"{name} ({a.shape[1]} channel{'s' * (a.shape[1] > 1)})" for name, a in self.values.items()) \
            or "none"


class Refused(ValueError):
    """A file Mitsuba's ply refuses: two groups of its properties give one attribute name, or a face property
    takes the name of a face index."""


def groups(names: list[str | None], element: str, reserved: set[str]) -> tuple[list[tuple[str, list[str]]], str]:
    """The attributes (name, its properties in channel order) of an element's properties `names` (None for a
    list property, which ends a group), and why the grouping is not trusted ('' where it is). `reserved`:
    the properties the shape reads itself (positions, normals, texture coordinates, face indices)."""
    present = set(n for n in names if n is not None)
    rename = {}
    if not {"r", "g", "b"} <= present and {"red", "green", "blue"} <= present:
        rename = {k: v for k, v in (("red", "r"), ("green", "g"), ("blue", "b"), ("alpha", "a")) if k in present}
    present = {rename.get(n, n) for n in present}
    out = []
    if {"r", "g", "b"} <= present:
        inverse = {v: k for k, v in rename.items()}
        out.append((element + "color", [inverse.get(c, c) for c in "rgba" if c in present]))
    skip = set(reserved) | {"r", "g", "b", "a"} | set(rename)
    seen: set[str] = set()
    prefix, row, fields = None, 0, []

    def close() -> None:
        nonlocal prefix, fields
        if prefix is not None and len(fields) in (1, 3):
            out.append((element + prefix + ("_color" if row == 1 else ""), fields))
            seen.add(prefix)
        prefix, fields = None, []

    for name in names:
        if name in skip:
            continue
        if name is None or "_" not in name or len(name.rsplit("_", 1)[1]) != 1:
            close()
            continue
        head, post = name.rsplit("_", 1)
        if prefix is not None and head != prefix:
            close()
        if prefix is None:
            if head in seen:
                return out, f"property '{name}' repeats the prefix of an attribute before it"
            starts = [k for k, r in enumerate(ROWS) if r[0] == post]
            if not starts:
                continue
            prefix, row, fields = head, starts[0], [name]
        elif len(fields) == 4 or post != ROWS[row][len(fields)]:
            return out, f"property '{name}' does not continue the postfixes {ROWS[row]} of '{prefix}'"
        else:
            fields.append(name)
    close()
    return out, ""


def read(data: np.ndarray, properties: list[tuple[str, bool]], element: str, reserved: set[str]) -> Attributes:
    """The attributes of an element's rows `data` (a structured array), its properties in file order as
    (name, is a list)."""
    if element == "face_" and (taken := FACE_RESERVED & {name for name, _ in properties}):
        raise Refused(f"a face property named '{min(taken)}', Mitsuba's name of a face index (Mitsuba refuses "
                      "the file)")
    names = [None if is_list and name not in reserved else name for name, is_list in properties]
    found, unread = groups(names, element, reserved)
    values = {}
    for name, fields in found:
        if name in values:
            raise Refused(f"two groups of {element[:-1]} properties give the attribute '{name}' (Mitsuba refuses "
                          "the file)")
        a = np.stack([np.asarray(data[f], np.float32) for f in fields], axis=1).reshape(len(data), len(fields))
        a.flags.writeable = False
        values[name] = a
    return Attributes(values, unread)
