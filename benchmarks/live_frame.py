"""Where one live frame's time goes: the parts of a ``Localizer`` call, timed in one process (issue 27).

``benchmarks/live.py`` gives the sustained rate of the whole loop; this script splits one frame
into its parts, on whatever device JAX uses (a GPU when there is one), so that the next change
aims at the largest. Medians and 90th percentiles of ``--repeats`` calls after a warm-up:

=========================  =====================================================================
part                       what is timed
=========================  =====================================================================
upload                     the frame to the default device (``jax.device_put``, blocked on)
round-trip floor           a one-operation program on the frame, its boolean read back
frame program              ``predict`` + ``observed_contact`` + ``shows_contact`` as one program,
                           frame in, contact flag out: what a frame in contact runs
host contact check         ``may_show_contact``: what a frame without a colour change costs
call, released             a ``Localizer`` call on the background frame, before any grasp
call, in contact           a call on a frame of a settled grasp (the estimate reported)
call, released, estimate   the background frame after that grasp (its estimate reported)
camera read                ``OpenCVCamera.read`` of a lossless video of the frames
=========================  =====================================================================

Also the kernels the frame program launches (``tactojax.kernel_count``; a loop counts once).

    python benchmarks/live_frame.py MAP.npz --json live_frame.json
    python benchmarks/live_frame.py --quick        # a 20 mm map, 50 repeats
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from tactojax import kernel_count
from tactojax.hardware import OpenCVCamera, write_video
from tactojax.io import read_test_grasps, resolve_encoder, resolve_shape_model
from tactojax.localize import Localizer
from tactojax.mapping import may_show_contact, observed_contact, shows_contact
from tactojax.sensor import gelslim
from tactojax.shape import coordinate_bias, predict

try:  # run as ``python benchmarks/live_frame.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    new_grasps_set, write_json)
except ImportError:
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                         new_grasps_set, write_json)


def milliseconds(call, repeats: int) -> dict[str, float]:
    """Median and 90th percentile (ms) of ``repeats`` calls, after ``repeats // 10 + 5`` warm ones."""
    for _ in range(repeats // 10 + 5):
        call()
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - start)
    return {"median_ms": 1e3 * float(np.median(seconds)), "p90_ms": 1e3 * float(np.percentile(seconds, 90))}


def frame_program(model):
    """The frame's program as a user can build it from the public API: (compiled, its arguments
    but the image), image (H, W, 3) uint8 in, contact flag out."""
    def contact(model, bias, image):
        pixels = image.astype(jnp.float32) / 255.0
        heightmap, mask = predict(model, pixels, bias)
        return shows_contact(pixels, model.background, observed_contact(pixels, model.background, mask,
                                                                        model.mm_per_px))

    arguments = jax.device_put((model, jax.jit(coordinate_bias)(model)))
    image = jax.ShapeDtypeStruct((*model.image_shape, 3), jnp.uint8)
    return jax.jit(contact).lower(*arguments, image).compile(), arguments


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser)
    parser.add_argument("--test", metavar="DIR", help="a new-grasps test set of the object (default: simulate one)")
    add_common_arguments(parser, quick="a 20 mm map, 50 repeats", seed_help="simulated test set", repeats=400)
    args = parser.parse_args()
    if args.quick:
        args.repeats = min(args.repeats, 50)
    return args


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, calibration),) = load_maps(args, model, encoder)
    test = new_grasps_set(args, tactile_map.object_id, episodes=1, grasps=1, fingers=1)
    records = read_test_grasps(test, ["image", "opening_mm", "T_world_gripper"], object_id=tactile_map.object_id)
    image = np.ascontiguousarray(records["image"][0])
    opening, gripper = float(records["opening_mm"][0]), records["T_world_gripper"][0].astype(np.float32)
    background = np.round(np.asarray(model.background) * 255).astype(np.uint8)
    background_float = np.asarray(model.background, np.float32)
    repeats = args.repeats

    print(f"compiling ({tactile_map.object_id}: {len(tactile_map)} imprints) ...", flush=True)
    program, arguments = frame_program(model)
    floor = jax.jit(lambda frame: jnp.any(frame > 250))
    localizer = Localizer([tactile_map], model, encoder, calibrations=[calibration])
    parts = {
        "upload": milliseconds(lambda: jax.block_until_ready(jax.device_put(image)), repeats),
        "round-trip floor": milliseconds(lambda: bool(floor(image)), repeats),
        "frame program": milliseconds(lambda: bool(program(*arguments, image)), repeats),
        "host contact check": milliseconds(lambda: may_show_contact(image, background_float), repeats),
        "call, released": milliseconds(lambda: localizer(background, opening + 10.0, gripper), repeats),
    }
    for _ in range(localizer.live.settle_frames):  # the grasp settles and updates the belief
        localizer(image, opening, gripper)
    localizer.wait()
    if localizer.grasps != 1:
        raise SystemExit(f"the test set's first touch shows no contact in {test}: choose another --seed")
    parts["call, in contact"] = milliseconds(lambda: localizer(image, opening, gripper), repeats)
    parts["call, released, estimate"] = milliseconds(lambda: localizer(background, opening + 10.0, gripper), repeats)
    localizer.close()
    Path(args.work).mkdir(parents=True, exist_ok=True)
    video = write_video(Path(args.work) / "live-frame.mkv", np.stack([image, background] * 8), fps=30.0)
    with OpenCVCamera(video, gelslim(scale=0.5)) as camera:
        reads = []
        for _ in range(16):
            start = time.perf_counter()
            camera.read()
            reads.append(time.perf_counter() - start)
    parts["camera read"] = {"median_ms": 1e3 * float(np.median(reads[1:])),
                            "p90_ms": 1e3 * float(np.percentile(reads[1:], 90))}

    result = {"object": tactile_map.object_id, "map_imprints": len(tactile_map), "test": str(test),
              "repeats": repeats, "frame_program_kernels": kernel_count(program), "parts": parts,
              "machine": machine_info()}
    print(format_table(["part", "median (ms)", "p90 (ms)"],
                       [[name, f"{t['median_ms']:.3f}", f"{t['p90_ms']:.3f}"] for name, t in parts.items()]))
    print(f"the frame program launches {result['frame_program_kernels']} kernels (a loop counts once); "
          f"{jax.devices()[0].device_kind}")
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
