"""The ``tactojax`` command line: thin sub-commands over the library."""

from tactojax.cli._main import main as main

__all__ = ["main"]
