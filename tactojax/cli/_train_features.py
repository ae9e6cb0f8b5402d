"""``tactojax train-features DATA... --out ENCODER``: train a tactile feature encoder for CTI.

Positives are touches at nearby poses of the same object (contrastive, see
``tactojax.features.train_encoder``). A random ``--held-out`` fraction of every object's
touches is not trained on; at the end each of them is retrieved among all touches of its
object with an opening within 2 mm (the paper's CTI, section VI), and the table reports how
often the top-1 is a pose neighbour. ``--eval-data`` adds unseen objects, each touch queried
against all the others, beside a randomly initialised network and raw pixels.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "train-features", help="train a tactile feature encoder for imprint retrieval (CTI)",
        description="Contrastive training of a feature encoder on grasp datasets (poses known): "
                    "touches within --positive-mm and --positive-deg of each other on the same "
                    "object are positives. Reports retrieval by pose on held-out touches and, "
                    "with --eval-data, on unseen objects.")
    parser.add_argument("data", nargs="+", help="grasp datasets (mapping protocol) of training objects")
    parser.add_argument("--out", required=True, help="encoder checkpoint to write (.msgpack)")
    defaults = _default_config()
    parser.add_argument("--preset", default=defaults.preset,
                        help="architecture (plain_tactile, plain_tiny, resnet_tactile, resnet_tiny, resnet18)")
    parser.add_argument("--input-size", type=int, nargs=2, default=list(defaults.input_size), metavar=("H", "W"),
                        help="network input, pixels")
    parser.add_argument("--steps", type=int, default=defaults.steps)
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size, help="anchors per step")
    parser.add_argument("--learning-rate", type=float, default=defaults.learning_rate)
    parser.add_argument("--temperature", type=float, default=defaults.temperature)
    parser.add_argument("--positive-mm", type=float, default=defaults.positive_mm)
    parser.add_argument("--positive-deg", type=float, default=defaults.positive_deg)
    parser.add_argument("--soft-positive-mm", type=float, default=defaults.soft_positive_mm,
                        help="weigh pose neighbours by exp(-pose cost / this) so the nearest rank first (0: alike)")
    parser.add_argument("--objects-per-batch", type=int, default=defaults.objects_per_batch)
    parser.add_argument("--contrastive-weight", type=float, default=defaults.contrastive_weight,
                        help="weight of the pose-neighbour contrastive term")
    parser.add_argument("--teacher", metavar="ENCODER", default=None,
                        help="distil the neighbourhoods of this encoder's features (e.g. imagenet:efficientnet-lite0)")
    parser.add_argument("--teacher-weight", type=float, default=1.0, help="weight of the distillation term (with --teacher)")
    parser.add_argument("--teacher-temperature", type=float, default=defaults.teacher_temperature)
    parser.add_argument("--held-out", type=float, default=0.1, help="fraction of touches per object held out")
    parser.add_argument("--eval-every", type=int, default=defaults.eval_every)
    parser.add_argument("--eval-data", nargs="+", default=[], metavar="DATA",
                        help="datasets of unseen objects to evaluate retrieval on")
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--checkpoint-every", type=int, default=defaults.checkpoint_every,
                        help="save a resumable OUT.train-state every this many steps")
    parser.add_argument("--restart", action="store_true", help="ignore OUT.train-state and start over")
    parser.add_argument("--json", metavar="PATH", help="write the metrics as JSON")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(run=run)


def _default_config():
    from tactojax.features import ContrastiveConfig

    return ContrastiveConfig()


def _row(name: str, result: dict, plain: dict | None = None) -> list:
    plain = plain or {}
    percent = lambda value: f"{100 * value:.1f} %" if value is not None else "-"  # noqa: E731
    return [name, result["queries"], percent(result["top1_rate"]), result["median_top1_mm"],
            percent(plain.get("top1_rate")), plain.get("median_top1_mm", "-"),
            percent(result["oracle_rate"]), percent(result["chance_rate"])]


HEADERS = ["queries of", "n", "top-1 pose-neighbour", "median top-1 mm", "same, no symmetry",
           "median mm, no symmetry", "best possible", "random pick"]


def evaluate_unseen(encoder, paths, *, progress: bool) -> dict:
    """Leave-one-out retrieval on unseen objects, up to symmetry and without: the encoder, a
    randomly initialised one and raw pixels (30 x 40, minus the background)."""
    import jax

    from tactojax.features import encode_images, estimate_background, init_encoder, per_object_retrieval, pixel_encoder
    from tactojax.io import load_touches

    touches = load_touches(paths)
    background = estimate_background(touches.images)
    encoders = {"trained": encoder,
                "random init": init_encoder(jax.random.key(1), encoder.architecture, encoder.input_size,
                                            background=background),
                "pixels": pixel_encoder((30, 40), background=background)}
    results = {}
    for name, candidate in encoders.items():
        features = encode_images(candidate, touches.images, progress=progress)
        results[name] = {"symmetric": per_object_retrieval(features, touches, symmetric=True),
                         "plain": per_object_retrieval(features, touches, symmetric=False)}
    return results


def run(args) -> int:
    from tactojax.features import ContrastiveConfig, encode_images, estimate_background, split_held_out, train_encoder
    from tactojax.features._touches import NEIGHBOUR_DEG, NEIGHBOUR_MM, OPENING_WINDOW_MM
    from tactojax.io import (load_encoder_train_state, load_touches, resolve_encoder, save_encoder,
                             save_encoder_train_state)

    if not 0.0 <= args.held_out < 1.0:
        raise ValueError(f"--held-out must be in [0, 1), got {args.held_out}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    touches = load_touches(args.data)
    config = ContrastiveConfig(
        preset=args.preset, input_size=tuple(args.input_size), steps=args.steps, batch_size=args.batch_size,
        objects_per_batch=args.objects_per_batch, learning_rate=args.learning_rate, temperature=args.temperature,
        positive_mm=args.positive_mm, positive_deg=args.positive_deg, soft_positive_mm=args.soft_positive_mm,
        eval_every=args.eval_every, seed=args.seed, checkpoint_every=args.checkpoint_every,
        contrastive_weight=args.contrastive_weight, teacher_weight=args.teacher_weight if args.teacher else 0.0,
        teacher_temperature=args.teacher_temperature)
    held_out = split_held_out(touches, args.held_out, seed=args.seed)
    print(f"training {args.preset} at {config.input_size[0]}x{config.input_size[1]} px on "
          f"{int((~held_out).sum())} touches of {len(touches.objects)} objects ({int(held_out.sum())} held out)")
    state_path = out.with_name(out.name + ".train-state")
    state, history = None, None
    if state_path.exists() and not args.restart:
        state, history = load_encoder_train_state(state_path, config)
        print(f"resuming from step {int(state.step)} ({state_path})")
    started = time.perf_counter()
    teacher = None
    if args.teacher:
        print(f"teacher features: {args.teacher}")
        teacher = encode_images(resolve_encoder(args.teacher), touches.images, progress=not args.no_progress)
    encoder, history = train_encoder(touches, config, background=estimate_background(touches.images),
                                     held_out=held_out, teacher_features=teacher, state=state, history=history,
                                     on_checkpoint=lambda s, h: save_encoder_train_state(state_path, s, config, h),
                                     progress=not args.no_progress)
    seconds = time.perf_counter() - started
    report = {"preset": args.preset, "data": [str(p) for p in args.data], "objects": list(touches.objects),
              "touches": len(touches), "held_out": int(held_out.sum()), "teacher": args.teacher,
              "config": dataclasses.asdict(config), "train_seconds": round(seconds, 1), "history": history}
    rows = []
    if held_out.any():
        rows.append(_row("held-out touches", {k: history[-1][k] for k in ("queries", "top1_rate", "median_top1_mm",
                                                                         "median_top1_deg", "oracle_rate", "chance_rate")}))
    if args.eval_data:
        report["unseen"] = evaluate_unseen(encoder, args.eval_data, progress=not args.no_progress)
        for obj in report["unseen"]["trained"]["symmetric"]:
            for name, result in report["unseen"].items():
                rows.append(_row(f"{obj} ({name})", result["symmetric"][obj], result["plain"][obj]))
    if rows:
        print(f"\nCTI retrieval by pose (top-1 among openings within {OPENING_WINDOW_MM:g} mm; a hit is "
              f"within {NEIGHBOUR_MM:g} mm and {NEIGHBOUR_DEG:g} deg of the query, up to the object's "
              f"symmetries)\n" + format_table(HEADERS, rows))
    save_encoder(out, encoder, metadata=report)
    state_path.unlink(missing_ok=True)  # the run is complete; the checkpoint holds the result
    print(f"wrote {out} after {seconds:.0f} s (this run; teacher features included)")
    if args.json:
        write_json(args.json, report)
    return 0
