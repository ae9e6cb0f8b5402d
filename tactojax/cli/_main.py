"""``tactojax`` entry point: argument parsing and dispatch to the sub-commands."""

from __future__ import annotations

import argparse
import sys

from tactojax import use_compilation_cache
from tactojax.cli import (
    _calibrate, _calibrate_belief, _demo, _eval_localization, _eval_shape, _fit_shape, _identify, _info, _localize, _localize_live,
    _map, _record, _repair, _show, _simulate, _train, _train_features,
)
from tactojax.cli import _compact, _compare, _eval_active, _import_bag, _map_catalog, _view


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tactojax",
        description="Tactile mapping and localization from high-resolution tactile imprints.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in (_simulate, _info, _train, _eval_shape, _calibrate, _train_features, _map, _map_catalog, _calibrate_belief,
                   _fit_shape, _show, _eval_localization, _eval_active, _compare, _identify, _localize, _record, _localize_live,
                   _demo, _repair, _compact):
        module.add_parser(commands)
    _import_bag.add_parser(commands)
    _view.add_parser(commands)
    return parser


class UserError(Exception):
    """A problem with the user's input, printed without a traceback."""


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Compiled programs are kept between runs (TACTOJAX_COMPILATION_CACHE=off: not kept).
    use_compilation_cache()
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, ImportError, UserError) as error:
        print(f"tactojax {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
