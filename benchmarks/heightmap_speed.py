"""Speed of ``tactojax.shape.predict`` with the ``fast`` model, stage by stage (issue 17).

Issue 17 asks for the whole touch at camera rate; at 120 x 160 px the image -> heightmap step
took about 11.5 ms on 2 CPU cores for some 68 M multiply-adds, far from what the CPU can do.
This script times every stage of ``predict`` as it is computed now and as it was computed
before (the replaced formulation, written out below as the reference), in the same process and
interleaved call by call, so that the ratio means something on a busy machine:

=============  ===========================================  ==================================
stage          now                                          before (reference)
=============  ===========================================  ==================================
input          colour change + pixel coordinates            same
patches        two three-way stacks of shifted planes       ``conv_general_dilated_patches``
slope MLP      4 dense layers, channels first (9C, H*W)     4 ``nn.Dense``, channels last
integration    Poisson solve, DCT as 4 matrix products      ``jax.scipy.fft.dctn``/``idctn``
background     quantile by selection (bisection on keys)    ``jnp.quantile`` (a sort)
mask + clamp   contact logit > 0, height >= 0               same
predict        the whole jitted ``predict``                 the stages above in one jit
=============  ===========================================  ==================================

A third formulation, "now + bias", is ``predict`` given the model's ``coordinate_bias``,
computed once as the live ``Localizer`` does: only the colour change is patched (27 rows instead
of 45), and the first layer's bias and pixel x/y part is that per-pixel constant.

Each stage is jitted on its own (its input is the previous stage's output); "predict" is the
whole pipeline in one program, which is what a user calls. Reported per stage: compile time
(``lower().compile()``), steady-state median and 10th percentile of ``--repeats`` calls (after
one warm call, each ending in ``block_until_ready``), and the number of kernels the compiled
program launches (``tactojax.kernel_count``). Also the largest difference of the
heightmaps and the mask agreement between the two formulations.

Sizes: 120 x 160 px at 0.2 mm/px (``gelslim(scale=0.5)``, the bundled checkpoint
``fast-gelslim-0.5``), and the full GelSlim 240 x 320 px at 0.1 mm/px. There is no checkpoint
trained at 240 x 320: that size runs the same architecture with the bundled weights (timing
only; its heightmaps mean nothing). The input is a rendered sphere press with sensor noise.

Run from the repository root:

    python benchmarks/heightmap_speed.py --json results/heightmap_speed.json
    python benchmarks/heightmap_speed.py --quick      # smoke run: 20 repeats
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from typing import Any, Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.fft import dctn, idctn

try:
    from benchmarks._common import DEFAULT_MODEL, add_common_arguments, format_table, machine_info, write_json
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import DEFAULT_MODEL, add_common_arguments, format_table, machine_info, write_json

from tactojax import kernel_count
from tactojax.io import resolve_shape_model
from tactojax.sensor import add_sensor_noise, gelslim, render_image
from tactojax.shape import (MASK_SHARPNESS_MM, build_network, coordinate_bias, integrate_gradient, network_input,
                            patch_planes, predict, zero_background)

BUNDLED = DEFAULT_MODEL
FORMULATIONS = ("before", "now", "now + bias")
"""The replaced formulation (reference), ``predict``, and ``predict`` with the model's
``coordinate_bias`` computed once (the live ``Localizer``'s path)."""
STAGES = ["input", "patches", "slope MLP", "integration", "background", "mask + clamp", "predict"]


# --- the formulation that predict replaced (the reference) --------------------------------------

def old_patches(inputs):
    return jax.lax.conv_general_dilated_patches(
        inputs[None], (3, 3), (1, 1), "SAME", dimension_numbers=("NHWC", "OIHW", "NHWC"))[0]


def old_slope_mlp(slope_params, patches):
    hidden = patches
    for index in range(4):
        layer = slope_params[f"Dense_{index}"]
        hidden = nn.Dense(layer["bias"].shape[0]).apply({"params": layer}, hidden)
        hidden = nn.relu(hidden) if index < 3 else hidden
    return hidden


def old_integrate(slope, mm_per_px):
    height_px, width_px = slope.shape[:2]
    step_x = 0.5 * (slope[:, 1:, 0] + slope[:, :-1, 0]) * mm_per_px
    step_y = 0.5 * (slope[1:, :, 1] + slope[:-1, :, 1]) * mm_per_px
    rhs = (jnp.pad(step_x, ((0, 0), (1, 0))) - jnp.pad(step_x, ((0, 0), (0, 1)))
           + jnp.pad(step_y, ((1, 0), (0, 0))) - jnp.pad(step_y, ((0, 1), (0, 0))))
    eig_x = 4.0 * jnp.sin(jnp.pi * jnp.arange(width_px) / (2 * width_px)) ** 2
    eig_y = 4.0 * jnp.sin(jnp.pi * jnp.arange(height_px) / (2 * height_px)) ** 2
    eigenvalues = eig_y[:, None] + eig_x[None, :]
    coefficients = dctn(rhs, type=2, norm="ortho")
    coefficients = jnp.where(eigenvalues > 0, coefficients / jnp.where(eigenvalues > 0, eigenvalues, 1.0), 0.0)
    return idctn(coefficients, type=2, norm="ortho")


def old_background(heightmap, quantile):
    return heightmap - jnp.quantile(heightmap, quantile)


# --- the stages, now and before -----------------------------------------------------------------

def mask_and_clamp(heightmap, threshold_mm):
    return jnp.maximum(heightmap, 0.0), (heightmap - threshold_mm) / MASK_SHARPNESS_MM > 0.0


def stage_functions(model, formulation: str) -> list[tuple[str, Callable]]:
    """(stage, function of (model, the previous stage's output)) in pipeline order, then the
    whole. The model is an argument, as in ``predict``, so its weights are not constants."""
    network = build_network(model.preset, model.mm_per_px)
    quantile, mm_per_px = network.background_quantile, model.mm_per_px
    height_px, width_px = model.image_shape

    def inputs(model, image):
        return network_input(image, model.background, model.preset, model.color_gain)

    def clamp(model, heightmap):
        return mask_and_clamp(heightmap, model.params["mask_threshold_mm"])

    if formulation in ("now", "now + bias"):
        # "now + bias": the x/y channels' part of the first layer computed once per model, as
        # the Localizer does; the input is then the colour change alone.
        bias = coordinate_bias(model) if formulation == "now + bias" else None
        if bias is not None:
            def inputs(model, image):
                return model.color_gain * (image - model.background)

        def patches(model, x):
            return patch_planes(jnp.moveaxis(x, -1, 0)).reshape(-1, height_px * width_px)

        def slope(model, p):
            planes = network.apply({"params": model.params}, p, method=lambda net, p: net.slope_net(
                p, channels_first=True, coordinate_bias=bias))
            return jnp.moveaxis(planes.reshape(2, height_px, width_px), 0, -1)

        def integrate(model, s):
            return integrate_gradient(s, mm_per_px)

        def background(model, h):
            return zero_background(h, quantile=quantile)

        def whole(model, image):
            return predict(model, image, bias)
    else:
        def patches(model, x):
            return old_patches(x)

        def slope(model, p):
            return old_slope_mlp(model.params["slope_net"], p)

        def integrate(model, s):
            return old_integrate(s, mm_per_px)

        def background(model, h):
            return old_background(h, quantile)

        def whole(model, image):
            stages = (inputs, patches, slope, integrate, background, clamp)
            value = image
            for stage in stages:
                value = stage(model, value)
            return value

    return [("input", inputs), ("patches", patches), ("slope MLP", slope), ("integration", integrate),
            ("background", background), ("mask + clamp", clamp), ("predict", whole)]


def compile_stages(model, image, formulation: str) -> dict[str, dict[str, Any]]:
    """Every stage compiled on the previous stage's real output: compiled program, argument,
    compile time and kernel count."""
    stages, value = {}, image
    for name, function in stage_functions(model, formulation):
        argument = image if name == "predict" else value
        start = time.perf_counter()
        compiled = jax.jit(function).lower(model, argument).compile()
        compile_s = time.perf_counter() - start
        output = jax.block_until_ready(compiled(model, argument))
        stages[name] = {"compiled": compiled, "model": model, "argument": argument, "compile_s": compile_s,
                        "kernels": kernel_count(compiled), "output": output}
        if name != "predict":
            value = output
    return stages


def time_interleaved(programs: dict[str, dict[str, Any]], repeats: int) -> dict[str, dict[str, float]]:
    """Steady-state times of several compiled programs, called in turn ``repeats`` times (so
    that a burst of load on the machine hits them all alike). Milliseconds."""
    times = {key: [] for key in programs}
    for _ in range(repeats):
        for key, program in programs.items():
            start = time.perf_counter()
            jax.block_until_ready(program["compiled"](program["model"], program["argument"]))
            times[key].append(time.perf_counter() - start)
    return {key: {"median_ms": 1e3 * statistics.median(values),
                  "p10_ms": 1e3 * float(np.percentile(values, 10)),
                  "min_ms": 1e3 * min(values)} for key, values in times.items()}


# --- inputs -------------------------------------------------------------------------------------

def model_and_image(scale: float, seed: int = 0):
    """The bundled ``fast`` model at ``gelslim(scale)``'s size and pitch, a sphere press, and
    whether the weights were trained at that size."""
    model = resolve_shape_model(BUNDLED)
    spec = gelslim(scale=scale)
    trained = spec.shape == model.image_shape and spec.mm_per_px == model.mm_per_px
    if not trained:  # same weights, another size: timing only
        model = model.replace(background=jnp.asarray(spec.optics.background, jnp.float32),
                              mm_per_px=spec.mm_per_px, sensor=f"gelslim x{scale} (bundled weights)")
    rows, cols = np.mgrid[:spec.height_px, :spec.width_px] * spec.mm_per_px
    centre, radius = np.array([rows.max(), cols.max()]) * 0.5, 4.0
    depth = np.maximum(1.0 - ((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2) / radius**2, 0.0)
    image = add_sensor_noise(jax.random.key(seed), spec, render_image(spec, jnp.asarray(depth, jnp.float32)))
    return model, image, trained


def bench_size(scale: float, repeats: int, seed: int = 0) -> dict[str, Any]:
    """The formulations at one sensor size: per-stage timings, kernels, compile, agreement."""
    model, image, trained = model_and_image(scale, seed)
    stages = {f: compile_stages(model, image, f) for f in FORMULATIONS}
    programs = {(f, name): stage for f, by_name in stages.items() for name, stage in by_name.items()}
    timings = time_interleaved(programs, repeats)
    old_height, old_mask = stages["before"]["predict"]["output"]
    rows = {name: {f: {"compile_s": stages[f][name]["compile_s"], "kernels": stages[f][name]["kernels"],
                       **timings[(f, name)]} for f in FORMULATIONS} for name in STAGES}
    agreement = {}
    for f in FORMULATIONS[1:]:
        new_height, new_mask = stages[f]["predict"]["output"]
        agreement[f] = {"max_abs_height_difference_mm": float(jnp.max(jnp.abs(new_height - old_height))),
                        "mask_agreement": float(jnp.mean(new_mask == old_mask))}
    return {
        "image": list(model.image_shape), "mm_per_px": model.mm_per_px, "sensor": model.sensor,
        "trained_at_this_size": trained,
        "stages": rows,
        "max_height_mm": float(jnp.max(old_height)),
        "against_before": agreement,
    }


def print_size(result: dict[str, Any]) -> None:
    height_px, width_px = result["image"]
    note = "" if result["trained_at_this_size"] else " (bundled weights, no checkpoint trained at this size)"
    print(f"\n{height_px} x {width_px} px, {result['mm_per_px']} mm/px{note}")
    rows = []
    for name, row in result["stages"].items():
        rows.append([name, *(row[f]["median_ms"] for f in FORMULATIONS), *(row[f]["p10_ms"] for f in FORMULATIONS),
                     *(row[f]["kernels"] for f in FORMULATIONS),
                     row["before"]["median_ms"] / row["now"]["median_ms"],
                     row["now"]["median_ms"] / row["now + bias"]["median_ms"]])
    print(format_table(["stage", *(f"ms {f}" for f in FORMULATIONS), *(f"p10 {f}" for f in FORMULATIONS),
                        *(f"kernels {f}" for f in FORMULATIONS), "now / before", "+ bias / now"], rows))
    for f, agreement in result["against_before"].items():
        print(f"{f}: heightmaps differ from before by at most {agreement['max_abs_height_difference_mm']:.2e} mm "
              f"(max height {result['max_height_mm']:.3f} mm); masks agree on "
              f"{100 * agreement['mask_agreement']:.3f} % of pixels")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scales", type=float, nargs="+", default=[0.5, 1.0],
                        help="gelslim resolution factors (0.5: 120 x 160, 1.0: 240 x 320)")
    add_common_arguments(parser, quick="20 repeats", seed_help="the sensor noise of the input image", repeats=300,
                         repeats_help="steady-state calls per program")
    args = parser.parse_args(argv)
    repeats = 20 if args.quick else args.repeats
    results: dict[str, Any] = {"machine": machine_info(), "settings": {**vars(args), "repeats": repeats},
                               "load_average_before": os.getloadavg(), "sizes": []}
    for scale in args.scales:
        results["sizes"].append(bench_size(scale, repeats, args.seed))
        print_size(results["sizes"][-1])
    results["load_average_after"] = os.getloadavg()
    print(f"\nload average (1, 5, 15 min) before {results['load_average_before']}, "
          f"after {results['load_average_after']} on {results['machine']['usable_cpus']} usable CPUs")
    if args.json:
        write_json(args.json, results)
        print(f"wrote {args.json}")
    return results


if __name__ == "__main__":
    main()
