"""Every benchmark script takes the shared flags and imports only tactojax's public API.

``--help`` of every script runs in one subprocess (argparse prints and exits before any work;
one process imports JAX once), and an AST scan finds imports of private modules
(``tactojax._x``, ``tactojax.stage._x``, or ``from tactojax.stage import _x``) in every file of
``benchmarks/``.
"""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
SCRIPTS = sorted(path for path in BENCHMARKS.glob("*.py") if not path.name.startswith("_"))
SHARED_FLAGS = ("--json", "--quick", "--seed")


def test_the_benchmarks_are_found():
    assert len(SCRIPTS) >= 13


HELP_OF_EACH = """
import contextlib, io, json, runpy, sys
helps = {}
for path in sys.argv[1:]:
    sys.argv, text = [path, "--help"], io.StringIO()
    with contextlib.redirect_stdout(text):
        try:
            runpy.run_path(path, run_name="__main__")
        except SystemExit:
            pass
    helps[path] = text.getvalue()
print(json.dumps(helps))
"""


@pytest.fixture(scope="module")
def helps() -> dict[str, str]:
    """``{script name: its --help text}``, every script run as ``__main__`` from the repository root."""
    result = subprocess.run([sys.executable, "-c", HELP_OF_EACH, *map(str, SCRIPTS)], capture_output=True, text=True,
                            timeout=600, cwd=BENCHMARKS.parent)
    assert result.returncode == 0, result.stderr
    return {Path(path).name: text for path, text in json.loads(result.stdout.splitlines()[-1]).items()}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: path.name)
def test_help_lists_the_shared_flags(helps, script):
    missing = [flag for flag in SHARED_FLAGS if flag not in helps[script.name]]
    assert not missing, f"{script.name} --help lacks {missing}:\n{helps[script.name]}"


def private_imports(path: Path) -> list[str]:
    """The private tactojax modules a file imports (any ``_``-prefixed part after ``tactojax``)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        else:
            continue
        for module in modules:
            parts = module.split(".")
            if parts[0] == "tactojax" and any(part.startswith("_") and part != "__version__" for part in parts[1:]):
                found.append(module)
    return found


@pytest.mark.parametrize("path", sorted(BENCHMARKS.glob("*.py")), ids=lambda path: path.name)
def test_imports_only_the_public_api(path):
    assert private_imports(path) == []


def test_the_scan_finds_private_imports(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("import tactojax._compilation\nfrom tactojax.localize._map import map_touch\n"
                      "from tactojax.shape import _predict\nfrom tactojax.localize import map_touch\n"
                      "from tactojax import __version__\n")
    assert private_imports(sample) == ["tactojax._compilation", "tactojax.localize._map",
                                       "tactojax.localize._map.map_touch", "tactojax.shape._predict"]
