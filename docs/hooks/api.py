"""MkDocs hook: one API reference page per ``tactojax`` subpackage (and public submodule), and a
check that it is complete.

Each page is generated at build time (nothing to keep in step by hand): ``::: tactojax.NAME``
with its members listed explicitly, taken from the package's ``__all__`` or, for a package
without one, from its ``from ... import X as X`` re-exports. After the build, every one of those
names must appear in the site's ``objects.inv`` (the inventory mkdocstrings writes); a missing
one is a warning, so ``mkdocs build --strict`` fails.

The docstrings cross-reference in Sphinx's way (``:class:`PoseBelief```,
``:func:`~tactojax.localize.fit_calibration```); the rendered pages show the name alone, in code.
"""

from __future__ import annotations

import ast
import logging
import re
import zlib
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.api")
ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "tactojax"


def public_names(init: Path) -> list[str]:
    """A package's public names: its ``__all__``, else the names it re-exports as ``X as X``."""
    tree = ast.parse(init.read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return [ast.literal_eval(element) for element in node.value.elts]
    return [alias.name for node in tree.body if isinstance(node, ast.ImportFrom)
            for alias in node.names if alias.asname == alias.name]


LAYERS = ("storage", "geometry", "sensor", "objects", "simulate", "shape", "mapping", "features", "localize",
          "io", "hardware", "viz", "cli")
"""The packages bottom to top (DESIGN.md); any other comes after them."""


def packages() -> dict[str, list[str]]:
    """``{"tactojax.NAME": [public names]}`` for the top level, every public subpackage (in layer
    order) and each one's public submodules."""
    found = {"tactojax": public_names(PACKAGE / "__init__.py")}
    order = {name: rank for rank, name in enumerate(LAYERS)}
    inits = sorted(PACKAGE.glob("*/__init__.py"), key=lambda init: (order.get(init.parent.name, len(LAYERS)),
                                                                        init.parent.name))
    for init in inits:
        if not init.parent.name.startswith("_"):
            found[f"tactojax.{init.parent.name}"] = public_names(init)
            for module in sorted(init.parent.glob("[!_]*.py")):  # public submodules (tactojax.localize.active)
                found[f"tactojax.{init.parent.name}.{module.stem}"] = public_names(module)
    return found


def page(module: str, names: list[str]) -> str:
    """The Markdown of one API page."""
    members = "".join(f"        - {name}\n" for name in names if name != "__version__")
    return f"# `{module}`\n\n::: {module}\n    options:\n      members:\n{members}"


def api_uri(module: str) -> str:
    """Where a package's API page goes: ``api/index.md`` for ``tactojax``, else ``api/NAME.md``
    (``api/NAME.SUB.md`` for a public submodule)."""
    return "api/index.md" if module == "tactojax" else f"api/{module.split('.', 1)[1]}.md"


def on_config(config):
    """The nav's "API reference" section lists every package's page (new packages included)."""
    for entry in config["nav"] or []:
        if isinstance(entry, dict) and "API reference" in entry:
            entry["API reference"] = [{module: api_uri(module)} for module in packages()]
    return config


def on_files(files, config):
    for module, names in packages().items():
        files.append(File.generated(config, api_uri(module), content=page(module, names)))
    return files


SPHINX_ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|obj|exc|const|ref):(?=<code>)")
SHORT_NAME = re.compile(r"<code>~(?:[\w]+\.)*([\w]+)</code>")


def on_page_content(html, page, config, files):
    """Sphinx roles in the rendered docstrings: ``:class:<code>X</code>`` -> ``<code>X</code>``,
    ``<code>~a.b.X</code>`` -> ``<code>X</code>``, and ``Example::`` -> ``Example:``."""
    if not page.file.src_uri.startswith("api/"):
        return html
    html = SHORT_NAME.sub(r"<code>\1</code>", SPHINX_ROLE.sub("", html))
    return html.replace("::</p>", ":</p>")  # reStructuredText's literal-block marker


def inventory_names(path: Path) -> set[str]:
    """The object names of a Sphinx inventory (``objects.inv``, version 2)."""
    data = path.read_bytes()
    body = data.split(b"\n", 4)[4]
    return {line.split(" ", 1)[0] for line in zlib.decompress(body).decode().splitlines() if line}


def on_post_build(config):
    inventory = Path(config["site_dir"]) / "objects.inv"
    documented = inventory_names(inventory)
    for module, names in packages().items():
        for name in names:
            if name != "__version__" and f"{module}.{name}" not in documented:
                log.warning(f"API reference: {module}.{name} is public but not documented")
