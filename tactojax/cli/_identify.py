"""``tactojax identify MAP...``: which object is in the hand, from one touch (paper section VII)."""

from __future__ import annotations

from tactojax.cli._maps import add_encoder_argument, load_maps_with_features
from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "identify", help="object identification among several maps (held-out touches)",
        description="Every imprint of every map is held out of its own map and identified as the "
                    "object whose map holds the most similar imprint (paper section VII); prints "
                    "top-1 accuracy and the confusion matrix, and saves it as a figure.")
    parser.add_argument("maps", nargs="+", help="tactile maps (.npz) of different objects")
    add_encoder_argument(parser)
    parser.add_argument("--figure", metavar="PNG", default="identification.png", help="confusion-matrix figure")
    parser.add_argument("--json", metavar="PATH", help="write the metrics as JSON")
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.localize import evaluate_identification
    from tactojax.viz import confusion_figure, save_png

    if len(args.maps) < 2:
        raise ValueError("identification needs the maps of at least two objects")
    maps, _ = load_maps_with_features(args.maps, args.encoder)
    result = evaluate_identification(maps, progress=True)
    summary = result.summary()
    confusion = result.confusion()
    names = list(result.object_ids)
    print(f"identification top-1: {100 * result.accuracy():.1f} % of {len(result.true)} held-out touches")
    print(format_table(["true \\ identified", *names, "top-1"],
                       [[name, *map(int, confusion[i]), f"{100 * summary['per_object_top1'][name]:.1f} %"]
                        for i, name in enumerate(names)]))
    save_png(confusion_figure(confusion, names), args.figure)
    print(f"figure: {args.figure}")
    if args.json:
        write_json(args.json, summary)
    return 0
