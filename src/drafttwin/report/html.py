"""HTML building blocks of the report: escaping, tables, figures, and the page shell.

Everything inserted as text goes through :func:`esc`; only :class:`Raw` fragments built by
these helpers are inserted unescaped. The page is self-contained: inline CSS, figures as
base64 PNG data URIs, one small inline script and no external resource.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from drafttwin.report.fmt import DASH, is_num, num


@dataclass(frozen=True)
class Raw:
    """An HTML fragment that is already safe (built by this module's helpers)."""

    html: str

    def __str__(self) -> str:
        return self.html


Content = str | Raw


def esc(text: Any) -> str:
    """Escape any value for HTML text and attribute values."""
    return html.escape(str(text), quote=True)


def render(content: Content) -> str:
    """Raw fragments as they are, anything else escaped."""
    return content.html if isinstance(content, Raw) else esc(content)


def join(parts: Iterable[Content], sep: str = "") -> Raw:
    """Concatenate fragments (text parts escaped)."""
    return Raw(sep.join(render(p) for p in parts))


def tag(name: str, content: Content = "", **attrs: Any) -> Raw:
    """``<name attrs>content</name>``; attribute ``cls`` becomes ``class``; None is dropped."""
    parts = [name]
    for key, value in attrs.items():
        if value is None or value is False:
            continue
        key = "class" if key == "cls" else key.replace("_", "-")
        parts.append(key if value is True else f'{key}="{esc(value)}"')
    return Raw(f"<{' '.join(parts)}>{render(content)}</{name}>")


@dataclass(frozen=True)
class Cell:
    """A table cell: content plus optional class, spans and tooltip."""

    content: Content
    cls: str | None = None
    colspan: int | None = None
    rowspan: int | None = None
    title: str | None = None
    header: bool = False

    def html(self) -> str:
        return tag(
            "th" if self.header else "td",
            self.content,
            cls=self.cls,
            colspan=self.colspan,
            rowspan=self.rowspan,
            title=self.title,
        ).html


CellLike = Cell | Content
Row = Sequence[CellLike]
"""A table row: its cells."""
BodyRow = Row | tuple[str, Row]
"""A body row, or ``(row_class, cells)``."""


def _cell(c: CellLike, header: bool) -> str:
    if isinstance(c, Cell):
        return c.html()
    return Cell(c, header=header).html()


def table(
    head: Sequence[Row],
    body: Sequence[BodyRow],
    *,
    id: str | None = None,
    cls: str | None = None,
    caption: Content | None = None,
) -> Raw:
    """A table; a body row given as ``(row_class, cells)`` gets that class."""
    thead = "".join(f"<tr>{''.join(_cell(c, True) for c in row)}</tr>" for row in head)
    rows = []
    for row in body:
        row_cls, cells = row if isinstance(row, tuple) else (None, row)
        attr = f' class="{esc(row_cls)}"' if row_cls else ""
        rows.append(f"<tr{attr}>{''.join(_cell(c, False) for c in cells)}</tr>")
    cap = f"<caption>{render(caption)}</caption>" if caption is not None else ""
    inner = f"{cap}<thead>{thead}</thead><tbody>{''.join(rows)}</tbody>"
    return tag("div", Raw(tag("table", Raw(inner), id=id, cls=cls).html), cls="scroll")


def kv_table(items: Mapping[str, Any], *, id: str | None = None) -> Raw:
    """A two-column key / value table; nested dicts are flattened with ' · '."""
    body = [
        [Cell(k, header=True), v if isinstance(v, Raw) else value_text(v)]
        for k, v in flatten(items).items()
    ]
    return table([], body, id=id, cls="kv")


def flatten(items: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings as one level, keys joined with ' · '."""
    out: dict[str, Any] = {}
    for key, value in items.items():
        name = f"{prefix} · {key}" if prefix else str(key)
        if isinstance(value, Mapping) and value:
            out.update(flatten(value, name))
        else:
            out[name] = value
    return out


def value_text(v: Any) -> str:
    """A setting's value as short text."""
    if v is None:
        return DASH
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return num(v, 4).rstrip("0").rstrip(".") if is_num(v) and abs(v) >= 1e-3 else f"{v:g}"
    if isinstance(v, list | tuple):
        return ", ".join(value_text(x) for x in v) if v else DASH
    if isinstance(v, Mapping):
        return ", ".join(f"{k}: {value_text(x)}" for k, x in v.items()) if v else DASH
    return str(v)


def bullets(items: Iterable[Content], cls: str | None = None) -> Raw:
    """An unordered list."""
    return tag("ul", join(tag("li", i) for i in items), cls=cls)


def para(content: Content, cls: str | None = None) -> Raw:
    return tag("p", content, cls=cls)


def figure(png: bytes, fig_id: str, caption: Content, alt: str) -> Raw:
    """A figure with the PNG embedded as a base64 data URI."""
    data = base64.b64encode(png).decode("ascii")
    img = f'<img src="data:image/png;base64,{data}" alt="{esc(alt)}">'
    return tag("figure", Raw(img + tag("figcaption", caption).html), id=fig_id)


def section(sec_id: str, title: str, *parts: Content) -> Raw:
    """A numbered report section."""
    return tag("section", join([tag("h2", title), *parts]), id=sec_id)


CSS = """
:root { --ink: #1d2430; --muted: #5b6472; --line: #d9dee5; --paper: #f4f1ea;
        --best: #dff3e4; --warn: #fff4d6; --bad: #fde2e1; --accent: #1f5f8b; }
* { box-sizing: border-box; }
body { font: 15px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: var(--ink);
       margin: 0; background: #fafbfc; }
main { max-width: 1180px; margin: 0 auto; padding: 24px 28px 60px; background: #fff; }
h1 { font-size: 22px; margin: 0 0 2px; }
h2 { font-size: 20px; border-bottom: 2px solid var(--accent); padding-bottom: 4px; margin-top: 40px; }
h3 { font-size: 16px; margin: 22px 0 6px; }
p, li { max-width: 92ch; }
.sub { color: var(--muted); margin: 0 0 6px; font-size: 13px; }
.banner { background: var(--warn); border-left: 5px solid #d9a400; padding: 8px 14px;
          margin: 14px 0; }
.banner details { margin-top: 4px; }
.banner summary { cursor: pointer; color: var(--accent); }
nav.toc { position: sticky; top: 0; z-index: 5; display: flex; gap: 14px; align-items: baseline;
          background: #fff; border-bottom: 1px solid var(--line); padding: 6px 0; font-size: 13px; }
nav.toc ol { display: flex; flex-wrap: wrap; gap: 2px 16px; list-style: none; margin: 0;
             padding: 0; }
nav a { color: var(--accent); text-decoration: none; }
nav a:hover { text-decoration: underline; }
[id] { scroll-margin-top: 44px; }
section.glance h2 { font-size: 18px; margin: 10px 0 4px; }
section.glance figure { margin: 4px 0 6px; }
table.verdicts { width: 100%; }
table.verdicts td { white-space: normal; text-align: left; vertical-align: top; }
table.verdicts td.q { font-weight: 600; min-width: 230px; }
table.verdicts .pair { display: block; font-weight: 400; color: var(--muted); font-size: 12px; }
table.verdicts td.name { white-space: nowrap; }
table.verdicts td.verdict { font-weight: 700; text-align: center; white-space: nowrap; }
td.v-not-run { color: var(--muted); }
.scroll { overflow-x: auto; margin: 8px 0 14px; }
table { border-collapse: collapse; font-size: 13px; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid var(--line); padding: 3px 7px; text-align: right; white-space: nowrap; }
th { background: #eef1f5; font-weight: 600; text-align: center; white-space: normal; }
td.name, th.name { text-align: left; }
table.kv th { text-align: left; background: #f5f7f9; font-weight: 500; }
table.kv td { text-align: left; white-space: normal; }
tr.paper td { background: var(--paper); color: #6b5f45; font-style: italic; }
tr.extra td { background: #f3f0fa; }
tr.floor td { color: var(--muted); font-style: italic; }
tr.group td { background: #e9eef4; font-weight: 600; text-align: left; }
td.best { background: var(--best); font-weight: 700; }
td.yes { background: var(--best); } td.no { background: var(--bad); }
td.v-agrees { background: var(--best); } td.v-partly { background: var(--warn); }
td.v-does-not-agree { background: var(--bad); } td.v-not-in-paper { color: var(--muted); }
td.wrap, th.wrap { white-space: normal; text-align: left; min-width: 180px; }
.bar { display: inline-block; height: 9px; background: var(--accent); vertical-align: middle; }
figure { margin: 14px 0 22px; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--line); }
figcaption { color: var(--muted); font-size: 13px; max-width: 100ch; }
caption { caption-side: bottom; text-align: left; color: var(--muted); font-size: 13px; padding-top: 4px; }
.note { color: var(--muted); font-size: 13px; }
.paperbox { background: var(--paper); padding: 8px 12px; border-left: 4px solid #b8a67a; }
footer { margin-top: 40px; color: var(--muted); font-size: 12px; }
"""

SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; });
  document.body.dataset.imagesTotal = String(imgs.length);
  document.body.dataset.imagesLoaded = String(ok.length);
});
"""


def page(title: str, body: Content) -> str:
    """The whole self-contained HTML document."""
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{esc(title)}</title>\n<style>{CSS}</style>\n</head>\n"
        f"<body>\n<main>\n{render(body)}\n</main>\n<script>{SCRIPT}</script>\n</body>\n</html>\n"
    )
