"""The two renderings of a ``document.Report``: Markdown (figures linked as PNG or SVG files written beside
it) and one self-contained HTML file (jinja2 template ``templates/report.html.j2``, figures embedded as
base64 PNG or inline SVG, inline CSS, no script and no external resource)."""

from __future__ import annotations

import base64
import re
from pathlib import Path

import jinja2

from dualid.report.document import Report, Table

_ENV = jinja2.Environment(loader=jinja2.PackageLoader("dualid.report", "templates"),
                          autoescape=jinja2.select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True,
                          undefined=jinja2.StrictUndefined)
_ENV.filters["b64"] = lambda data: base64.b64encode(data).decode("ascii")
_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)(e[-+]?\d+)?( ± \S+)?$")
_ENV.tests["number"] = lambda cell: bool(_NUMBER.match(cell))  # right-aligned cells


def _cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def table_markdown(t: Table) -> list[str]:
    lines = [f"**{t.title}**", ""] if t.title else []
    lines += ["| " + " | ".join(_cell(h) for h in t.header) + " |", "|" + "|".join(["---"] * len(t.header)) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in t.rows]
    return lines + (["", t.note] if t.note else [])


def to_markdown(report: Report) -> str:
    lines = [f"# {report.title}", ""]
    if report.banner:
        lines += [f"**{report.banner}**", ""]
    for s in report.sections:
        lines += [f"## {s.title}", ""]
        for b in s.blocks:
            if b.kind == "text":
                lines += [b.text]
            elif b.kind == "bullets":
                lines += [f"- {item}" for item in b.items]
            elif b.kind == "pre":
                lines += ["```", b.text, "```"]
            elif b.kind == "table":
                lines += table_markdown(b)
            else:  # image
                lines += [f"![{b.name}]({b.name})", "", f"*{b.caption}*" if b.caption else ""]
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def to_html(report: Report) -> str:
    return _ENV.get_template("report.html.j2").render(report=report)


def write_report(report: Report, out: Path, written: dict[str, Path]) -> None:
    """report.md with its figures beside it, and report.html (the same report, figures embedded), in ``out``
    (a folder the output-directory policy of ``report.outdir`` handed out); ``written`` gains their paths."""
    for image in report.images:
        (out / image.name).write_bytes(image.png or image.svg.encode())
        written[image.name] = out / image.name
    (out / "report.md").write_text(to_markdown(report))
    (out / "report.html").write_text(to_html(report))
    written["report.md"], written["report.html"] = out / "report.md", out / "report.html"
