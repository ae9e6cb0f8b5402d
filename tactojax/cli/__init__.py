"""The ``tactojax`` command line: thin sub-commands over the library, and its table and JSON writer
(which the benchmarks use too)."""

from tactojax.cli._main import main as main
from tactojax.cli._table import format_table as format_table
from tactojax.cli._table import write_json as write_json

__all__ = ["format_table", "main", "write_json"]
