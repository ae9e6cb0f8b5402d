"""``tactojax compact MAP... --out DIR``: rewrite maps in the compact format (no remapping)."""

from __future__ import annotations

from tactojax.cli._table import format_table


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "compact", help="rewrite tactile maps in the compact format",
        description="Rewrite tactile maps (any format version) in the compact one: heightmaps and contact masks "
                    "packed into float16, points as pixel indices, no images unless kept. The header (belief "
                    "calibration, metadata) is kept; features of unknown origin are encoded with the default "
                    "encoder first.")
    parser.add_argument("maps", nargs="+", help="tactile maps (.npz)")
    parser.add_argument("--out", required=True, help="directory for the compact maps (same file names)")
    parser.add_argument("--keep-images", action="store_true",
                        help="keep the tactile images (needed to encode features with another encoder later)")
    parser.set_defaults(run=run)


def run(args) -> int:
    from pathlib import Path

    from tactojax.io import compact_tactile_map, tactile_map_bytes

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for source in map(Path, args.maps):
        destination = out / source.name
        if destination.resolve() == source.resolve():
            raise ValueError(f"--out would overwrite {source}: choose another directory")
        before = tactile_map_bytes(source)
        compact_tactile_map(source, destination, keep_images=args.keep_images)
        after = tactile_map_bytes(destination)
        count = after["imprints"]
        rows.append([str(destination), count, f"{before['memory_bytes'] / count / 1e3:.1f}",
                     f"{after['loaded_bytes'] / count / 1e3:.1f}", f"{before['file_bytes'] / 1e6:.1f}",
                     f"{after['file_bytes'] / 1e6:.1f}"])
    print(format_table(["map", "imprints", "kB/imprint before", "kB/imprint now", "file MB before",
                        "file MB now"], rows))
    return 0
