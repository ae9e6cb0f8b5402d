"""Rendering speed: optical rendering vs Taxim, contact rendering of grasps, the mapping protocol.

What is measured (all in one process, so that ratios are meaningful on a noisy machine):

1. Optical rendering at 480 x 640 (``tactojax.sensor.gelsight()``, the real GelSight
   calibration), images/s for a batch of ball presses (radius 2-4 mm, depth 0.5-1 mm):
   * ours, ``render_image`` (jit + vmap) on the gel heightmap (indentation, mm, >= 0);
   * ours, ``gel_surface`` + ``render_image`` from the rigid indentation: this includes the
     gel deformation step, like Taxim's render, and is the row compared with Taxim;
   * Taxim JAX backend (``taxim.Taxim(backend="jax")``) on the equivalent object height map
     (the ball's surface height above the gel top, mm: negative where it presses), with
     ``with_shadow=False`` (the comparable model) and ``with_shadow=True`` (reference).
   The ratio ours/Taxim of images/s is printed (the stated target is >= 1; not asserted).
2. Contact rendering of grasps of the YCB scissors with the default GelSlim sensor: grasps/s
   of ``simulate_grasps`` over batches of top-down grasps (ray casting + contact + image).
3. The full mapping protocol on the scissors (``tactojax.simulate.simulate_protocol``), one
   run, wall time (target: under 5 minutes on 2 cores). Skipped with ``--skip-protocol``.

Every row reports the first call (tracing + compilation + one run) apart from the steady-state
median of ``--repeats`` further calls. Run from the repository root:

    python benchmarks/render.py                       # full run
    python benchmarks/render.py --quick               # CI smoke: 3 repeats, batch 4, no protocol
    python benchmarks/render.py --json results/render.json --repeats 20 --batch 16
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

import tactojax
from tactojax.objects import get_object
from tactojax.sensor import gel_surface, gelsight, gelslim, render_image
from tactojax.simulate import simulate_grasps

try:
    from benchmarks._common import add_common_arguments, format_table, machine_info, time_call, write_json
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import add_common_arguments, format_table, machine_info, time_call, write_json


def ball_presses(spec, batch: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rigid indentations (B, H, W) and the matching Taxim object height maps, mm.

    Ball of radius R pressed by ``depth`` at (cx, cy): object surface height above the gel top
    is ``R - sqrt(R^2 - r^2) - depth`` (negative where it presses); the rigid indentation is
    its negative part. Outside the ball's footprint the height is clipped to R - depth.
    """
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[: spec.height_px, : spec.width_px].astype(np.float64)
    x = (cols - (spec.width_px - 1) / 2) * spec.mm_per_px
    y = (rows - (spec.height_px - 1) / 2) * spec.mm_per_px
    rigid, taxim_heights = [], []
    for _ in range(batch):
        radius, depth = rng.uniform(2.0, 4.0), rng.uniform(0.5, 1.0)
        cx, cy = rng.uniform(-3.0, 3.0), rng.uniform(-2.0, 2.0)
        r2 = (x - cx) ** 2 + (y - cy) ** 2
        height = radius - np.sqrt(np.maximum(radius**2 - r2, 0.0)) - depth
        taxim_heights.append(height)
        rigid.append(np.maximum(-height, 0.0))
    return np.asarray(rigid, np.float32), np.asarray(taxim_heights, np.float32)


def bench_optical(batch: int, repeats: int, seed: int = 0) -> list[dict[str, Any]]:
    """Section 1: images/s of ours vs Taxim JAX at 480 x 640 on the same ball presses."""
    import taxim

    spec = gelsight(noise_std=0.0)
    rigid, taxim_heights = ball_presses(spec, batch, seed)
    rigid, taxim_heights = jnp.asarray(rigid), jnp.asarray(taxim_heights)
    render_only = jax.jit(jax.vmap(render_image, in_axes=(None, 0)))
    with_gel = jax.jit(jax.vmap(lambda s, h: render_image(s, gel_surface(s, h)), in_axes=(None, 0)))
    gel_heightmaps = jax.block_until_ready(jax.jit(jax.vmap(gel_surface, in_axes=(None, 0)))(spec, rigid))
    simulator = taxim.Taxim(backend="jax")
    cases = [
        ("ours: render_image", lambda: render_only(spec, gel_heightmaps)),
        ("ours: gel_surface + render_image", lambda: with_gel(spec, rigid)),
        ("taxim jax, no shadow", lambda: simulator.render(taxim_heights, with_shadow=False)),
        ("taxim jax, with shadow", lambda: simulator.render(taxim_heights, with_shadow=True)),
    ]
    rows = []
    for name, fn in cases:
        timing = time_call(fn, repeats=repeats)
        rows.append({"name": name, "unit": "images/s", "batch": batch,
                     "throughput": batch / timing["median_s"], **timing})
        print(f"  {name}: {rows[-1]['throughput']:.1f} images/s", flush=True)
    return rows


def top_down_grasps(count: int, seed: int = 0) -> jaxlie.SE3:
    """(count,) top-down grasps of the mounted scissors: z = world -z, closing axis y = world -y."""
    rng = np.random.default_rng(seed)
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # columns x, y, z
    positions = np.stack([rng.uniform(-80, 80, count), np.zeros(count), rng.uniform(-30, 30, count)], -1)
    rotations = jaxlie.SO3.from_matrix(jnp.broadcast_to(jnp.asarray(rotation, jnp.float32), (count, 3, 3)))
    return jaxlie.SE3.from_rotation_and_translation(rotations, jnp.asarray(positions, jnp.float32))


def bench_grasps(batch: int, repeats: int, seed: int = 0) -> dict[str, Any]:
    """Section 2: grasps/s of simulate_grasps on the YCB scissors with the GelSlim sensor."""
    spec, obj = gelslim(), get_object("scissors")
    T_world_object = jaxlie.SE3.identity()
    T_world_gripper = top_down_grasps(batch, seed)
    key = jax.random.key(seed)
    fn = lambda: simulate_grasps(key, spec, obj, T_world_object, T_world_gripper)  # noqa: E731
    timing = time_call(fn, repeats=repeats)
    valid = float(jnp.mean(fn().valid))
    print(f"  grasps: {batch / timing['median_s']:.1f} grasps/s (valid {valid:.0%})", flush=True)
    return {"name": f"grasps: scissors, {spec.name} {spec.height_px}x{spec.width_px}",
            "unit": "grasps/s", "batch": batch, "throughput": batch / timing["median_s"],
            "valid_fraction": valid, **timing}


def bench_protocol(seed: int = 0) -> dict[str, Any]:
    """Section 3: wall time of one full simulated mapping protocol on the scissors."""
    name = "protocol: scissors, full mapping"
    try:
        from tactojax.simulate import MappingProtocol, mapping_plan, simulate_protocol
    except ImportError:
        return {"name": name, "unit": "s", "note": "not available: tactojax.simulate.simulate_protocol"}
    spec, obj, protocol = gelslim(), get_object("scissors"), MappingProtocol()
    planned = len(mapping_plan(obj, protocol))
    start = time.perf_counter()
    batches = list(simulate_protocol(jax.random.key(seed), spec, obj, protocol, progress=False))
    wall = time.perf_counter() - start
    kept = sum(len(batch["opening_mm"]) for batch in batches)
    print(f"  protocol: {wall:.1f} s for {planned} grasps ({kept} imprints kept)", flush=True)
    return {"name": name, "unit": "grasps/s", "batch": planned, "first_call_s": wall,
            "throughput": planned / wall, "grasps_planned": planned, "imprints_kept": kept,
            "target_s": 300.0, "note": "one run incl. compilation; target < 300 s on 2 cores"}


def print_results(optical: list[dict[str, Any]], grasps: dict[str, Any], protocol: dict[str, Any] | None) -> None:
    headers = ["benchmark", "batch", "first call s", "compile s", "median s", "throughput", "unit"]
    rows = [[r["name"], r.get("batch"), r.get("first_call_s"), r.get("compile_s"), r.get("median_s"),
             r.get("throughput"), r["unit"]] for r in [*optical, grasps]]
    if protocol is not None:
        rows.append([protocol["name"], protocol.get("batch"), protocol.get("first_call_s"), None, None,
                     protocol.get("throughput"), protocol["unit"]])
    print()
    print(format_table(headers, rows))
    if protocol is not None:
        print(f"protocol: {protocol['note']}")
    print()
    by_name = {r["name"]: r["throughput"] for r in optical}
    for ours in ("ours: render_image", "ours: gel_surface + render_image"):
        for ref in ("taxim jax, no shadow", "taxim jax, with shadow"):
            print(f"ratio  {ours} / {ref}: {by_name[ours] / by_name[ref]:.2f}x")
    print("(target: ours >= taxim without shadow, i.e. ratio >= 1; not asserted)")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=8, help="images per optical rendering batch")
    parser.add_argument("--grasp-batch", type=int, default=16, help="grasps per simulate_grasps call")
    parser.add_argument("--skip-protocol", action="store_true", help="skip the mapping protocol row")
    add_common_arguments(parser, quick="3 repeats, batch 4, no protocol", seed_help="ball presses, grasps and keys",
                         repeats=10, repeats_help="steady-state calls per row")
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.batch < 1 or args.grasp_batch < 1:
        parser.error("--repeats, --batch and --grasp-batch must be positive")
    if args.quick:
        args.repeats, args.batch = min(args.repeats, 3), min(args.batch, 4)
        args.skip_protocol = True

    info = {**machine_info(), "tactojax_version": tactojax.__version__}
    print(f"{info['processor']}, {info['usable_cpus']} usable CPUs, jax {info['jax_version']} "
          f"({info['jax_backend']}), repeats {args.repeats}", flush=True)
    optical = bench_optical(args.batch, args.repeats, args.seed)
    grasps = bench_grasps(args.grasp_batch, args.repeats, args.seed)
    protocol = None if args.skip_protocol else bench_protocol(args.seed)
    print_results(optical, grasps, protocol)

    by_name = {r["name"]: r["throughput"] for r in optical}
    results = {
        "benchmark": "render", "machine": info,
        "settings": {"repeats": args.repeats, "batch": args.batch, "grasp_batch": args.grasp_batch,
                     "quick": args.quick, "seed": args.seed},
        "optical": optical, "grasps": grasps,
        "protocol": protocol if protocol is not None else {"note": "skipped"},
        "ratio_gel_surface_render_over_taxim_no_shadow": by_name["ours: gel_surface + render_image"]
        / by_name["taxim jax, no shadow"],
        "ratio_render_image_over_taxim_no_shadow": by_name["ours: render_image"]
        / by_name["taxim jax, no shadow"],
    }
    if args.json:
        write_json(args.json, results)
        print(f"wrote {args.json}")
    return results


if __name__ == "__main__":
    main()
