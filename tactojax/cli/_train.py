"""``tactojax train DATA... --out MODEL``: train an image -> heightmap model (paper section IV)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from tactojax.cli._shape_report import print_shape_report
from tactojax.cli._table import write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "train", help="train an image -> heightmap model on calibration datasets",
        description="Train a local-shape model (paper section IV) on simulated or recorded "
                    "(image, heightmap) pairs. The last --test-per-object pairs of every object "
                    "are held out and evaluated at the end. Interrupted runs resume from "
                    "MODEL.train-state.")
    parser.add_argument("data", nargs="+", help="dataset directories (same sensor)")
    parser.add_argument("--out", required=True, help="model checkpoint to write (.msgpack)")
    parser.add_argument("--preset", default="fast", choices=["paper", "fast", "tiny", "lookup"],
                        help="architecture (lookup: the classical table, no learning)")
    parser.add_argument("--pairs", type=int, help="training pairs, balanced over objects (default all)")
    parser.add_argument("--exclude-object", action="append", default=[], metavar="NAME",
                        help="leave this object out of training (Table I); repeatable")
    parser.add_argument("--test-per-object", type=int, default=100,
                        help="pairs per object held out for testing (paper: 100 of 600)")
    defaults = _default_config()
    parser.add_argument("--steps", type=int, default=defaults.steps, help="whole-image steps")
    parser.add_argument("--pixel-steps", type=int, default=defaults.pixel_steps,
                        help="slope-only steps before them (fast/tiny)")
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size)
    parser.add_argument("--learning-rate", type=float, default=defaults.learning_rate)
    parser.add_argument("--crop-px", type=int, default=defaults.crop_px,
                        help="paper preset: train on random crops of this size (0: whole images)")
    parser.add_argument("--no-augment", action="store_true", help="no colour augmentation")
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--restart", action="store_true", help="ignore a saved training state")
    parser.add_argument("--json", metavar="PATH", help="write the test errors as JSON")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(run=run)


def _default_config():
    from tactojax.shape import TrainConfig

    return TrainConfig()


def run(args) -> int:
    import numpy as np

    from tactojax.io import (load_shape_data, load_train_state, save_shape_model,
                             save_train_state)
    from tactojax.shape import (TrainConfig, balanced_subset, evaluate_shape_model,
                                fit_lookup_model, split_held_out, train_shape_model)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = load_shape_data(args.data)
    unknown = sorted(set(args.exclude_object) - set(data.objects))
    if unknown:
        raise ValueError(f"--exclude-object {unknown}: not in the data ({data.objects})")
    train, test = split_held_out(data, args.test_per_object) if args.test_per_object else (data, None)
    if args.exclude_object:
        train = train.take(~np.isin(train.object_ids, args.exclude_object))
    if args.pairs:
        train = balanced_subset(train, args.pairs)
    print(f"training {args.preset} on {len(train)} pairs ({', '.join(train.objects)}), "
          f"{data.images.shape[1]}x{data.images.shape[2]} px at {data.mm_per_px} mm/px")
    config = TrainConfig(steps=args.steps, pixel_steps=args.pixel_steps, batch_size=args.batch_size,
                         learning_rate=args.learning_rate, augment=not args.no_augment, crop_px=args.crop_px,
                         seed=args.seed)
    started = time.perf_counter()
    if args.preset == "lookup":
        model = fit_lookup_model(train, seed=args.seed)
    else:
        state_path = out.with_name(out.name + ".train-state")
        state = None
        if state_path.exists() and not args.restart:
            state = load_train_state(state_path, config)
            print(f"resuming from step {int(state.step)} ({state_path})")
        state = train_shape_model(args.preset, train, config, state=state, progress=not args.no_progress,
                                  on_checkpoint=lambda s: save_train_state(state_path, s, config))
        model = state.model
    seconds = time.perf_counter() - started
    report = {"preset": args.preset, "data": [str(p) for p in args.data], "pairs": len(train),
              "objects": train.objects, "excluded": args.exclude_object,
              "config": dataclasses.asdict(config), "train_seconds": round(seconds, 1)}
    if test is not None:
        errors = evaluate_shape_model(model, test)
        report["test"] = print_shape_report(errors, test.object_ids,
                                            title=f"held-out test pairs ({len(test)})")
    save_shape_model(out, model, metadata=report)
    if args.preset != "lookup":
        state_path.unlink(missing_ok=True)  # the run is complete; the model holds the result
    print(f"wrote {out} after {seconds:.0f} s of training")
    if args.json:
        write_json(args.json, report)
    return 0
