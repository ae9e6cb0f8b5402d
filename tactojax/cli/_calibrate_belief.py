"""``tactojax calibrate-belief MAP... --grasps DIR``: fit the belief's likelihood scales on the map's own grasps."""

from __future__ import annotations

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._maps import add_encoder_argument
from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "calibrate-belief", help="fit the pose belief's likelihood scales on calibration grasps",
        description="Run the pose belief over calibration grasps of each map's object (episodes of grasps "
                    "at known poses: `tactojax simulate OBJECT --protocol grasps --seed S`, with a seed of "
                    "their own, never the test set's) and fit its temperature, appearance weight and "
                    "fusion exponent (the temperature and exponent so that its P(within 2 mm) is calibrated, then "
                    "the probability, by touch count, that its search found the true pose's mode at all; the "
                    "appearance weight relative to the temperature, which decides the poses, stays the default's "
                    "unless --fit-shape or the maps' features come from another encoder); the fit is stored in the "
                    "map's header, where every command that runs the belief reads it.")
    parser.add_argument("maps", nargs="+", help="tactile maps (.npz) from `tactojax map` or map catalogs (the fit "
                                                 "is written into their headers; nothing else changes)")
    parser.add_argument("--grasps", nargs="+", required=True, metavar="DIR",
                        help="new-grasps datasets holding each map's object (`--protocol grasps`)")
    parser.add_argument("--fingers", type=int, choices=[1, 2], default=2,
                        help="fingers fused per grasp, as the robot will (default 2)")
    parser.add_argument("--fit-shape", action="store_true",
                        help="also fit the appearance weight relative to the temperature, by the likelihood of the "
                             "true pose (it decides which pose wins: on the catalog objects' 32 calibration episodes "
                             "it lost episodes; always fit for features of an encoder other than the default's)")
    parser.add_argument("--search-only", action="store_true",
                        help="keep the default's scales and fit only the probability, by touch count, that the "
                             "search found the true pose's mode (the term that differs most between objects; "
                             "the poses and the scales stay the default's)")
    parser.add_argument("--rounds", type=int, default=None,
                        help="fits, each running the belief with the previous one's scales (with --fit-shape they "
                             "decide which hypotheses it keeps; default 2 then, else 1: the shape kept, a second "
                             "round would find the same hypotheses)")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model for the images (default {DEFAULT_MODEL})")
    add_encoder_argument(parser)
    parser.add_argument("--json", metavar="PATH", help="write the fits as JSON")
    parser.set_defaults(run=run)


def _episodes_of(object_id: str, directories, model, encoder):
    """The calibration episodes of ``object_id`` from the first directory that holds it."""
    from tactojax.io import read_test_grasps
    from tactojax.localize.evaluation import load_test_episodes

    for directory in directories:
        try:
            read_test_grasps(directory, ["opening_mm"], object_id=object_id)
        except ValueError:
            continue
        return load_test_episodes(directory, object_id, model, encoder)
    raise ValueError(f"no calibration grasps of {object_id!r} in {list(directories)} "
                     f"(make them with `tactojax simulate {object_id} --protocol grasps --seed S --out DIR`)")


def run(args) -> int:
    from tactojax.cli._maps import maps_and_query_encoder, maps_encoder_name
    from tactojax.io import DEFAULT_ENCODER, expand_catalogs, resolve_shape_model
    from tactojax.localize import calibration_to_json

    args.maps = expand_catalogs(args.maps)
    maps, encoder = maps_and_query_encoder(args.maps, args.encoder)
    # The default's shape belongs to its encoder's features: the features of another need their own.
    fit_shape = args.fit_shape or maps_encoder_name(args.maps, args.encoder) != DEFAULT_ENCODER
    if args.search_only and fit_shape:
        raise ValueError("--search-only keeps the default's scales, which belong to the default encoder's features: "
                         "not with --fit-shape or the features of another encoder")
    rounds = args.rounds if args.rounds is not None else (2 if fit_shape else 1)
    if rounds < 1:
        raise ValueError(f"--rounds must be at least 1, got {rounds}")
    model = resolve_shape_model(args.model)
    rows, payload = [], {}
    for path, tactile_map in zip(args.maps, maps):
        episodes, recorded = _episodes_of(tactile_map.object_id, args.grasps, model, encoder)
        if args.fingers > recorded:
            raise ValueError(f"--fingers {args.fingers}: the calibration grasps of {tactile_map.object_id} "
                             f"record {recorded} finger per grasp (simulate them with --fingers 2)")
        calibration, report = calibrate_map_file(path, tactile_map, episodes, fingers=args.fingers, fit_shape=fit_shape,
                                                 search_only=args.search_only, rounds=rounds)
        report.update(encoder=maps_encoder_name([path], args.encoder), grasps=list(args.grasps))
        store_calibration(path, report)
        payload[tactile_map.object_id] = report
        rows.append([tactile_map.object_id, report["beliefs"], *calibration_to_json(calibration).values(),
                     report["truth_loss"], report["loss"], f"{100 * report['accuracy']:.0f} %"])
    fields = [name.replace("_", " ") for name in calibration_to_json(calibration)]
    print(format_table(["object", "beliefs", *fields, "truth NLL", "within log loss", "best within 2 mm"], rows))
    if args.json:
        write_json(args.json, payload)
    return 0


def calibrate_map_file(path, tactile_map, episodes, *, fingers: int = 2, fit_shape: bool = False,
                       search_only: bool = False, rounds: int = 1, progress: bool = True):
    """Fit the belief's calibration of the map stored at ``path`` on its object's calibration episodes.

    Args:
        path: the map's file (its stored surface is read, nothing is written).
        tactile_map: the map, as loaded from ``path``.
        episodes: calibration grasps of the map's object (:class:`~tactojax.localize.evaluation.TestEpisodes`).
        fingers: fingers fused per grasp.
        fit_shape: also fit the appearance weight relative to the temperature (else the default's).
        search_only: keep the default's scales and fit only the missed-search term.
        rounds: fits, each running the belief with the previous one's scales.
        progress: show a progress bar.

    Returns:
        (the fit :class:`~tactojax.localize.BeliefCalibration`, its report for the map's header).
    """
    from tactojax.io import stored_surface
    from tactojax.localize import BeliefCalibration, LocalizationMap, fit_calibration
    from tactojax.localize.evaluation import record_beliefs

    view = LocalizationMap.from_tactile_map(tactile_map, surface=stored_surface(path))  # the first round: uncalibrated
    for _ in range(rounds):
        records = record_beliefs(view, episodes, fingers=fingers, progress=progress)
        calibration, report = fit_calibration(records, None if fit_shape else BeliefCalibration.default(),
                                              search_only=search_only)
        view = view.replace(calibration=calibration)  # the next round keeps hypotheses by this fit
    report.update(fingers=fingers, shape_fit=fit_shape, search_only=search_only,
                  episodes=int(episodes.openings.shape[0]))
    return calibration, report


def typical_touch_found(calibration, report: dict) -> tuple[float, float]:
    """P(search found) after one touch of the map's object, at its typical size: (the median
    contact area of the single touches of its calibration grasps, mm², or the reference area
    for a fit stored before that was recorded; P under ``calibration``). ``report``: the fit's
    report (:func:`calibrate_map_file`'s, as stored in the map's header)."""
    from tactojax.localize._map import REFERENCE_CONTACT_MM2

    area = report.get("contact_mm2") or REFERENCE_CONTACT_MM2
    return area, float(calibration.found_probability(1, area))


def store_calibration(path, report: dict) -> None:
    """Write a fit's report (:func:`calibrate_map_file`'s, with its encoder) into the map's header,
    where every command that runs the belief reads it; the file keeps its arrays and format."""
    from tactojax.io import tactile_map_metadata, update_tactile_map_metadata

    metadata = tactile_map_metadata(path).get("metadata", {})
    metadata["belief_calibration"] = report
    update_tactile_map_metadata(path, metadata)
