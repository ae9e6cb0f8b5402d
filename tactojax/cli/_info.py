"""``tactojax info DIR|MAP``: what a dataset holds (counts per object, image size, sensor), a map
catalog (its maps, sizes and build times), or where a tactile map's bytes are (per field, in memory
and on disk, per imprint)."""

from __future__ import annotations

from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser("info", help="summarise a dataset, a map catalog or a tactile map, or list the "
                                              "object catalog",
                                 description="Counts per object, image size and sensor of a dataset; the maps, "
                                             "sizes and build times of a map catalog (`tactojax map-catalog`); for a "
                                             "tactile map (.npz), its bytes per imprint, per field, in memory and on "
                                             "disk.")
    parser.add_argument("dataset", nargs="?", help="dataset or map-catalog directory, or a tactile map (.npz)")
    parser.add_argument("--json", metavar="PATH", help="also write the summary as JSON")
    parser.add_argument("--objects", action="store_true", help="list the built-in object catalog")
    parser.add_argument("--ycb", choices=["all", "training"],
                        help="list the ids of the YCB scans (simulate them as ycb:ID), one per line; training: "
                             "without the evaluation objects' scans (scissors, markers, screwdrivers)")
    parser.set_defaults(run=run)


def run(args) -> int:
    if args.objects:
        return _list_objects(args)
    if args.ycb:
        from tactojax.objects import ycb_scans

        print("\n".join(ycb_scans(training=args.ycb == "training")))
        return 0
    if not args.dataset:
        raise ValueError("give a dataset directory, or --objects to list the catalog (--ycb the YCB scans)")
    from pathlib import Path

    if Path(args.dataset).is_file():
        return _map_bytes(args)
    from tactojax.io import dataset_summary, is_catalog, read_catalog

    if is_catalog(args.dataset):
        from tactojax.cli._map_catalog import summary_table

        index = read_catalog(args.dataset)
        print(summary_table(args.dataset, index))
        if args.json:
            write_json(args.json, index)
        return 0
    summary = dataset_summary(args.dataset)
    metadata = summary.get("metadata", {})
    sensor = metadata.get("sensor", {})
    protocol = metadata.get("protocol", {})
    image_shape = summary["schema"].get("image", {}).get("shape")
    print(f"dataset   {summary['path']}")
    print(f"imprints  {summary['count']} in {summary['chunks']} chunks ({summary['bytes'] / 1e6:.1f} MB)")
    mm_per_px = sensor.get("mm_per_px", float("nan"))
    print(f"sensor    {sensor.get('name', '?')}, {mm_per_px:.4f} mm/px, image {image_shape}")
    print(f"protocol  {protocol.get('name', '?')}")
    for repair in metadata.get("repairs", []):  # records dropped by `tactojax repair`
        lost = repair.get("lost", [])
        print(f"repaired  {repair.get('date', '?')}: lost {sum(c.get('records', 0) for c in lost)} records "
              f"({', '.join(c.get('file', '?') for c in lost)})")
    groups = summary.get("groups") or {}
    if groups:
        from tactojax.io import dataset_symmetry

        print()
        symmetries = {name: dataset_symmetry(metadata, name) for name in groups}
        print(format_table(["object", "imprints", "symmetry"],
                           [[name, count, "-" if symmetries[name] is None else symmetries[name].describe()]
                            for name, count in sorted(groups.items())]))
    if args.json:
        write_json(args.json, summary)
    return 0


def _map_symmetry(header: dict) -> str:
    """The map's symmetry group in words, and where it comes from (``header``: the map's)."""
    from tactojax.objects import ObjectSymmetry, object_symmetry

    if "symmetry" in header:
        return f"{ObjectSymmetry.from_json(header['symmetry']).describe()} (recorded when mapped)"
    return f"{object_symmetry(header['object_id']).describe()} (the catalog's, by object id; none recorded)"


def _map_calibration(header: dict) -> str:
    """The belief calibration the map's header stores, in words (``calibrate-belief``, ``map-catalog --calibrate``)."""
    from tactojax.cli._calibrate_belief import typical_touch_found
    from tactojax.localize import calibration_from_json

    fit = header.get("metadata", {}).get("belief_calibration")
    if fit is None:
        return "the default (no fit of its own: `calibrate-belief` or `map-catalog --calibrate`)"
    kind = "the search term" if fit.get("search_only") else "every scale" if fit.get("shape_fit") else "the sharpness"
    calibration = calibration_from_json(fit)
    typical, found = typical_touch_found(calibration, fit)
    pinpoint = (f", {float(calibration.found_probability(1, 1.0)):.2f} after one of 1 mm²"
                if float(calibration.found_contact) > 0 else "")
    return (f"{kind} fit on {fit.get('episodes', '?')} episodes of its object's grasps ({fit.get('fingers', '?')} "
            f"fingers); P(search found) after one touch of {typical:.0f} mm² {found:.2f}{pinpoint}")


def _map_bytes(args) -> int:
    from tactojax.io import tactile_map_bytes, tactile_map_metadata

    summary = tactile_map_bytes(args.dataset)
    count = max(summary["imprints"], 1)
    rows = [[name, f"{field['memory'] / count:,.0f}", "-" if field["disk"] is None else f"{field['disk'] / count:,.0f}"]
            for name, field in sorted(summary["fields"].items(), key=lambda item: -item[1]["memory"])]
    total = summary["memory_bytes"] + summary["surface_bytes"]
    rows.append(["total", f"{total / count:,.0f}", f"{summary['file_bytes'] / count:,.0f}"])
    print(f"map       {args.dataset}: {summary['object_id']}, {summary['imprints']} imprints, format version "
          f"{summary['version']}")
    print(f"memory    {summary['loaded_bytes'] / count:,.0f} bytes per imprint as loaded (without images)")
    surface = (f"stored, {summary['surface_bytes'] / count:,.0f} bytes per imprint" if summary["surface_bytes"]
               else "not stored (built when the map is loaded for localization)")
    print(f"surface   {surface}")
    header = tactile_map_metadata(args.dataset)
    print(f"symmetry  {_map_symmetry(header)}")
    print(f"belief    {_map_calibration(header)}")
    print(format_table(["field", "bytes/imprint (memory)", "bytes/imprint (disk)"], rows))
    if args.json:
        write_json(args.json, summary)
    return 0


def _list_objects(args) -> int:
    from tactojax.objects import CATALOG

    rows = []
    for name in CATALOG:
        from tactojax.objects import get_object

        try:
            obj = get_object(name)
            rows.append([name, obj.group, "x".join(f"{e:.0f}" for e in obj.extents), obj.description])
        except ImportError as error:
            rows.append([name, "-", "-", f"unavailable: {error}"])
    print(format_table(["object", "group", "size (mm)", "description"], rows))
    if args.json:
        write_json(args.json, {"objects": [dict(zip(["name", "group", "size_mm", "description"], r)) for r in rows]})
    return 0
