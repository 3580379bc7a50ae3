"""What every generated report ends with and how it is written: the machine, the versions and the command
that produced it; files replaced atomically (an interrupted run leaves the previous report intact)."""
from __future__ import annotations

import json
import os
import platform
from importlib.metadata import version as package_version
from pathlib import Path

from tracer.imageio import atomic_write

PACKAGES = ("drjit", "numpy", "scipy", "scikit-image", "matplotlib")


def environment(command: str) -> list[str]:
    """Markdown lines: the command, the machine, Python, Mitsuba and the packages' versions."""
    from .mitsuba_render import version

    packages = ", ".join(f"{p} {package_version(p)}" for p in PACKAGES)
    return [f"- Command: `{command}`",
            f"- Machine: {platform.machine()}, {platform.processor() or 'cpu'}, {len(os.sched_getaffinity(0))} cores, "
            f"{platform.platform()}",
            f"- Python {platform.python_version()}; {version()}; {packages}"]


def write_text(path: str | Path, text: str) -> Path:
    """`text` written to `path` atomically (its folder created)."""
    path = Path(path)
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))
    return path


def write_json(path: str | Path, value) -> Path:
    return write_text(path, json.dumps(value, indent=1) + "\n")


def replace_section(path: Path, title: str, lines: list[str], before: str) -> Path:
    """Writes the Markdown section `lines` (starting with its heading `title`) into `path`: in place of an
    earlier section of that title, else before the heading `before`, else at the end; the rest is kept."""
    section = "\n".join(lines) + "\n\n"
    text = Path(path).read_text() if Path(path).exists() else ""
    if title in text:
        start = text.index(title)
        end = text.find("\n## ", start + len(title))
        text = text[:start] + section + (text[end + 1:] if end >= 0 else "")
    elif f"\n{before}" in text:
        at = text.index(f"\n{before}") + 1
        text = text[:at] + section + text[at:]
    else:
        text += ("\n" if text else "") + section
    return write_text(path, text)
