"""A tiny document builder that writes the same content as Markdown and as HTML.

The HTML is self-contained (inline CSS, no network) and carries a small inline
script that, once the page has loaded, records on ``<body>`` how many tables and
images it has and which images failed to load (``data-broken-images``), so a
headless browser run with ``--dump-dom`` can check the page.
"""

from __future__ import annotations

import html
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:1.5em auto;
max-width:1250px;padding:0 1em;color:#1d1d1f;line-height:1.4}
h1{font-size:1.6em;border-bottom:2px solid #ccc;padding-bottom:.2em}
h2{font-size:1.25em;margin-top:1.6em;border-bottom:1px solid #ddd}
h3{font-size:1.05em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right}
th{background:#f0f2f5}
td.l,th.l{text-align:left}
tr:nth-child(even) td{background:#fafafa}
caption{caption-side:bottom;font-size:.85em;color:#555;padding-top:.3em;text-align:left}
figure{display:inline-block;margin:.4em .8em .4em 0;vertical-align:top}
figure img{max-width:100%;border:1px solid #ddd}
figure img.pixels{height:210px;width:auto;margin-top:22px;image-rendering:pixelated}
figcaption{font-size:.85em;color:#444;text-align:center}
.row{display:flex;flex-wrap:wrap;align-items:flex-start}
.note{color:#8a4b00;font-size:.9em}
code{background:#f3f3f3;padding:0 .2em}
"""

_CHECK_SCRIPT = """
window.addEventListener('load', function () {
  var broken = [];
  for (var i = 0; i < document.images.length; i++) {
    var im = document.images[i];
    if (!(im.complete && im.naturalWidth > 0)) broken.push(im.getAttribute('src'));
  }
  var b = document.body;
  b.setAttribute('data-image-count', String(document.images.length));
  b.setAttribute('data-broken-images', broken.join(' '));
  b.setAttribute('data-table-count', String(document.querySelectorAll('table').length));
  b.setAttribute('data-checked', 'yes');
});
"""


def _md_cell(text: str) -> str:
    """Escape a Markdown table cell."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def _pair(cell) -> tuple[str, str]:
    """A cell as (markdown, html): a plain string is used for both (escaped in HTML)."""
    if isinstance(cell, tuple):
        return cell
    return str(cell), html.escape(str(cell))


class Doc:
    """Accumulates a report as Markdown and HTML side by side."""

    def __init__(self, title: str):
        self.title = title
        self.md: list[str] = [f"# {title}", ""]
        self.html: list[str] = [f"<h1>{html.escape(title)}</h1>"]

    def heading(self, text: str, *, level: int = 2) -> None:
        """Add a section heading."""
        self.md += [f"{'#' * level} {text}", ""]
        self.html.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def para(self, text, *, note: bool = False) -> None:
        """Add a paragraph; ``text`` is a string or a (markdown, html) pair."""
        md, htm = _pair(text)
        self.md += [f"*{md}*" if note else md, ""]
        self.html.append(f'<p class="note">{htm}</p>' if note else f"<p>{htm}</p>")

    def table(self, columns, rows, *, groups=None, caption: str | None = None,
              left: int = 1) -> None:
        """Add a table.

        Parameters
        ----------
        columns : sequence
            Column labels (strings or (markdown, html) pairs).
        rows : sequence of sequence
            Cells (strings or (markdown, html) pairs).
        groups : sequence of (str, int), optional
            Column groups for an upper HTML header row (label, span); in Markdown the
            group label prefixes each column label of the group.
        caption : str, optional
            Caption under the table.
        left : int
            How many leading columns are left-aligned (labels).
        """
        cols = [_pair(c) for c in columns]
        md_cols = [c[0] for c in cols]
        if groups:
            labels = [g for g, span in groups for _ in range(span)]
            md_cols = [f"{g} {c}".strip() for g, c in zip(labels, md_cols)]
        self.md.append("| " + " | ".join(_md_cell(c) for c in md_cols) + " |")
        self.md.append("|" + "|".join(":--" if i < left else "--:" for i in range(len(cols))) + "|")
        for row in rows:
            self.md.append("| " + " | ".join(_md_cell(_pair(c)[0]) for c in row) + " |")
        if caption:
            self.md += ["", f"*{caption}*"]
        self.md.append("")
        self.html.append(self._html_table(cols, rows, groups, caption, left))

    @staticmethod
    def _html_table(cols, rows, groups, caption, left) -> str:
        """The HTML of a table (see :meth:`table`)."""
        cls = lambda i: ' class="l"' if i < left else ""  # noqa: E731
        out = ["<table>"]
        if caption:
            out.append(f"<caption>{html.escape(caption)}</caption>")
        if groups:
            out.append("<tr>" + "".join(
                f'<th colspan="{span}">{html.escape(g)}</th>' for g, span in groups) + "</tr>")
        out.append("<tr>" + "".join(f"<th{cls(i)}>{c[1]}</th>" for i, c in enumerate(cols)) + "</tr>")
        for row in rows:
            out.append("<tr>" + "".join(
                f"<td{cls(i)}>{_pair(c)[1]}</td>" for i, c in enumerate(row)) + "</tr>")
        out.append("</table>")
        return "\n".join(out)

    def figures(self, items) -> None:
        """Add images side by side.

        Parameters
        ----------
        items : sequence of tuple
            ``(relative src, caption)`` or ``(relative src, caption, css class)``; the
            class ``pixels`` shows a raw image at panel height with sharp pixels.
        """
        figs = []
        for src, caption, *cls in items:
            self.md.append(f"![{_md_cell(caption)}]({src})")
            attr = f' class="{html.escape(cls[0])}"' if cls else ""
            figs.append(f'<figure><img src="{html.escape(src)}" alt="{html.escape(caption)}"{attr}>'
                        f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        self.md.append("")
        self.html.append(f'<div class="row">{"".join(figs)}</div>')

    def links(self, items) -> None:
        """Add a bullet list of links: ``items`` is a sequence of (text, href)."""
        self.md += [f"- [{text}]({href})" for text, href in items] + [""]
        self.html.append("<ul>" + "".join(
            f'<li><a href="{html.escape(href)}">{html.escape(text)}</a></li>'
            for text, href in items) + "</ul>")

    def render_md(self) -> str:
        """The Markdown document."""
        return "\n".join(self.md).rstrip() + "\n"

    def render_html(self) -> str:
        """The self-contained HTML document."""
        return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                f"<title>{html.escape(self.title)}</title><style>{_CSS}</style>"
                f"<script>{_CHECK_SCRIPT}</script></head>\n<body>\n"
                + "\n".join(self.html) + "\n</body></html>\n")


def link_cell(text: str, href: str) -> tuple[str, str]:
    """A table cell holding a link, as a (markdown, html) pair."""
    return f"[{text}]({href})", f'<a href="{html.escape(href)}">{html.escape(text)}</a>'


@contextmanager
def staged(out_dir, names):
    """Write a report all at once: yield a temporary folder beside ``out_dir``'s files to write
    ``names`` (files or folders) into; on success move each into ``out_dir``, replacing an older
    one, folders first so the documents never point at missing figures. On failure (Ctrl-C
    included) nothing is moved and ``out_dir`` is as it was; a folder it creates is removed.

    Parameters
    ----------
    out_dir : path-like
        The folder the report belongs in (created if missing).
    names : sequence of str
        What the report writes, in the order to move it into place.
    """
    out_dir = Path(out_dir)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir, prefix=".report-"))
    try:
        yield tmp
        for name in names:
            if (tmp / name).is_dir() and (out_dir / name).is_dir():
                os.replace(out_dir / name, tmp / f"{name}.old")   # removed with tmp below
            if (tmp / name).exists():
                os.replace(tmp / name, out_dir / name)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    shutil.rmtree(tmp, ignore_errors=True)
