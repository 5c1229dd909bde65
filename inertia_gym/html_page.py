"""A report's markdown as one self-contained HTML page: its plots inlined, no other file needed.

The reports' markdown uses a small subset (headings, paragraphs, bullet lists, pipe tables,
**bold**, `code`, fenced code and image lines), which this renders without a markdown package,
so the page needs nothing beyond the core install. Images given as ![name](file.png) are read
from the report's folder and embedded as base64 data; a missing one is left as its name.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

STYLE = ("body{font-family:system-ui,sans-serif;max-width:60rem;margin:2rem auto;padding:0 1rem;"
         "line-height:1.45;color:#222}table{border-collapse:collapse;margin:1rem 0}"
         "td,th{border:1px solid #ccc;padding:.25rem .5rem;text-align:left}th{background:#f3f3f3}"
         "img{max-width:100%}code,pre{background:#f6f6f6}pre{padding:.5rem;overflow-x:auto}")


def _inline(text: str) -> str:
    """Escaped text with **bold** and `code` marked up."""
    out = html.escape(text, quote=False)
    out = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", out)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", out)


def _image(name: str, path: str, folder: Path) -> str:
    """An <img> with the file's bytes inlined, or the name where the file is not there."""
    file = folder / path
    if not file.is_file():
        return f"<p>{html.escape(name)} (not written)</p>"
    data = base64.b64encode(file.read_bytes()).decode("ascii")
    return f'<p><img alt="{html.escape(name)}" src="data:image/png;base64,{data}"></p>'


def _table(rows: list[str]) -> str:
    """A pipe table (header, separator, body rows) as <table>."""
    cells = [[c.strip() for c in row.strip().strip("|").split("|")] for row in rows]
    head, body = cells[0], cells[2:]
    out = ["<table><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>" for row in body]
    return "\n".join(out) + "</table>"


def render(markdown: str, folder: Path, title: str) -> str:
    """The HTML page of `markdown` (a report's summary), its images read from `folder`."""
    lines, out, i = markdown.splitlines(), [], 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), len(lines))
            out.append("<pre>" + html.escape("\n".join(lines[i + 1:end])) + "</pre>")
            i = end + 1
            continue
        heading = re.match(r"(#{1,6}) (.*)", line)
        image = re.fullmatch(r"!\[(.*?)\]\((.*?)\)", line.strip())
        if heading:
            level = len(heading.group(1))
            out.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
        elif image:
            out.append(_image(image.group(1), image.group(2), folder))
        elif line.startswith("|"):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            out.append(_table(lines[i:j]))
            i = j
            continue
        elif line.startswith("- "):
            j = i
            while j < len(lines) and lines[j].startswith("- "):
                j += 1
            out.append("<ul>" + "".join(f"<li>{_inline(item[2:])}</li>" for item in lines[i:j]) + "</ul>")
            i = j
            continue
        elif line.strip():
            j = i
            while j < len(lines) and lines[j].strip() and not re.match(r"#|\||- |!\[|```", lines[j]):
                j += 1
            out.append("<p>" + _inline(" ".join(lines[i:j])) + "</p>")
            i = j
            continue
        i += 1
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head>\n<body>\n" + "\n".join(out) + "\n</body></html>\n")
