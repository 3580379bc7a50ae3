"""docs/equations.md keeps up with the code: every equation number the code cites has an entry, and every
file and function an entry names exists. Pure text checks: no Dr.Jit, no rendering."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "equations.md"
SCANNED = ["tracer", "validation", "tests", "scripts", "examples"]   # folders whose .py and .md files are read
SCANNED_FILES = ["README.md"]

# "eq. 10", "Eq. 10:", "eq. 2-4", "eq. 7-8, 12", "eq. 8 / 12", "eqs. 2 and 3", "equation 5"; not "eq=False"
CITATION = re.compile(r"\b(?:eqs?\.|equations?)\s*(\d+(?:\s*(?:-|–|/|,|and)\s*\d+)*)", re.IGNORECASE)
NUMBER_OR_RANGE = re.compile(r"(\d+)(?:\s*[-–]\s*(\d+))?")
ENTRY = re.compile(r"^#{2,3}\s+Eq\.\s+(\d+)\b", re.MULTILINE)
# `path/to/file.py::name` or `path/to/file.py::Class.method`
LOCATION = re.compile(r"`((?:tracer|validation|tests)/[\w/]+\.py)::([\w.]+)`")


def cited_numbers(text: str) -> set[int]:
    """Equation numbers cited in `text`, ranges expanded."""
    numbers = set()
    for citation in CITATION.finditer(text):
        for first, last in NUMBER_OR_RANGE.findall(citation.group(1)):
            numbers.update(range(int(first), int(last or first) + 1))
    return numbers


def scanned_files() -> list[Path]:
    files = [ROOT / f for f in SCANNED_FILES]
    for folder in SCANNED:
        files += sorted(p for p in (ROOT / folder).rglob("*") if p.suffix in (".py", ".md"))
    return [f for f in files if f.is_file() and f.resolve() != Path(__file__).resolve()]


def citations_in_code() -> dict[int, list[str]]:
    """Equation number -> the files citing it."""
    where: dict[int, list[str]] = {}
    for f in scanned_files():
        for n in cited_numbers(f.read_text(encoding="utf-8")):
            where.setdefault(n, []).append(str(f.relative_to(ROOT)))
    return where


def documented_numbers(doc: str) -> set[int]:
    return {int(n) for n in ENTRY.findall(doc)}


def defines(source: str, name: str) -> bool:
    """Whether `source` defines `name` (a function, class or module-level assignment)."""
    return re.search(rf"^\s*(?:async\s+)?(?:def|class)\s+{re.escape(name)}\b|^{re.escape(name)}\s*[:=]",
                     source, re.MULTILINE) is not None


@pytest.mark.parametrize("text, expected", [
    ("ray-plane (eq. 2-4), Moeller", {2, 3, 4}),
    ("weighted by F and 1 - F (eq. 7-8, 12). Light", {7, 8, 12}),
    ("N facing the incoming ray (eq. 8 / 12)", {8, 12}),
    ('"""Eq. 10: (1/N) sum', {10}),
    ("how eq. 11's directions are drawn", {11}),
    ("the f of eq. 10)", {10}),
    ("Snell, equation 7, and eqs. 2 and 3", {2, 3, 7}),
    ("@dataclass(eq=False)", set()),
    ("the cosine, A = 1 / pdf_area (eq. 10, A = 1)", {10}),
])
def test_citation_parser(text, expected):
    assert cited_numbers(text) == expected


def test_every_cited_equation_is_documented():
    where = citations_in_code()
    assert where, "no equation citation found in the code: the citation pattern is broken"
    missing = {n: files for n, files in sorted(where.items()) if n not in documented_numbers(DOC.read_text("utf-8"))}
    assert not missing, ("docs/equations.md has no '## Eq. N' entry for equations the code cites: "
                         + "; ".join(f"eq. {n} in {', '.join(files)}" for n, files in missing.items()))


def test_every_location_in_the_doc_exists():
    """An entry's `file.py::name` must name an existing file that defines each part of the dotted name."""
    locations = LOCATION.findall(DOC.read_text("utf-8"))
    assert locations, "no `file.py::name` location found in docs/equations.md"
    stale = []
    for path, dotted in sorted(set(locations)):
        file = ROOT / path
        if not file.is_file():
            stale.append(f"{path} (no such file)")
            continue
        source = file.read_text("utf-8")
        stale += [f"{path}::{dotted} ({part} not defined there)" for part in dotted.split(".")
                  if not defines(source, part)]
    assert not stale, "docs/equations.md names code that does not exist: " + "; ".join(stale)
