"""One report as an HTML page that opens from a file path: an HDR image viewer on float data, plots,
tables, verdicts and provenance.

The page is `index.html` with its assets beside it, and needs neither network nor server:
- `viewer_images.js` holds every image as little-endian float32 linear RGB (row-major, H x W x 3), its bytes
  shuffled into four planes (byte k of every float, then byte k + 1: the shuffle filter of HDF5 and Blosc),
  deflated (zlib) and base64-encoded, assigned to `window.VIEWER_IMAGES` and loaded by a script tag (browsers
  refuse `fetch()` of file:// URLs); `viewer.js` inflates it with the browser's DecompressionStream into
  Float32Arrays, so exposure, the display transform and the pixel readout work on the linear values
  themselves. A rendered 600 x 600 image takes about 3.5 MB (16 bytes a pixel without the shuffle and deflate).
- the signed difference and the relative error of a compared pair are computed in the page, in float32 like
  NumPy's, from the two images;
- plots are Plotly figures; `plotly.min.js` from the `plotly` wheel is written beside the page.
"""
from __future__ import annotations

import base64
import html
import json
import math
import shutil
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .markdown import Table, inline, table_from_rows, table_html, tables as markdown_tables

ASSETS = Path(__file__).parent / "assets"
RELATIVE_EPSILON = 0.01
"""Relative error is (a - b) / (|b| + 0.01) per channel, the regularised form of relative MSE (Rousselle,
Knaus and Zwicker 2011), so that black reference pixels do not divide by zero."""


@dataclass
class Series:
    """One curve: its points, and per point an optional line shown on hover besides x and y."""
    name: str
    x: Sequence[float | str]
    y: Sequence[float]
    hover: Sequence[str] | None = None
    fitted: bool = False  # a fitted model rather than measurements: a dashed line without markers
    bars: bool = False  # bars rather than a line


@dataclass
class Plot:
    title: str
    x_label: str
    y_label: str
    series: list[Series]
    log_x: bool = False
    log_y: bool = False


@dataclass
class BlockTest:
    """Per-block p-values of a test over image blocks: shape (rows, cols) or (rows, cols, channels); block
    (r, c) covers the image's rows r H / rows .. (r + 1) H / rows and likewise columns. A block is rejected
    where any channel's p-value is below `threshold` (the per-test level after any correction)."""
    p_values: np.ndarray
    threshold: float
    label: str = "block test"


def write_viewer(folder: str | Path, title: str, images: Mapping[str, np.ndarray], *,
                 compare: tuple[str, str] | None = None, block_test: BlockTest | None = None,
                 plots: Sequence[Plot] = (), tables: Sequence[tuple[str, str | Sequence[Sequence[str]]]] = (),
                 verdicts: Sequence[str] = (), provenance: Mapping[str, str] | None = None,
                 intro: str = "") -> Path:
    """Writes `folder/index.html` and its assets; returns the page's path.

    images: name -> (H, W, 3) linear RGB, all of one size, shown in this order (keys 1..9 reach the
    first nine views, the arrow keys all).
    compare: (test, reference) names: adds their signed difference test - reference and relative error.
    tables: (caption, rows of cells whose first row is the header), or (heading, Markdown text): every pipe
    table in the text under its section's heading, after the paragraph above it.
    verdicts, intro: lines of Markdown (`code`, **bold**, [links](...)); provenance: name -> value."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names = list(images)
    arrays = [_linear_rgb(name, images[name]) for name in names]
    if len({a.shape for a in arrays}) > 1:
        raise ValueError("images differ in size: " + ", ".join(f"{n} {a.shape}" for n, a in zip(names, arrays)))
    if compare is not None and any(n not in images for n in compare):
        raise ValueError(f"compare names {compare} are not all among the images {names}")

    for asset in ("viewer.js", "viewer.css"):
        shutil.copyfile(ASSETS / asset, folder / asset)
    head = ['<link rel="stylesheet" href="viewer.css">']
    if plots:
        _write_if_changed(folder / "plotly.min.js", _plotly_js())
        head.append('<script src="plotly.min.js"></script>')
    else:
        (folder / "plotly.min.js").unlink(missing_ok=True)

    body = [f"<header><h1>{html.escape(title)}</h1>"]
    if intro:
        body.append(f'<p class="intro">{inline(intro)}</p>')
    body.append("</header>")
    if verdicts:
        body.append('<section id="verdicts"><h2>Verdicts</h2><ul>'
                    + "".join(f"<li>{inline(v)}</li>" for v in verdicts) + "</ul></section>")
    tail = []
    if names:
        _write_images(folder / "viewer_images.js", names, arrays)
        body.append(_VIEWER_HTML)
        spec = {"width": arrays[0].shape[1], "height": arrays[0].shape[0], "names": names,
                "compare": [names.index(n) for n in compare] if compare else None,
                "epsilon": RELATIVE_EPSILON, "blocks": _block_spec(block_test)}
        tail += [f'<script type="application/json" id="viewer-spec">{_json_for_html(spec)}</script>',
                 '<script src="viewer_images.js"></script>']
    else:
        (folder / "viewer_images.js").unlink(missing_ok=True)
    if plots:
        body.append('<section id="plots"><h2>Plots</h2>'
                    + "".join(_plot_html(p, i) for i, p in enumerate(plots)) + "</section>")
    if tables:
        body.append('<section id="tables"><h2>Tables</h2>'
                    + "".join(_tables_html(caption, content) for caption, content in tables) + "</section>")
    if provenance:
        rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{inline(str(v))}</td></tr>" for k, v in provenance.items())
        body.append(f'<section id="provenance"><h2>Machine and versions</h2><table>{rows}</table></section>')
    tail.append('<script src="viewer.js"></script>')

    page = folder / "index.html"
    page.write_text("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                    f"<title>{html.escape(title)}</title>"
                    '<meta name="viewport" content="width=device-width, initial-scale=1">'
                    + "".join(head) + "</head>\n<body>\n" + "\n".join(body + tail) + "\n</body></html>\n",
                    encoding="utf-8")
    return page


def _linear_rgb(name: str, image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 1:
        raise ValueError(f"image {name!r} has shape {image.shape}; the viewer shows (H, W, 3) linear RGB")
    return np.ascontiguousarray(image, dtype="<f4")


def _write_images(path: Path, names: list[str], arrays: list[np.ndarray]) -> None:
    with path.open("w", encoding="ascii") as f:
        f.write("// Linear RGB, little-endian float32, row-major (H, W, 3): byte-shuffled, deflated, base64; "
                "decoded by viewer.js.\n")
        f.write("window.VIEWER_IMAGES = [\n")
        for name, a in zip(names, arrays):
            planes = np.frombuffer(a.tobytes(), np.uint8).reshape(-1, 4).T.tobytes()
            f.write(f'{{"name": {json.dumps(name)}, "width": {a.shape[1]}, "height": {a.shape[0]}, "data": "')
            f.write(base64.b64encode(zlib.compress(planes, 6)).decode("ascii"))
            f.write('"},\n')
        f.write("];\n")


def _block_spec(test: BlockTest | None) -> dict | None:
    if test is None:
        return None
    p = np.asarray(test.p_values, dtype=np.float64)
    if p.ndim == 2:
        p = p[..., None]
    if p.ndim != 3 or 0 in p.shape:
        raise ValueError(f"block p-values have shape {np.shape(test.p_values)}; expected (rows, cols[, channels])")
    return {"rows": p.shape[0], "cols": p.shape[1], "channels": p.shape[2], "threshold": float(test.threshold),
            "label": test.label, "p": [float(v) if math.isfinite(v) else None for v in p.ravel()]}


def _json_for_html(value) -> str:
    return json.dumps(value, separators=(",", ":")).replace("</", "<\\/")


def _plotly_js() -> str:
    from plotly.offline import get_plotlyjs
    return get_plotlyjs()


def _write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def _plot_html(plot: Plot, index: int) -> str:
    import plotly.graph_objects as go
    import plotly.io as pio

    fig = go.Figure()
    for s in plot.series:
        template = (f"{html.escape(s.name)}<br>{html.escape(plot.x_label)}: %{{x}}"
                    f"<br>{html.escape(plot.y_label)}: %{{y:.4g}}")
        if s.hover is not None:
            template += "<br>%{text}"
        common = {"x": list(s.x), "y": list(s.y), "name": s.name, "hovertemplate": template + "<extra></extra>",
                  "text": list(s.hover) if s.hover is not None else None}
        if s.bars:
            fig.add_trace(go.Bar(**common))
        else:
            fig.add_trace(go.Scatter(**common, mode="lines" if s.fitted else "lines+markers",
                                     line={"dash": "dash"} if s.fitted else None))
    fig.update_layout(title=plot.title, template="plotly_white", height=440, hovermode="closest",
                      margin={"l": 70, "r": 20, "t": 50, "b": 60}, legend={"font": {"size": 11}})
    fig.update_xaxes(title=plot.x_label, type="log" if plot.log_x else None, showgrid=True)
    fig.update_yaxes(title=plot.y_label, type="log" if plot.log_y else None, showgrid=True)
    return '<div class="plot">' + pio.to_html(fig, include_plotlyjs=False, full_html=False, div_id=f"plot-{index}",
                                              config={"displaylogo": False, "responsive": True}) + "</div>"


def _tables_html(caption: str, content: str | Sequence[Sequence[str]]) -> str:
    """Rows: one table with the caption. Markdown: the caption as a heading, then each of its pipe tables
    captioned by its section's heading and preceded by the paragraph above it."""
    if not isinstance(content, str):
        return table_html(table_from_rows([list(r) for r in content]), caption)
    found: list[Table] = markdown_tables(content)
    if not found:
        raise ValueError(f"table {caption!r}: the Markdown holds no pipe table")
    parts = [f"<h3>{inline(caption)}</h3>"] if caption else []
    shown = caption
    for t in found:
        if t.heading and t.heading != shown:
            parts.append(f"<h3>{inline(t.heading)}</h3>")
            shown = t.heading
        if t.note:
            parts.append(f'<p class="note">{inline(t.note)}</p>')
        parts.append(table_html(t))
    return "".join(parts)


_VIEWER_HTML = """<section id="viewer-section"><h2>Images</h2>
<div class="toolbar">
  <span id="view-buttons"></span>
  <span class="group"><label for="exposure">exposure</label>
    <input type="range" id="exposure" min="-20" max="20" step="0.1" value="0">
    <output id="exposure-value"></output></span>
  <span class="group"><label for="transform">display</label>
    <select id="transform">
      <option value="srgb">sRGB</option>
      <option value="signed" title="false colour of the mean of R, G, B: blue negative, red positive">false colour &plusmn;</option>
      <option value="magnitude" title="false colour of the mean of |R|, |G|, |B|">false colour |&middot;|</option>
    </select></span>
  <span class="group"><button id="zoom-in" title="zoom in (z)">+</button><button id="zoom-out" title="zoom out (x)">&minus;</button>
    <button id="zoom-fit" title="fit (f)">fit</button><button id="zoom-one" title="one image pixel per screen pixel">1:1</button>
    <output id="zoom-value"></output></span>
  <span class="group" id="outline-group"><label><input type="checkbox" id="outline" checked> outline rejected blocks (b)</label></span>
</div>
<div class="viewer"><canvas id="canvas" tabindex="0"></canvas><aside id="readout"></aside></div>
<div id="legend"><canvas id="legend-bar" width="256" height="12"></canvas><span id="legend-text"></span></div>
<p class="keys">Keys: <kbd>1</kbd>..<kbd>9</kbd> or <kbd>&larr;</kbd> <kbd>&rarr;</kbd> switch image;
<kbd>z</kbd> / <kbd>x</kbd> zoom in / out at the cursor (or the mouse wheel), <kbd>f</kbd> fit; drag to pan;
<kbd>+</kbd> / <kbd>-</kbd> exposure by half a stop, <kbd>0</kbd> its default; <kbd>t</kbd> display transform;
<kbd>b</kbd> block outlines. The readout shows each image's linear RGB at the pixel under the cursor.</p>
</section>"""
