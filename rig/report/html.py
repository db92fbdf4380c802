"""One self-contained HTML page: inline CSS, images embedded as base64 PNG, no scripts, no links out.

The page is built from a few plain blocks (text, table, image, list) so the report builder never writes
markup itself and every string is escaped in one place.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field


@dataclass
class Table:
    headers: list[str]
    rows: list[list[str]]
    caption: str = ""


@dataclass
class Image:
    png: bytes
    caption: str
    filename: str  # the PNG written next to the HTML file


@dataclass
class ItemList:
    items: list[str]
    kind: str = "plain"  # "warning" draws the items in the warning colour
    empty_text: str = "none"


@dataclass
class Links:
    """Links to files beside the page (relative names only: the page links nowhere else)."""

    items: list[tuple[str, str]]  # (text, file name)
    empty_text: str = "none"


@dataclass
class Section:
    title: str
    blocks: list[str | Table | Image | ItemList | Links] = field(default_factory=list)
    level: int = 2


CSS = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1150px; color: #222; line-height: 1.4; }
h1 { border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
table { border-collapse: collapse; margin: .6em 0 1.2em; font-size: 90%; }
th, td { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
th { background: #eee; }
td:first-child, th:first-child { text-align: left; }
caption { caption-side: top; text-align: left; font-weight: bold; padding: .3em 0; }
figure { margin: 1em 0 2em; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 90%; color: #555; }
ul.warning li { color: #8a4b00; }
p.subtitle { color: #555; }
"""


def _table(t: Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in t.headers)
    body = "\n".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in t.rows
    )
    caption = f"<caption>{html.escape(t.caption)}</caption>" if t.caption else ""
    return f"<table>{caption}<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody></table>"


def _image(img: Image) -> str:
    data = base64.b64encode(img.png).decode("ascii")
    alt = html.escape(img.caption)
    return (
        f'<figure><img alt="{alt}" src="data:image/png;base64,{data}">'
        f"<figcaption>{alt} ({html.escape(img.filename)})</figcaption></figure>"
    )


def _list(lst: ItemList) -> str:
    if not lst.items:
        return f"<p>{html.escape(lst.empty_text)}</p>"
    items = "\n".join(f"<li>{html.escape(i)}</li>" for i in lst.items)
    return f'<ul class="{html.escape(lst.kind)}">\n{items}\n</ul>'


def _links(links: Links) -> str:
    if not links.items:
        return f"<p>{html.escape(links.empty_text)}</p>"
    for _, name in links.items:
        if "/" in name or "\\" in name or ":" in name:
            raise ValueError(f"a report links only to files beside it, not {name!r}")
    items = "\n".join(f'<li><a href="{html.escape(name)}">{html.escape(text)}</a></li>'
                      for text, name in links.items)
    return f"<ul>\n{items}\n</ul>"


def _block(block: str | Table | Image | ItemList | Links) -> str:
    if isinstance(block, Links):
        return _links(block)
    if isinstance(block, Table):
        return _table(block)
    if isinstance(block, Image):
        return _image(block)
    if isinstance(block, ItemList):
        return _list(block)
    return f"<p>{html.escape(block)}</p>"


def render_html(title: str, sections: list[Section], subtitle: str = "", *,
                banner: list[tuple[str, str]] = (), css: str = "") -> str:
    """The page; `banner`: (text, class) lines shown above everything (a certificate's marks), `css`:
    more style (the page's print layout: the project's own, never a user's text)."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        f"<style>{CSS}{css}</style></head><body>",
    ]
    if banner:
        lines = "".join(f'<p class="{html.escape(kind)}">{html.escape(line)}</p>' for line, kind in banner)
        parts.append(f'<div class="marks">{lines}</div>')
    parts.append(f"<h1>{html.escape(title)}</h1>")
    if subtitle:
        parts.append(f'<p class="subtitle">{html.escape(subtitle)}</p>')
    for section in sections:
        level = min(max(section.level, 2), 4)
        parts.append(f"<h{level}>{html.escape(section.title)}</h{level}>")
        parts.extend(_block(b) for b in section.blocks)
    parts.append("</body></html>\n")
    return "\n".join(parts)


def images_in(sections: list[Section]) -> list[Image]:
    """Every image of the page, in order: the PNG files written next to it."""
    return [b for s in sections for b in s.blocks if isinstance(b, Image)]
