"""One renderer for the suite's report: a list of sections written as Markdown and as HTML.

A section builder (``report_paper``, ``report_own``, ``report_runs``, ``report_controls``) turns
results into text and Markdown tables and knows nothing of either output format; a plot is drawn
apart (``report_plots``) and enters a section as an ``Image``. ``write_document`` writes
``report.md`` (plots beside it as PNG) and ``report.html`` (the same, plots inline), each whole
(``gpl_dist.atomic.write_atomic``).
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass
from pathlib import Path

from gpl_dist.atomic import write_atomic


@dataclass(frozen=True)
class Text:
    """A paragraph; ``html``: its text in the HTML page where it differs (e.g. without Markdown's backticks)."""

    md: str
    html: str | None = None

    def markdown(self) -> str:
        return self.md

    def to_html(self) -> str:
        return f"<p>{html.escape(self.md if self.html is None else self.html)}</p>"


@dataclass(frozen=True)
class Table:
    """A Markdown table, its caption lines (those not starting with '|') above it."""

    md: str

    def markdown(self) -> str:
        return self.md

    def to_html(self) -> str:
        return md_table_html(self.md)


@dataclass(frozen=True)
class Bullets:
    """A paragraph and a list under it (backticks dropped in the HTML page)."""

    intro: str
    items: tuple[str, ...]

    def markdown(self) -> str:
        return self.intro + "\n\n" + "\n".join(f"- {item}" for item in self.items)

    def to_html(self) -> str:
        return (f"<p>{html.escape(self.intro.replace('`', ''))}</p><ul>"
                + "".join(f"<li>{html.escape(item.replace('`', ''))}</li>" for item in self.items) + "</ul>")


@dataclass(frozen=True)
class Image:
    """A PNG already drawn beside the report: linked from the Markdown, inline in the HTML page."""

    path: Path
    alt: str

    def markdown(self) -> str:
        return f"![{self.alt}]({self.path.name})"

    def to_html(self) -> str:
        data = base64.b64encode(self.path.read_bytes()).decode()
        return f'<img alt="{html.escape(self.alt)}" src="data:image/png;base64,{data}">'


Block = Text | Table | Bullets | Image


@dataclass(frozen=True)
class Section:
    """A titled part of the report; ``html_title``: a shorter title for the HTML page, where one is given."""

    title: str
    blocks: tuple[Block, ...] = ()
    html_title: str | None = None


@dataclass(frozen=True)
class Document:
    """A whole report: its title, the paragraphs before any section, and its sections in order."""

    title: str
    page_title: str
    """The HTML page's ``<title>``."""
    intro: tuple[Block, ...]
    sections: tuple[Section, ...]


_STYLE = ("<style>body{font-family:sans-serif;max-width:60em;margin:auto}td,th{border:1px solid #ccc;"
          "padding:2px 6px}table{border-collapse:collapse}</style>")


def render_markdown(doc: Document) -> str:
    """The document as Markdown: parts separated by a blank line."""
    parts = [b.markdown() for b in doc.intro]
    for section in doc.sections:
        parts += [f"## {section.title}", *(b.markdown() for b in section.blocks)]
    return f"# {doc.title}\n\n" + "\n\n".join(parts) + "\n"


def render_html(doc: Document) -> str:
    """The document as one HTML page, every text escaped and every plot inline."""
    parts = [b.to_html() for b in doc.intro]
    for section in doc.sections:
        title = section.title if section.html_title is None else section.html_title
        parts += [f"<h2>{html.escape(title)}</h2>", *(b.to_html() for b in section.blocks)]
    return (f"<!doctype html><meta charset='utf-8'><title>{html.escape(doc.page_title, quote=False)}</title>{_STYLE}"
            f"<h1>{html.escape(doc.title, quote=False)}</h1>" + "\n".join(parts) + "\n")


def write_document(doc: Document, out: Path) -> tuple[Path, Path]:
    """Write ``out/report.md`` and ``out/report.html``, each whole."""
    md_path, html_path = out / "report.md", out / "report.html"
    write_atomic(md_path, render_markdown(doc))
    write_atomic(html_path, render_html(doc))
    return md_path, html_path


def md_table_html(md: str) -> str:
    """The Markdown table in ``md`` (its other lines kept as paragraphs) as HTML, escaped; only the
    paragraphs where ``md`` holds no table."""
    lines = md.splitlines()
    caption = [ln for ln in lines if ln and not ln.startswith("|")]
    rows = [ln.strip("|").split("|") for ln in lines if ln.startswith("|") and not ln.startswith("|---")]
    tags = ["th"] + ["td"] * len(rows)  # the first row is the header
    body = "".join("<tr>" + "".join(f"<{tag}>{html.escape(c.strip().strip('`*'))}</{tag}>" for c in row) + "</tr>"
                   for tag, row in zip(tags, rows))
    return "".join(f"<p>{html.escape(c.replace('**', ''))}</p>" for c in caption) + (f"<table>{body}</table>" if rows else "")
