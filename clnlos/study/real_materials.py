"""The real-materials section of the study report (``results["real_materials"]``).

The section the study's real captures make is built by the lead's module of issue 47; this
module is the report's reader of it: :func:`section_html` renders whatever the section holds
(its ``rows`` as a table, its ``summary`` as a paragraph), so the report works before and
after that module lands."""

from __future__ import annotations

import html


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return html.escape(str(v))


def section_html(section: dict, out_dir) -> str:
    """The report's section of the real materials: ``section["title"]`` (default "Real
    materials"), ``section["summary"]`` (a paragraph) and ``section["rows"]`` (a list of
    dicts, one table row each, the keys of the first as the header). ``out_dir``: the
    report's folder (for figures written beside it)."""
    title = section.get("title", "Real materials")
    out = [f"<details><summary>{html.escape(title)}</summary>"]
    if section.get("summary"):
        out.append(f"<p>{html.escape(str(section['summary']))}</p>")
    rows = section.get("rows") or []
    if rows:
        keys = list(rows[0])
        head = "".join(f"<th>{html.escape(str(k))}</th>" for k in keys)
        body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(k, ''))}</td>" for k in keys)
                       + "</tr>" for r in rows)
        out.append(f"<div class='tab'><table><tr>{head}</tr>{body}</table></div>")
    out.append("</details>")
    return "\n".join(out)
