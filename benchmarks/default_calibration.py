"""The default belief calibration's search term: how often the belief's hypotheses miss the truth.

A map that ``tactojax calibrate-belief`` never fit runs with ``BeliefCalibration.default()``. Its
likelihood scales are the element-wise median of the five catalog objects' fits; its
P(the search found the true pose's mode) = sigmoid(offset + slope * log touches) is fit here, on
the five objects' calibration grasps *pooled*, under those default scales: the belief runs over
every episode touch by touch (:func:`tactojax.localize.evaluation.record_beliefs`), and
:func:`tactojax.localize.evaluation.fit_found_probability` chooses the offset and slope by the
log loss of what happened under the reported P(within 2 mm).

Printed per object and pooled, by the touches a belief holds: the mean P(within 2 mm) the belief
reports with a complete search assumed (before) and with the fitted term (after), the share of
beliefs whose best pose was within 2 mm (observed), and the log loss before and after.

    python benchmarks/default_calibration.py scissors.npz screwdriver.npz large_marker.npz gum_box.npz \
        tape_roll.npz --grasps data/cal-scissors data/cal-screwdriver ... --json default_calibration.json
    python benchmarks/default_calibration.py --quick     # smoke run: 4 episodes of the scissors on a 20 mm map
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import numpy as np

try:
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    map_paths, new_grasps_set, write_json)
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, map_paths,
                         new_grasps_set, write_json)

from tactojax.io import read_test_grasps, resolve_encoder, resolve_shape_model
from tactojax.localize import BeliefCalibration, LocalizationMap
from tactojax.localize.evaluation import (fit_found_probability, load_test_episodes, predict_within, record_beliefs,
                                         within_log_loss)

TOUCH_GROUPS = ((1, 1), (2, 2), (3, 4), (5, 6))
"""Touch counts reported together."""


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_map_arguments(parser, several=True)
    parser.add_argument("--grasps", nargs="*", default=[], metavar="DIR",
                        help="calibration grasps holding each map's object (`tactojax simulate OBJECT --protocol "
                             "grasps --seed 900`; default: simulate them)")
    parser.add_argument("--episodes", type=int, default=32, help="episodes simulated without --grasps (default 32)")
    add_common_arguments(parser, quick="4 episodes of the scissors, a 20 mm map", seed=900,
                         seed_help="seed of simulated calibration grasps")
    args = parser.parse_args()
    if args.quick:
        args.episodes = min(args.episodes, 4)
    return args


def grasps_of(args, object_id: str):
    """The calibration grasps of ``object_id``: the first ``--grasps`` directory holding it."""
    for directory in args.grasps:
        try:
            read_test_grasps(directory, ["opening_mm"], object_id=object_id)
        except ValueError:
            continue
        return directory
    if args.grasps:
        raise ValueError(f"no calibration grasps of {object_id!r} in {args.grasps}")
    return new_grasps_set(args, object_id, episodes=args.episodes, grasps=3, fingers=2)


def usable(records):
    """The records of beliefs that hold a hypothesis (as :func:`~tactojax.localize.fit_calibration` keeps)."""
    keep = records.valid.any(axis=1)
    return jax.tree.map(lambda x: x[keep], records)


def summary(records, before: BeliefCalibration, after: BeliefCalibration) -> dict:
    """Mean reported P(within 2 mm) before and after, the observed share and the log losses, by
    touch group and over all beliefs."""
    p_before, happened = predict_within(records, before)
    p_after, _ = predict_within(records, after)
    touches = np.asarray(records.touches)

    def loss(p, mask):
        return within_log_loss(p[mask], happened[mask])

    groups = {}
    for low, high in TOUCH_GROUPS:
        mask = (touches >= low) & (touches <= high)
        if mask.any():
            groups[f"{low}-{high}" if low < high else f"{low}"] = {
                "beliefs": int(mask.sum()), "predicted_before": float(p_before[mask].mean()),
                "predicted_after": float(p_after[mask].mean()), "observed": float(happened[mask].mean()),
                "log_loss_before": loss(p_before, mask), "log_loss_after": loss(p_after, mask)}
    everything = np.ones_like(happened, bool)
    return {"touches": groups, "log_loss_before": loss(p_before, everything),
            "log_loss_after": loss(p_after, everything), "beliefs": int(everything.sum())}


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    default = BeliefCalibration.default()
    # The search assumed complete: the search term at BeliefCalibration's own defaults.
    complete = default.replace(**{f.name: f.default for f in dataclasses.fields(BeliefCalibration)
                                  if f.name.startswith("found_")})
    recorded = {}
    for tactile_map, _ in load_maps(args, model, encoder):
        episodes, _ = load_test_episodes(grasps_of(args, tactile_map.object_id), tactile_map.object_id, model, encoder,
                                         progress=False)
        view = LocalizationMap.from_tactile_map(tactile_map, calibration=default)
        print(f"{tactile_map.object_id}: {episodes.openings.shape[0]} episodes", flush=True)
        recorded[tactile_map.object_id] = usable(record_beliefs(view, episodes, fingers=2, progress=True))
    pooled = jax.tree.map(lambda *x: np.concatenate(x), *recorded.values())
    fitted = fit_found_probability(pooled, complete)
    results = {name: summary(r, complete, fitted) for name, r in {**recorded, "pooled": pooled}.items()}
    rows = []
    for name, result in results.items():
        for group, row in result["touches"].items():
            rows.append([name, group, row["beliefs"], f"{row['predicted_before']:.2f}", f"{row['predicted_after']:.2f}",
                         f"{row['observed']:.2f}", f"{row['log_loss_before']:.3f}", f"{row['log_loss_after']:.3f}"])
    print(format_table(["object", "touches", "beliefs", "mean P before", "mean P after", "observed",
                        "log loss before", "log loss after"], rows))
    found = fitted.found_probability(np.array([1, 2, 3, 6]))
    print(f"fitted: found_offset {float(fitted.found_offset):.2f}, found_slope {float(fitted.found_slope):.2f}, "
          f"found_contact {float(fitted.found_contact):.2f} "
          f"(P(found) after 1 / 2 / 3 / 6 touches of 20 mm²: {' / '.join(f'{float(p):.2f}' for p in found)}); "
          f"pooled log loss {results['pooled']['log_loss_before']:.3f} -> {results['pooled']['log_loss_after']:.3f}")
    if args.json:
        write_json(args.json, {"maps": map_paths(args), "grasps": args.grasps, "found_offset": float(fitted.found_offset),
                               "found_slope": float(fitted.found_slope), "found_contact": float(fitted.found_contact),
                               "results": results, "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
