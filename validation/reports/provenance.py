"""What every generated report ends with and how it is written: the machine, the versions and the command
that produced it; files replaced atomically (an interrupted run leaves the previous report intact)."""
from __future__ import annotations

import json
import os
import platform
import shlex
from importlib.metadata import version as package_version
from pathlib import Path

from tracer.imageio import atomic_write

PACKAGES = ("drjit", "numpy", "scipy", "scikit-image", "matplotlib")


def environment(command: str) -> list[str]:
    """Markdown lines: the command, the machine, Python, Mitsuba and the packages' versions."""
    from ..verdict.mitsuba_render import version

    packages = ", ".join(f"{p} {package_version(p)}" for p in PACKAGES)
    return [f"- Command: `{command}`",
            f"- Machine: {platform.machine()}, {platform.processor() or 'cpu'}, {len(os.sched_getaffinity(0))} cores, "
            f"{platform.platform()}",
            f"- Python {platform.python_version()}; {version()}; {packages}"]


def command_line(argv: list[str], data: Path | None = None) -> str:
    """The command as a report quotes it; the folder `data` (a local copy of a public repository) is named by
    its role, MITSUBA_DATA_DIR, not by one machine's path."""
    words = [shlex.quote(a) for a in argv]
    if data is not None:
        words = ["MITSUBA_DATA_DIR" if Path(a) == Path(data) else w for a, w in zip(argv, words)]
    return "validate " + " ".join(words)


def relative_to(text: str, data: Path) -> str:
    """A message with the paths inside the folder `data` made relative to it, so that a report about a public
    repository's files names them as that repository does, not by one machine's path."""
    for prefix in dict.fromkeys((str(data.resolve()), str(data.absolute()), str(data))):
        text = text.replace(prefix.rstrip("/") + "/", "")
    return text


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
