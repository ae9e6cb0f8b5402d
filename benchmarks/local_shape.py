"""Local shape (paper section IV): Table I, the learning curve, the classical baseline, speed.

What is measured, on simulated calibration data (the 5 calibration shapes, 600 touches each,
the last 100 of every shape held out for testing, as in the paper):

1. Table I: a model trained on 2000 pairs of all shapes, then one per shape trained on 2000
   pairs of the other four; contact-patch RMSE (mm) on every shape's test pairs ("all") and on
   the removed shape ("removed"). The ``fast`` network and the classical ``lookup`` baseline
   (colour -> slope table + Poisson, no learning) side by side. Paper: 0.062-0.077 (all),
   0.073-0.167 (removed).
2. Learning curve: 500 / 1000 / 2000 training pairs. Paper: ~0.1 mm at 500, 0.060 at 2000.
3. Time to train ``fast`` to 0.06 mm on 100 test pairs (wall time of training only).
4. Robustness: unseen lighting and extra noise (``tactojax.shape.robustness_study``), and the
   same training on another sensor preset (``--other-sensor``, the real GelSight optics).
5. The ``paper`` preset (10 x 64 x 3x3) trained with ``--paper-steps`` on random crops, for the
   accuracy comparison; expensive on CPU (about 3 s a step on 2 cores). Or pass a checkpoint
   trained apart (``--paper-model``, e.g. from ``tactojax train DATA --preset paper --crop-px 40
   --pairs 2000``, which holds out the same last 100 touches of every shape).
6. Speed: images/s of ``predict`` for every preset at the full sensor resolution, batch 1 and
   batch 16, compile time apart, and multiply-adds per pixel. The ``fast`` model stage by
   stage, against the formulation it replaced: ``benchmarks/heightmap_speed.py``.

Run from the repository root (data is simulated into --work once and reused):

    python benchmarks/local_shape.py --json results/local_shape.json
    python benchmarks/local_shape.py --quick          # smoke run: small data, few steps
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

try:
    from benchmarks._common import add_common_arguments, format_table, machine_info, time_call, write_json
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import add_common_arguments, format_table, machine_info, time_call, write_json

from tactojax.io import load_shape_data, load_shape_model, shape_model_metadata
from tactojax.objects import CALIBRATION_SHAPES, get_object
from tactojax.sensor import sensor_preset
from tactojax.shape import (TrainConfig, balanced_subset, build_network, evaluate_shape_model,
                            fit_lookup_model, flops_per_pixel, init_shape_model, predict_batch,
                            robustness_study, split_held_out, summarize_errors, train_shape_model)
from tactojax.simulate import CalibrationProtocol, simulate_to_dataset


def simulate_calibration(work: Path, sensor: str, scale: float, touches: int, seed: int = 0) -> Path:
    """The calibration protocol on the 5 shapes, simulated once into ``work`` (shape ``i`` with
    key ``seed * 5 + i``)."""
    path = work / (f"calibration-{sensor}-{scale}-{touches}" + ("" if seed == 0 else f"-seed{seed}"))
    if (path / "manifest.json").exists():
        return path
    spec = sensor_preset(sensor, scale=scale)
    for index, name in enumerate(CALIBRATION_SHAPES):
        simulate_to_dataset(path, jax.random.key(seed * len(CALIBRATION_SHAPES) + index), spec, get_object(name),
                            CalibrationProtocol(touches=touches))
    return path


def patch_rmse(model, test) -> dict:
    """Mean contact-patch RMSE per object and over all test pairs."""
    summary = summarize_errors(evaluate_shape_model(model, test), test.object_ids)
    return {name: row["patch_rmse"] for name, row in summary.items()} | {
        "mask_iou": summary["all"]["mask_iou"]}


def fit(method: str, train, config: TrainConfig, on_checkpoint=None):
    start = time.perf_counter()
    if method == "lookup":
        model = fit_lookup_model(train)
    else:
        model = train_shape_model(method, train, config, on_checkpoint=on_checkpoint).model
    return model, time.perf_counter() - start


def table_one(train, test, methods, configs, pairs, full_models) -> dict:
    """Paper Table I: all shapes (``full_models``, already trained), then each shape removed."""
    results = {}
    for method in methods:
        rows = {"none removed": {"all": patch_rmse(full_models[method], test)}}
        for shape in train.objects:
            kept = train.take(train.object_ids != shape)
            model, seconds = fit(method, balanced_subset(kept, min(pairs, len(kept))), configs[method])
            errors = patch_rmse(model, test)
            rows[shape] = {"all": errors["all"], "removed": errors[shape], "train_s": seconds}
        results[method] = rows
    return results


def learning_curve(train, test, methods, configs, sizes, full_models) -> dict:
    """Test RMSE against the number of training pairs; the largest size is ``full_models``."""
    return {method: {size: patch_rmse(full_models[method] if size == max(sizes) else
                                      fit(method, balanced_subset(train, size), configs[method])[0], test)["all"]
                     for size in sizes if size <= len(train)} for method in methods}


def train_with_trace(train, test, config: TrainConfig, target_mm: float, every: int):
    """Train ``fast``, recording the wall time of training (evaluations excluded) until the
    RMSE on a 100-pair probe of the test set first reaches ``target_mm``. Returns (model, record)."""
    probe = test.take(np.arange(0, len(test), max(1, len(test) // 100)))
    record = {"target_mm": target_mm, "reached_at_s": None, "trace": []}
    clock = {"training": 0.0, "last": time.perf_counter()}

    def on_checkpoint(state):
        clock["training"] += time.perf_counter() - clock["last"]
        rmse = float(np.nanmean(evaluate_shape_model(state.model, probe)["patch_rmse"]))
        record["trace"].append({"step": int(state.step), "train_s": round(clock["training"], 1),
                                "patch_rmse": rmse})
        if rmse <= target_mm and record["reached_at_s"] is None:
            record["reached_at_s"] = round(clock["training"], 1)
            record["reached_at_step"] = int(state.step)
        clock["last"] = time.perf_counter()

    config = TrainConfig(**{**config.__dict__, "checkpoint_every": every})
    model = train_shape_model("fast", train, config, on_checkpoint=on_checkpoint).model
    return model, record


def speed(sensor: str, repeats: int) -> list[dict]:
    """images/s of ``predict`` for every preset at the sensor's full resolution."""
    spec = sensor_preset(sensor)
    background = np.asarray(spec.optics.background, np.float32)
    images = np.repeat(background[None], 16, axis=0)
    rows = []
    for preset in ("paper", "fast", "tiny", "lookup"):
        if preset == "lookup":
            params = {"table": np.zeros((24, 24, 24, 2), np.float32), "color_range": np.float32(0.4),
                      "mask_threshold_mm": np.float32(0.1)}
            from tactojax.shape import ShapeModel
            model = ShapeModel(params=params, background=background, preset="lookup",
                               mm_per_px=spec.mm_per_px, sensor=sensor)
            flops = None
        else:
            model = init_shape_model(jax.random.key(0), preset, background, spec.mm_per_px)
            flops = flops_per_pixel(build_network(preset, spec.mm_per_px))
        row = {"preset": preset, "multiply_adds_per_px": flops}
        for batch in (1, 16):
            timing = time_call(predict_batch, model, images[:batch], repeats=repeats)
            row[f"batch{batch}_images_per_s"] = batch / timing["median_s"]
            row[f"batch{batch}_compile_s"] = timing["compile_s"]
        rows.append(row)
    return rows


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", default="benchmark-data/local_shape", help="simulated data cache")
    parser.add_argument("--scale", type=float, default=0.5, help="gelslim resolution factor for training")
    parser.add_argument("--touches", type=int, default=600)
    parser.add_argument("--pairs", type=int, default=2000)
    parser.add_argument("--other-sensor", default="gelsight", help="second sensor preset ('' to skip)")
    parser.add_argument("--other-scale", type=float, default=0.25)
    parser.add_argument("--paper-steps", type=int, default=0, help="train the paper preset (slow on CPU)")
    parser.add_argument("--paper-model", metavar="PATH", help="evaluate this trained paper checkpoint instead")
    parser.add_argument("--skip-table", action="store_true", help="skip Table I and the learning curve")
    add_common_arguments(parser, quick="60 touches, short training", seed_help="simulated calibration data",
                         repeats=10, repeats_help="steady-state calls per speed row")
    args = parser.parse_args()
    if args.quick:
        args.touches, args.pairs, args.repeats, args.scale, args.other_scale = 60, 100, 3, 0.25, 0.125
    return args


def table_and_curve(args, results: dict, train, test, configs: dict, full_models: dict, save) -> None:
    """Table I and the learning curve, printed and kept in ``results``."""
    shapes = train.objects
    results["table1"] = table_one(train, test, ["fast", "lookup"], configs, args.pairs, full_models)
    print("\nTable I: contact-patch RMSE (mm) of models trained without one shape (paper: all "
          "0.062-0.077, removed 0.073-0.167)")
    rows = []
    for method, table in results["table1"].items():
        rows.append([f"{method} all (none removed)", *[table["none removed"]["all"][s] for s in shapes]])
        rows.append([f"{method} all", *[table[s]["all"] for s in shapes]])
        rows.append([f"{method} removed", *[table[s]["removed"] for s in shapes]])
    print(format_table(["model / test set", *shapes], rows))
    save()
    sizes = [args.pairs // 4, args.pairs // 2, args.pairs]
    results["learning_curve"] = learning_curve(train, test, ["fast", "lookup"], configs, sizes, full_models)
    print("\nLearning curve: contact-patch RMSE (mm), all test pairs (paper: ~0.1 at 500, 0.060 at 2000)")
    print(format_table(["pairs", *results["learning_curve"]],
                       [[size, *[results["learning_curve"][m].get(size) for m in results["learning_curve"]]]
                        for size in sizes]))
    save()


def paper_preset(args, results: dict, subset, test, fast_model) -> None:
    """The ``paper`` preset trained here (``--paper-steps``) or read (``--paper-model``), against ``fast``."""
    if args.paper_model:
        paper_model = load_shape_model(args.paper_model)
        metadata = shape_model_metadata(args.paper_model)
        training = {"checkpoint": args.paper_model, "steps": metadata["config"]["steps"],
                    "train_s": metadata.get("train_seconds"), "crop_px": metadata["config"]["crop_px"]}
    else:
        paper_model, seconds = fit("paper", subset, TrainConfig(steps=args.paper_steps, crop_px=40, batch_size=8))
        training = {"steps": args.paper_steps, "train_s": seconds, "crop_px": 40}
    results["paper_preset"] = {**training, "per_shape": patch_rmse(paper_model, test),
                               "robustness": robustness_study(paper_model, test)}
    results["robustness"]["paper"] = results["paper_preset"]["robustness"]
    columns = [*subset.objects, "all"]
    print("\npaper preset, trained on all shapes: contact-patch RMSE (mm)")
    print(format_table(["model", *columns], [["paper", *[results["paper_preset"]["per_shape"][s] for s in columns]],
                                             ["fast", *[patch_rmse(fast_model, test)[s] for s in columns]]]))


def other_sensor(args, results: dict, work: Path, test_per_object: int, configs: dict) -> None:
    """``fast`` and ``lookup`` trained and tested on ``--other-sensor``'s simulated data."""
    other = load_shape_data(simulate_calibration(work, args.other_sensor, args.other_scale, args.touches,
                                                 args.seed))
    other_train, other_test = split_held_out(other, test_per_object)
    other_train = balanced_subset(other_train, min(args.pairs, len(other_train)))
    results["other_sensor"] = {
        "sensor": args.other_sensor, "scale": args.other_scale,
        "image": list(other.images.shape[1:3]), "mm_per_px": other.mm_per_px,
        **{m: patch_rmse(fit(m, other_train, configs[m])[0], other_test) for m in ("fast", "lookup")}}
    print(f"\n{args.other_sensor} x{args.other_scale} ({other.mm_per_px:.3f} mm/px): contact-patch RMSE (mm)")
    print(format_table(["model", *other.objects, "all"],
                       [[m, *[results["other_sensor"][m][s] for s in [*other.objects, "all"]]]
                        for m in ("fast", "lookup")]))


def main() -> None:
    args = parse_args()
    config = TrainConfig() if not args.quick else TrainConfig(steps=10, pixel_steps=100)
    configs = {"fast": config, "lookup": None}
    work = Path(args.work)
    test_per_object = max(1, args.touches // 6)
    results: dict = {"machine": machine_info(), "settings": vars(args), "config": config.__dict__}

    def save():  # after every section, so an interrupted run keeps what it measured
        if args.json:
            write_json(args.json, results)

    data = load_shape_data(simulate_calibration(work, "gelslim", args.scale, args.touches, args.seed))
    train, test = split_held_out(data, test_per_object)
    print(f"gelslim x{args.scale}: {data.images.shape[1]}x{data.images.shape[2]} px, "
          f"{len(train)} train / {len(test)} test pairs")
    subset = balanced_subset(train, min(args.pairs, len(train)))
    fast_model, results["time_to_0.06mm"] = train_with_trace(subset, test, config, 0.06,
                                                             every=100 if not args.quick else 50)
    print(f"\nfast reaches 0.06 mm after {results['time_to_0.06mm']['reached_at_s']} s of training")
    lookup_model, _ = fit("lookup", subset, None)
    full_models = {"fast": fast_model, "lookup": lookup_model}
    save()
    if not args.skip_table:
        table_and_curve(args, results, train, test, configs, full_models, save)
    results["robustness"] = {"fast": robustness_study(fast_model, test), "lookup": robustness_study(lookup_model, test)}
    if args.paper_steps or args.paper_model:
        paper_preset(args, results, subset, test, fast_model)
    print("\nRobustness: contact-patch RMSE (mm) on all test pairs, conditions never seen in training")
    conditions = list(results["robustness"]["fast"])
    print(format_table(["model", *conditions],
                       [[m, *[r[c]["patch_rmse"] for c in conditions]] for m, r in results["robustness"].items()]))
    save()
    if args.other_sensor:
        other_sensor(args, results, work, test_per_object, configs)
    results["speed"] = speed("gelslim", args.repeats)
    print("\nSpeed of predict at the full gelslim resolution (240 x 320), compile time apart")
    print(format_table(["preset", "MACs/px", "images/s (1)", "images/s (16)", "compile s (16)"],
                       [[r["preset"], r["multiply_adds_per_px"], r["batch1_images_per_s"],
                         r["batch16_images_per_s"], r["batch16_compile_s"]] for r in results["speed"]]))
    if args.json:
        write_json(args.json, results)
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
