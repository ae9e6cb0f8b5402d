"""MkDocs hook: the benchmarks page, generated from the JSON files in ``benchmarks/results/``.

``mkdocs build`` (or ``mkdocs serve``) regenerates the page; ``python docs/hooks/benchmarks.py``
prints the same Markdown. Each results file holds one benchmark's record::

    {"benchmark": "mapping", "order": 20, "title": "...", "date": "YYYY-MM-DD",
     "version": "...", "machine": "...", "jax": "0.10.2", "command": "python benchmarks/...",
     "source": "where the figures come from", "notes": "...",
     "tables": [{"title": "...", "header": [...], "rows": [[...], ...], "notes": "..."}]}

``jax``, ``notes`` and ``source`` are optional. To update a result, run its command and
replace the file's tables (and its date, version and machine).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

log = logging.getLogger("mkdocs.hooks.benchmarks")
RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
MARKER = "<!-- benchmark results -->"
REQUIRED = ("benchmark", "title", "date", "version", "machine", "command", "tables")


def _cell(value) -> str:
    return "-" if value is None else str(value).replace("|", "\\|")


def render_table(table: dict) -> str:
    lines = [f"**{table['title']}**", ""] if table.get("title") else []
    lines.append("| " + " | ".join(_cell(h) for h in table["header"]) + " |")
    lines.append("|" + "---|" * len(table["header"]))
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in table["rows"]]
    if table.get("notes"):
        lines += ["", table["notes"]]
    return "\n".join(lines)


def render_result(result: dict) -> str:
    missing = [key for key in REQUIRED if key not in result]
    if missing:
        raise ValueError(f"benchmark result {result.get('benchmark', '?')!r} lacks {', '.join(missing)}")
    jax = f" · JAX {result['jax']}" if result.get("jax") else ""
    lines = [f"## {result['title']}", "",
             f"*{result['date']} · tactojax {result['version']} · {result['machine']}{jax}*", "",
             f"```bash\n{result['command']}\n```", ""]
    for table in result["tables"]:
        lines += [render_table(table), ""]
    if result.get("notes"):
        lines += [result["notes"], ""]
    if result.get("source"):
        lines += [f"<small>Source: {result['source']}; `benchmarks/results/{result['benchmark']}.json`.</small>", ""]
    return "\n".join(lines)


def load_results(directory: Path = RESULTS) -> list[dict]:
    results = [json.loads(path.read_text()) for path in sorted(directory.glob("*.json"))]
    return sorted(results, key=lambda r: (r.get("order", 1000), r["benchmark"]))


def render(directory: Path = RESULTS) -> str:
    results = load_results(directory)
    contents = "\n".join(f"- [{r['title']}](#{_anchor(r['title'])}) ({r['date']})" for r in results)
    return contents + "\n\n" + "\n".join(render_result(r) for r in results)


def _anchor(title: str) -> str:
    """The anchor MkDocs' default ``toc`` slugify gives a heading."""
    import re
    import unicodedata

    text = unicodedata.normalize("NFKD", title).encode("ascii", "ignore").decode()
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def on_page_markdown(markdown, page, config, files):
    if page.file.src_uri != "benchmarks.md":
        return markdown
    if MARKER not in markdown:
        log.warning(f"benchmarks.md lacks the marker {MARKER!r} where the results go")
        return markdown
    return markdown.replace(MARKER, render())


if __name__ == "__main__":
    print(render())
