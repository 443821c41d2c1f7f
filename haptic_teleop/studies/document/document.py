"""The report as sections of paragraphs, tables and figures, written twice from the same content:

- `write_html`: one self-contained file. Figures are `<img src="data:image/png;base64,...">`, the
  style sheet and the one small script are inline; the only links are to the page's own sections
  (`href="#..."`). The script marks each image once the browser has drawn it
  (`data-drawn="yes"` when `complete` and `naturalWidth > 0`, else "no") and writes the count to
  `<p id="plot-check" data-drawn="N" data-total="M">`: the browser test reads these back.
- `write_markdown`: the same text and tables in Markdown, each figure a PNG file in `figures/`
  beside it, linked by a relative path.
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass, field
from pathlib import Path

HTML_FILE = "report.html"
MD_FILE = "report.md"
FIGURE_DIR = "figures"


@dataclass(frozen=True)
class Para:
    text: str


@dataclass(frozen=True)
class Table:
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str = ""


@dataclass
class Image:
    """A figure: PNG bytes and the file name it gets beside the Markdown."""

    name: str
    png: bytes
    title: str
    caption: str = ""


Block = Para | Table | Image


@dataclass
class Section:
    anchor: str
    title: str
    blocks: list[Block] = field(default_factory=list)
    subsections: list[Section] = field(default_factory=list)

    def images(self) -> list[Image]:
        own = [b for b in self.blocks if isinstance(b, Image)]
        return own + [i for s in self.subsections for i in s.images()]


@dataclass
class Document:
    title: str
    intro: list[Block]
    sections: list[Section]

    def images(self) -> list[Image]:
        return [i for s in self.sections for i in s.images()]


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"


def unique_names(doc: Document) -> None:
    """Give every figure a distinct file name (`NN-name.png`), in the document's order."""
    for n, img in enumerate(doc.images(), start=1):
        img.name = f"{n:02d}-{slug(img.name)}.png"


# ------------------------------------------------------------------------------------------------
# HTML

STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 1.5em auto;
       max-width: 1280px; padding: 0 1em; color: #222; line-height: 1.45; }
h1 { font-size: 1.7em; border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { font-size: 1.35em; margin-top: 2em; border-bottom: 1px solid #bbb; }
h3 { font-size: 1.1em; margin-top: 1.5em; }
.table { overflow-x: auto; margin: .6em 0 1.2em; }
table { border-collapse: collapse; font-size: .85em; }
th, td { border: 1px solid #ccc; padding: .25em .55em; text-align: right; vertical-align: top; }
th { background: #f0f0f0; max-width: 16em; }
td { white-space: nowrap; }
td:first-child, th:first-child { text-align: left; }
caption { caption-side: top; text-align: left; font-style: italic; padding-bottom: .3em; }
figure { margin: 1em 0 1.6em; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: .9em; color: #444; margin-top: .3em; }
code { background: #f4f4f4; padding: 0 .2em; }
nav ul { columns: 2; }
#plot-check { font-size: .8em; color: #888; }
"""

# Marks each image the browser has drawn; the browser test reads the marks from the DOM.
SCRIPT = """
window.addEventListener("load", function () {
  var imgs = document.images, drawn = 0;
  for (var i = 0; i < imgs.length; i++) {
    var ok = imgs[i].complete && imgs[i].naturalWidth > 0;
    imgs[i].setAttribute("data-drawn", ok ? "yes" : "no");
    if (ok) { drawn++; }
  }
  var p = document.getElementById("plot-check");
  p.setAttribute("data-drawn", String(drawn));
  p.setAttribute("data-total", String(imgs.length));
  p.textContent = drawn + " of " + imgs.length + " plots drawn";
});
"""

_CODE = re.compile(r"`([^`]+)`")


def _inline(text: str) -> str:
    """Escaped text with `code` spans."""
    parts = _CODE.split(text)
    return "".join(f"<code>{html.escape(p)}</code>" if i % 2 else html.escape(p) for i, p in enumerate(parts))


def _breakable(text: str) -> str:
    """A column header: long key paths and metric names may break after `.`, `_` and `+`."""
    return re.sub(r"([._+])(?=\w)", r"\1<wbr>", _inline(text)) if "`" not in text else _inline(text)


def _html_block(b: Block) -> str:
    if isinstance(b, Para):
        return f"<p>{_inline(b.text)}</p>"
    if isinstance(b, Table):
        cap = f"<caption>{_inline(b.caption)}</caption>" if b.caption else ""
        head = "".join(f"<th>{_breakable(h)}</th>" for h in b.header)
        body = "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>" for row in b.rows)
        return f'<div class="table"><table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'
    data = base64.b64encode(b.png).decode("ascii")
    cap = f"<figcaption>{_inline(b.caption)}</figcaption>" if b.caption else ""
    return f'<figure><img alt="{html.escape(b.title)}" src="data:image/png;base64,{data}">{cap}</figure>'


def _html_section(s: Section, level: int) -> str:
    parts = [f'<section id="{s.anchor}"><h{level}>{_inline(s.title)}</h{level}>']
    parts += [_html_block(b) for b in s.blocks]
    parts += [_html_section(sub, level + 1) for sub in s.subsections]
    parts.append("</section>")
    return "\n".join(parts)


def render_html(doc: Document) -> str:
    toc = "".join(f'<li><a href="#{s.anchor}">{_inline(s.title)}</a></li>' for s in doc.sections)
    body = [
        f"<h1>{_inline(doc.title)}</h1>",
        *(_html_block(b) for b in doc.intro),
        f"<nav><ul>{toc}</ul></nav>" if doc.sections else "",
        *(_html_section(s, 2) for s in doc.sections),
        '<p id="plot-check" data-drawn="" data-total="">(plots not yet checked)</p>',
    ]
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{html.escape(doc.title)}</title><style>{STYLE}</style></head>\n<body>\n"
        + "\n".join(p for p in body if p)
        + f"\n<script>{SCRIPT}</script>\n</body></html>\n"
    )


# ------------------------------------------------------------------------------------------------
# Markdown


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_block(b: Block) -> str:
    if isinstance(b, Para):
        return b.text
    if isinstance(b, Table):
        lines = [f"*{b.caption}*", ""] if b.caption else []
        lines.append("| " + " | ".join(_md_cell(h) for h in b.header) + " |")
        lines.append("|" + "|".join("---" for _ in b.header) + "|")
        lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b.rows]
        return "\n".join(lines)
    text = f"![{b.title}]({FIGURE_DIR}/{b.name})"
    return f"{text}\n\n{b.caption}" if b.caption else text


def _md_section(s: Section, level: int) -> list[str]:
    out = [f'<a id="{s.anchor}"></a>', "", f"{'#' * level} {s.title}", ""]
    for b in s.blocks:
        out += [_md_block(b), ""]
    for sub in s.subsections:
        out += _md_section(sub, level + 1)
    return out


def render_markdown(doc: Document) -> str:
    lines = [f"# {doc.title}", ""]
    for b in doc.intro:
        lines += [_md_block(b), ""]
    for s in doc.sections:
        lines.append(f"- [{s.title}](#{s.anchor})")
    lines.append("")
    for s in doc.sections:
        lines += _md_section(s, 2)
    return "\n".join(lines).rstrip() + "\n"


def _write_bytes(path: Path, data: bytes) -> None:
    """Whole or not at all: through a temporary file and a rename."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def write(doc: Document, out: Path) -> tuple[Path, Path]:
    """report.html, report.md and figures/*.png in `out` (which exists); their paths. The figures
    and the Markdown first: the HTML appears last, whole."""
    unique_names(doc)
    images = doc.images()
    if images:
        fig_dir = out / FIGURE_DIR
        fig_dir.mkdir(exist_ok=True)
        for img in images:
            _write_bytes(fig_dir / img.name, img.png)
    _write_bytes(out / MD_FILE, render_markdown(doc).encode("utf-8"))
    _write_bytes(out / HTML_FILE, render_html(doc).encode("utf-8"))
    return out / HTML_FILE, out / MD_FILE
