"""The pages of a run folder that name the run (``report.html`` and the viewer's
``viewer/data/index.js``) as templates: written once with placeholders for the run's name,
time and timings, then filled with one run's values. A run kept whole in the cache
(:mod:`tap_bench.bench.run.served`) keeps the templates; the run folder's writer
(:mod:`tap_bench.bench.run.folder`) and a served run fill them with the same code, so a
served page is the page a made run writes (tested)."""

from __future__ import annotations

import contextlib
import html
import json
import secrets
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

__all__ = ["PAGES", "RUN_FACTS", "fill_page", "page_templates", "timings_html"]

PAGES = ("report.html", "viewer/data/index.js")
"""The run folder's files that name the run (kept as templates)."""
RUN_FACTS = ("run", "created", "timings")
"""The summary fields the pages show that belong to one run (placeholders in a template)."""


def timings_html(timings: Mapping[str, float] | str) -> str:
    """The report's timings section: wall time per stage [s], one row each (nothing for no
    timings; a template's placeholder as it is)."""
    if isinstance(timings, str):
        return timings
    if not timings:
        return ""
    rows = "".join(f'<tr><td class="l">{html.escape(str(stage))}</td>'
                   f'<td class="l">{float(seconds):.1f} s</td></tr>'
                   for stage, seconds in timings.items())
    return ('<h3>Timings</h3><div class="tablebox"><div class="scroll"><table id="timings" '
            'class="sortable"><caption>Wall time per stage; *_cpu_in_workers add up over the '
            'worker processes.</caption><thead><tr><th class="l">stage</th><th class="l">'
            f"seconds</th></tr></thead><tbody>{rows}</tbody></table></div></div>")


def _placeholders(nonce: str) -> dict[str, str]:
    """The text that stands for each of :data:`RUN_FACTS` in a template: letters and digits
    only, so that no page escapes it, with a random part no run's text holds."""
    return {fact: f"tapbench{fact}{nonce}" for fact in RUN_FACTS}


def fill_page(name: str, template: bytes, nonce: str, summary: Mapping[str, Any]) -> bytes:
    """The page ``name`` (one of :data:`PAGES`) of a run: its template with the run's name,
    time and timings (from ``summary``), written as the report and the viewer write them."""
    marks = _placeholders(nonce)
    run, created = str(summary.get("run", "")), str(summary.get("created", ""))
    if name == "report.html":
        values = {"run": html.escape(run), "created": html.escape(created),
                  "timings": timings_html(summary.get("timings", {}))}
    else:  # inside a JSON string of a script: what json.dumps writes, "</" escaped
        values = {fact: json.dumps(text)[1:-1].replace("</", "<\\/")
                  for fact, text in (("run", run), ("created", created))}
        values["timings"] = ""
    text = template.decode("utf-8")
    for fact, mark in marks.items():
        text = text.replace(mark, values[fact])
    return text.encode("utf-8")


@contextlib.contextmanager
def page_templates(folder: Path, summary: dict[str, Any], pages: dict[str, bytes] | None
                   ) -> Iterator[dict[str, Any]]:
    """Yield the summary the pages of ``folder`` are to be written from. With ``pages`` (a
    dict), the run's name, time and timings in it are placeholders; on leaving, each page
    written is kept in ``pages`` as its template (with ``"nonce"``) and written to
    ``folder`` filled with ``summary``'s values (:func:`fill_page`): the same bytes as
    written from ``summary`` itself (tested)."""
    if pages is None:
        yield summary
        return
    nonce = secrets.token_hex(12)
    yield {**summary, **_placeholders(nonce)}
    pages.clear()
    pages["nonce"] = nonce.encode()
    for name in PAGES:
        path = folder / name
        if path.is_file():
            pages[name] = path.read_bytes()
            path.write_bytes(fill_page(name, pages[name], nonce, summary))
