"""``tactojax show MAP --out PNG``: a figure of a tactile map (the paper's "Tactile shape")."""

from __future__ import annotations


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "show", help="draw a tactile map as a PNG",
        description="The map's stitched contact cloud from two viewpoints, with a few of its "
                    "imprints (image and predicted heightmap).")
    parser.add_argument("map", help="tactile map (.npz) from `tactojax map`")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--examples", type=int, default=3, help="imprints shown beside the cloud")
    parser.set_defaults(run=run)


def run(args) -> int:
    import sys

    import numpy as np

    from tactojax.io import load_tactile_map
    from tactojax.mapping import stitched_point_cloud
    from tactojax.viz import tactile_map_figure

    tactile_map = load_tactile_map(args.map, images=args.examples > 0)
    if tactile_map.images is None and args.examples > 0:
        print(f"note: {args.map} stores no images (a compact map): no example imprints", file=sys.stderr)
        args.examples = 0
    points, _ = stitched_point_cloud(tactile_map)
    examples = None
    if args.examples > 0:
        contact = np.asarray(tactile_map.masks.sum(axis=(1, 2)))
        picks = np.argsort(-contact)[np.linspace(0, len(contact) // 2, args.examples).astype(int)]
        examples = (np.asarray(tactile_map.images)[picks], np.asarray(tactile_map.heightmaps)[picks])
    title = (f"{tactile_map.object_id}: {int(tactile_map.imprint_valid.sum())} imprints, "
             f"{len(points)} contact points")
    tactile_map_figure(points, args.out, title=title, examples=examples,
                       mm_per_px=tactile_map.mm_per_px)
    print(f"figure: {args.out}")
    return 0
