"""What the material modules' `from_xml` share: indices of refraction by value or name, reflectance bounds."""
import numpy as np

from ..ior import named_ior
from ..spectra import rgb


def read_ior(ctx, props, name: str, default: str) -> float:
    """An index of refraction given as a number or by name (Mitsuba's table, tracer.ior)."""
    value = props.get(name, default, ("float", "integer", "string"))
    if isinstance(value, str):
        try:
            return named_ior(value)
        except KeyError as e:
            raise ctx.error(props.values.get(name, props.node), e.args[0]) from None
    return float(value)


def check_unit_interval(ctx, node, name: str, value: np.ndarray) -> None:
    """Refuses a reflectance outside [0, 1]."""
    if np.any(value < 0) or np.any(value > 1):
        raise ctx.error(node, f"{name} must lie in [0, 1], got {rgb(value)}")
