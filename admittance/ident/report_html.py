"""``report.html``: the identification report as one self-contained page a browser opens.

It is rendered from the same text as ``report.md`` (one source), so the two never disagree:
the few Markdown forms the report uses (headings, bullet lists, tables, paragraphs, ``**bold**``,
```code```, and ``![caption](figure.png)``) become HTML, and every figure is embedded as a
base64 PNG inside a ``<figure>`` with its caption. No script, no external stylesheet, font or
image: the file can be mailed, archived or opened offline.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from admittance.errors import DataError

IMAGE = re.compile(r"^!\[(?P<caption>[^\]]*)\]\((?P<file>[^)\s]+)\)$")
STYLE = """
body { font-family: sans-serif; max-width: 70em; margin: 1em auto; padding: 0 1em; line-height: 1.4; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
th { background: #eee; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #444; margin-top: 0.3em; }
code { background: #f3f3f3; padding: 0 0.2em; }
"""


def write_html(markdown: str, figures_dir: Path, path: Path) -> Path:
    """``path`` = the page of ``markdown``, its images read from ``figures_dir`` and embedded."""
    title = next((line[2:].strip() for line in markdown.splitlines() if line.startswith("# ")), "Identification report")
    body = "\n".join(_blocks(markdown.splitlines(), figures_dir))
    page = (f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{html.escape(title)}</title>\n"
            f"<style>{STYLE}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n")
    try:
        path.write_text(page, encoding="utf-8")
    except OSError as exc:
        raise DataError(f"--report {path}: cannot write ({exc.strerror})") from None
    return path


def _inline(text: str) -> str:
    text = html.escape(text, quote=False)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)


def _blocks(lines: list[str], figures_dir: Path):
    """HTML blocks of the Markdown lines: consecutive list items and table rows are grouped."""
    i = 0
    while i < len(lines):
        line = lines[i].rstrip()
        if not line:
            i += 1
            continue
        if line.startswith("|"):
            j = _run_end(lines, i, lambda s: s.startswith("|"))
            yield _table(lines[i:j])
            i = j
        elif line.startswith("- "):
            j = _run_end(lines, i, lambda s: s.startswith("- "))
            yield "<ul>\n" + "\n".join(f"<li>{_inline(s[2:])}</li>" for s in lines[i:j]) + "\n</ul>"
            i = j
        elif (match := IMAGE.match(line)) is not None:
            yield _figure(match["caption"], figures_dir / match["file"])
            i += 1
        elif line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")), 6)
            yield f"<h{level}>{_inline(line[level:].strip())}</h{level}>"
            i += 1
        else:
            yield f"<p>{_inline(line)}</p>"
            i += 1


def _run_end(lines: list[str], start: int, belongs) -> int:
    end = start
    while end < len(lines) and belongs(lines[end].rstrip()):
        end += 1
    return end


def _cells(row: str) -> list[str]:
    return [c.strip() for c in row.strip().strip("|").split("|")]


def _table(rows: list[str]) -> str:
    body = [r for r in rows[1:] if not set(r.replace("|", "").strip()) <= set("-: ")]
    head = "".join(f"<th>{_inline(c)}</th>" for c in _cells(rows[0]))
    cells = ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in _cells(r)) + "</tr>" for r in body]
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(cells) + "\n</tbody>\n</table>"


def _figure(caption: str, image: Path) -> str:
    try:
        data = base64.b64encode(image.read_bytes()).decode("ascii")
    except OSError as exc:
        raise DataError(f"--report: figure {image} cannot be read ({exc.strerror})") from None
    text = _inline(caption)
    return (f"<figure>\n<img src=\"data:image/png;base64,{data}\" alt=\"{html.escape(caption)}\">\n"
            f"<figcaption>{text}</figcaption>\n</figure>")
