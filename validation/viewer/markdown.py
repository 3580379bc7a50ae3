"""The Markdown the reports are written in, as far as the HTML pages show it: pipe tables, headings,
paragraphs, and inline `code`, **bold** and [links](target)."""
from __future__ import annotations

import html
import re
from dataclasses import dataclass

_INLINE = re.compile(r"`([^`]+)`|\*\*([^*]+)\*\*|\[([^\]]+)\]\(([^)\s]+)\)")


def inline(text: str) -> str:
    """One line of Markdown as HTML: everything escaped except `code`, **bold** and [text](link)."""
    out, pos = [], 0
    for m in _INLINE.finditer(text):
        out.append(html.escape(text[pos:m.start()]))
        code, bold, label, target = m.groups()
        if code is not None:
            out.append(f"<code>{html.escape(code)}</code>")
        elif bold is not None:
            out.append(f"<strong>{html.escape(bold)}</strong>")
        else:
            out.append(f'<a href="{html.escape(target)}">{html.escape(label)}</a>')
        pos = m.end()
    out.append(html.escape(text[pos:]))
    return "".join(out)


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    align: list[str]  # "left", "right" or "center" per column
    heading: str = ""  # the nearest heading above the table in its Markdown
    note: str = ""  # the paragraph right above the table (after its heading), which usually explains it


def _cells(line: str) -> list[str]:
    line = line.strip()
    if line.startswith("|"):
        line = line[1:]
    if line.endswith("|") and not line.endswith("\\|"):
        line = line[:-1]
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line)]


def _is_separator(line: str) -> bool:
    cells = _cells(line)
    return bool(cells) and all(re.fullmatch(r":?-{1,}:?", c) for c in cells)


def _alignment(cell: str) -> str:
    if cell.startswith(":") and cell.endswith(":"):
        return "center"
    return "right" if cell.endswith(":") else "left"


def tables(markdown: str) -> list[Table]:
    """Every pipe table in a Markdown text: a header line, a separator line (---, :--, --:), rows."""
    lines = markdown.splitlines()
    found = []
    heading, paragraph = "", []
    i = 0
    while i + 1 < len(lines):
        if lines[i].lstrip().startswith("|") and _is_separator(lines[i + 1]):
            note = " ".join(paragraph)
            header = _cells(lines[i])
            align = [_alignment(c) for c in _cells(lines[i + 1])]
            align += ["left"] * (len(header) - len(align))
            rows = []
            i += 2
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            found.append(Table(header, rows, align[:len(header)], heading, note))
            paragraph = []
        else:
            line = lines[i].strip()
            if line.startswith("#"):
                heading, paragraph = line.lstrip("#").strip(), []
            elif line.startswith("!["):
                paragraph = []
            elif line:
                paragraph = paragraph + [line] if i > 0 and lines[i - 1].strip() else [line]
            i += 1
    return found


def table_from_rows(rows: list[list[str]]) -> Table:
    """A table from rows of cells, the first row the header; numbers align right."""
    header, body = [str(c) for c in rows[0]], [[str(c) for c in r] for r in rows[1:]]
    numeric = re.compile(r"[-+]?[\d.,]+(e[-+]?\d+)?( ?[%x]| [A-Za-z]+)?")
    align = ["right" if body and all(numeric.fullmatch(r[j]) for r in body if j < len(r)) else "left"
             for j in range(len(header))]
    return Table(header, body, align)


def table_html(table: Table, caption: str | None = None, max_rows: int | None = None) -> str:
    """A table as HTML; with max_rows, the rows after it are left out and counted in a last line."""
    shown = table.rows if max_rows is None else table.rows[:max_rows]

    def row(cells: list[str], tag: str) -> str:
        tds = []
        for j, cell in enumerate(cells):
            a = table.align[j] if j < len(table.align) else "left"
            style = "" if a == "left" else f' style="text-align:{a}"'
            tds.append(f"<{tag}{style}>{inline(cell)}</{tag}>")
        return "<tr>" + "".join(tds) + "</tr>"

    parts = ["<table>"]
    if caption:
        parts.append(f"<caption>{inline(caption)}</caption>")
    parts.append("<thead>" + row(table.header, "th") + "</thead><tbody>")
    parts.extend(row(r, "td") for r in shown)
    if len(shown) < len(table.rows):
        parts.append(f'<tr><td colspan="{len(table.header)}" class="more">… {len(table.rows) - len(shown)} more '
                     "rows</td></tr>")
    parts.append("</tbody></table>")
    return "".join(parts)


def title_and_lead(markdown: str) -> tuple[str, str]:
    """The first `# ` heading and the first paragraph after it (its lines joined)."""
    title, lead, lines = "", [], markdown.splitlines()
    i = 0
    while i < len(lines) and not lines[i].startswith("# "):
        i += 1
    if i < len(lines):
        title = lines[i][2:].strip()
        i += 1
    while i < len(lines) and not lines[i].strip():
        i += 1
    while i < len(lines) and lines[i].strip() and not lines[i].lstrip().startswith(("#", "|", "!")):
        lead.append(lines[i].strip())
        i += 1
    return title, " ".join(lead)
