"""`reports/index.html`: every report under a folder, with its title, its opening paragraph and its first
table (the headline numbers), linking to the report's HTML page where there is one and to its Markdown."""
from __future__ import annotations

import html
import re
import shutil
from pathlib import Path

from .markdown import inline, table_html, tables, title_and_lead
from .page import ASSETS

LEAD_CHARS = 400
TABLE_ROWS = 8


def write_index(reports: str | Path, title: str = "Validation reports") -> Path:
    """Writes `reports/index.html` listing every Markdown report under `reports` (a folder's README.md is
    that folder's report; the folder's own README.md is the overview and not listed) and every folder
    with an index.html but no README.md. Returns the page's path."""
    reports = Path(reports)
    entries = []
    for md in sorted(reports.rglob("*.md")):
        if md == reports / "README.md" or any(part.startswith(".") for part in md.relative_to(reports).parts):
            continue
        entries.append(_entry(reports, md))
    for page in sorted(reports.glob("*/**/index.html")):
        if not (page.parent / "README.md").exists():
            entries.append(_entry(reports, None, page))
    shutil.copyfile(ASSETS / "viewer.css", reports / "viewer.css")
    body = "\n".join(entries) if entries else "<p>No reports yet.</p>"
    out = reports / "index.html"
    out.write_text("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                   f"<title>{html.escape(title)}</title>"
                   '<meta name="viewport" content="width=device-width, initial-scale=1">'
                   '<link rel="stylesheet" href="viewer.css"></head>\n<body>\n'
                   f"<header><h1>{html.escape(title)}</h1><p class=\"intro\">{len(entries)} reports; each links "
                   "to its interactive page where it has one and to its Markdown. Regenerate with "
                   "<code>python -m validation.viewer index reports</code>.</p></header>\n"
                   f"{body}\n</body></html>\n", encoding="utf-8")
    return out


def _entry(reports: Path, md: Path | None, page: Path | None = None) -> str:
    if md is not None:
        name = md.parent.relative_to(reports).as_posix() if md.name == "README.md" else \
            md.relative_to(reports).with_suffix("").as_posix()
        text = md.read_text(encoding="utf-8")
        title, lead = title_and_lead(text)
        found = tables(text)
        if md.name == "README.md" and (md.parent / "index.html").exists():
            page = md.parent / "index.html"
    else:
        name = page.parent.relative_to(reports).as_posix()
        match = re.search(r"<title>(.*?)</title>", page.read_text(encoding="utf-8"), re.S)
        title, lead, found = html.unescape(match.group(1)) if match else name, "", []
    links = []
    if page is not None:
        links.append(f'<a href="{html.escape(page.relative_to(reports).as_posix())}">interactive page</a>')
    if md is not None:
        links.append(f'<a href="{html.escape(md.relative_to(reports).as_posix())}">Markdown</a>')
    lead = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", lead)  # links are relative to the report, not here
    if len(lead) > LEAD_CHARS:
        lead = lead[:LEAD_CHARS].rsplit(" ", 1)[0]
        if lead.count("`") % 2:  # not inside a code span
            lead = lead[:lead.rindex("`")].rstrip()
        lead += " …"
    parts = [f'<section class="report" id="{html.escape(name)}"><h2>{inline(title or name)}</h2>',
             f'<p class="links"><code>{html.escape(name)}</code>: {" · ".join(links)}</p>']
    if lead:
        parts.append(f'<p class="lead">{inline(lead)}</p>')
    if found:
        parts.append(table_html(found[0], max_rows=TABLE_ROWS))
    parts.append("</section>")
    return "".join(parts)
