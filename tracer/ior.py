"""Mitsuba's named indices of refraction (its `ior.h` table): a dielectric's `int_ior`/`ext_ior` may be
given by name instead of a number; names are matched case-insensitively."""
from __future__ import annotations

NAMED_IOR: dict[str, float] = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277, "carbon dioxide": 1.00045,
    "water": 1.3330, "acetone": 1.36, "ethanol": 1.361, "carbon tetrachloride": 1.461, "glycerol": 1.4729,
    "benzene": 1.501, "silicone oil": 1.52045, "bromine": 1.661,
    "water ice": 1.31, "fused quartz": 1.458, "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49,
    "bk7": 1.5046, "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}


def named_ior(name: str) -> float:
    """The index of refraction of a named material; KeyError naming the choices otherwise."""
    try:
        return NAMED_IOR[name.lower()]
    except KeyError:
        raise KeyError(f"no index of refraction named '{name}'; known: {', '.join(NAMED_IOR)}") from None
