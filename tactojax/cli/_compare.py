"""``tactojax compare BEFORE.json AFTER.json``: two evaluations of one test set, episode by episode."""

from __future__ import annotations

from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "compare", help="compare two evaluations of the same test set, episode by episode (is a change real?)",
        description="Match the rows of two JSON files of `tactojax eval-localization --test` or `tactojax "
                    "eval-active` run on the same test set (by object, method or policy, fingers and grasps), and "
                    "compare them localization by localization: the share within 2 mm before and after, the "
                    "episodes only one of them places within 2 mm, McNemar's exact p-value (could the difference "
                    "be chance?), the medians, and the belief's log loss of P(within 2 mm) with Wilcoxon's "
                    "signed-rank p-value.")
    parser.add_argument("before", help="JSON of the reference run")
    parser.add_argument("after", help="JSON of the changed run (the same test set)")
    parser.add_argument("--json", metavar="PATH", help="also write the comparison as JSON")
    parser.set_defaults(run=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from tactojax.localize.evaluation import compare_evaluations, format_p

    def read(path):
        if not Path(path).is_file():
            raise FileNotFoundError(f"no evaluation JSON at {path}")
        try:
            return json.loads(Path(path).read_text())
        except json.JSONDecodeError as error:
            raise ValueError(f"{path} is not JSON ({error})") from None

    before, after = read(args.before), read(args.after)
    if before.get("test") != after.get("test"):
        print(f"note: the runs name different test sets ({before.get('test')} and {after.get('test')}); the "
              "comparison assumes the same episodes in the same order")
    compared = compare_evaluations(before, after)
    rows = []
    for c in compared:
        share, loss = c["within_2mm"], c.get("log_loss")
        rows.append([c["object"], c["method"], c["fingers"], c["grasps"] if c["fused"] else "1 (each)", c["count"],
                     f"{100 * share['before']:.0f} %", f"{100 * share['after']:.0f} %",
                     f"+{share['gained']} / -{share['lost']}", format_p(share["p"]),
                     *(c["median_mm"] or ["-", "-"]),
                     "-" if loss is None else f"{loss['before']:.3f} -> {loss['after']:.3f}",
                     "-" if loss is None else format_p(loss["p"])])
    print(format_table(["object", "method", "fingers", "grasps", "count", "<= 2 mm before", "after",
                        "episodes gained / lost", "p (McNemar)", "median before (mm)", "after (mm)",
                        "log loss of P(<= 2 mm)", "p (Wilcoxon)"], rows))
    print("\nerrors up to symmetry for symmetric objects; object all: every object's localizations pooled; p: the "
          "chance of a difference at least this large if the two runs were equally good (small: a real change)")
    if args.json:
        write_json(args.json, {"before": args.before, "after": args.after, "rows": compared})
    return 0
