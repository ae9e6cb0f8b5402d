"""One active episode on the simulated cell, as ``tactojax record --active`` and ``tactojax demo`` run it.

The object is placed at a turn, the first grasp is the new-grasps protocol's (tried in order
until one is felt), and then :func:`tactojax.hardware.active_episode` chooses every grasp
through the cell's robot, two tactile cameras and pose feed, while the live localizer fuses
them. The simulator knows where the object is: after each grasp the belief's error is measured
against it (:func:`tactojax.localize.evaluation.belief_error`).
"""

from __future__ import annotations

from pathlib import Path

from tactojax.cli._table import format_table

FIRST_GRASPS = 32
"""Protocol grasps tried, in order, for the first grasp."""


def add_active_arguments(group) -> None:
    """The flags of an active episode (``record --active``, ``demo``)."""
    group.add_argument("--max-grasps", type=int, default=3, help="grasps charged per episode at most (default 3)")
    group.add_argument("--candidates", type=int, default=32, help="grasps proposed per choice (default 32)")
    group.add_argument("--stop", type=float, default=0.95,
                       help="stop when the belief's P(within 2 mm) reaches this (default 0.95)")


def run_simulated_active(spec, obj, maps, model, encoder, *, calibrations=None, surfaces=None, turn_deg: float = 0.0,
                         max_grasps: int = 3, candidates: int = 32, stop: float = 0.95, seed: int = 0,
                         recorder=None, object_id: str = "", figure: str | Path | None = None) -> dict:
    """Run one active episode on a simulated two-finger cell (see the module docstring), print
    a row per executed grasp, and write the episode's figure if asked.

    Returns:
        ``{"object", "turn_deg", "grasps": [row dicts], "stopped", "compile_s", "seconds", "figure"}``
        (a row's ``error_mm`` is None before any fused grasp, ``expected_gain`` None for a first grasp).
    """
    import time

    import jax
    import jaxlie
    import numpy as np

    from tactojax.hardware import active_episode, simulated_cell
    from tactojax.localize import BeliefSettings, Localizer
    from tactojax.localize.active import ActiveSettings
    from tactojax.localize.evaluation import belief_error
    from tactojax.simulate import GraspsProtocol, grasps_plan

    if max_grasps < 1 or candidates < 1 or not 0.0 < stop <= 1.0:
        raise ValueError("--max-grasps and --candidates must be at least 1, --stop in (0, 1]")
    start = time.perf_counter()
    localizer = Localizer(maps, model, encoder, calibrations=calibrations, surfaces=surfaces,
                          settings=BeliefSettings(max_touches=max(6, 2 * max_grasps)))
    print(f"live localizer compiled in {localizer.compile_s:.1f} s")
    plan = grasps_plan(jax.random.key(seed), obj, GraspsProtocol(episodes=1, grasps_per_episode=FIRST_GRASPS,
                                                                 fingers=2, turns_deg=(turn_deg,)))
    T_world_object = jaxlie.SE3(plan.T_world_object.wxyz_xyz[0])
    settings = ActiveSettings(stop_probability=stop)
    rows, snapshots = [], []
    with simulated_cell(spec, obj, fingers=2, seed=seed) as cell:
        cell.scene.place_object(T_world_object)
        for step in active_episode(jax.random.key(seed + 1), cell.robot, localizer, cell.camera,
                                   cell.gripper.opening_mm, cell.poses, plan.T_world_gripper,
                                   second_camera=cell.second_camera, max_grasps=max_grasps, candidates=candidates,
                                   settings=settings, recorder=recorder, object_id=object_id or obj.name):
            # Where the jaws held it (the commanded pose re-centred by the wrist), else where commanded.
            held = step.T_world_gripper if step.T_world_gripper_held is None else step.T_world_gripper_held
            T_object_gripper = T_world_object.inverse() @ held
            centre = np.asarray(T_object_gripper.translation())
            closing = np.asarray(T_object_gripper.rotation().as_matrix())[:, 1]
            error = float(belief_error(step.belief, T_world_object)) if step.belief is not None else None
            within = step.estimate.probability_within if step.estimate is not None else 0.0
            rows.append({"grasp": step.grasp, "chosen": step.chosen, "centre_mm": centre.round(1).tolist(),
                         "yaw_deg": _yaw_deg(closing), "opening_mm": step.opening_mm, "fused": step.fused,
                         "expected_gain": None if step.chosen == "first" else step.gain,
                         "probability_within_2mm": within, "error_mm": error, "stop": step.stop,
                         "choice_s": step.choice_s})
            snapshots.append(_snapshot(step, T_world_object, centre, closing, error, within))
    _print_rows(rows)
    stopped = bool(rows and rows[-1]["stop"])
    print(f"{'stopped: P(within 2 mm) >= ' + format(stop, 'g') if stopped else 'no stop'} after "
          f"{rows[-1]['grasp'] if rows else 0} grasps charged ({len(rows)} executed)")
    report = {"object": obj.name, "turn_deg": turn_deg, "grasps": rows, "stopped": stopped,
              "compile_s": localizer.compile_s, "seconds": time.perf_counter() - start}
    if figure is not None and snapshots:
        from tactojax.viz import active_episode_figure, save_png

        points = np.asarray(maps[0].points_object)[np.asarray(maps[0].valid)]
        title = (f"active touch on {obj.name} (turned {turn_deg:g} deg): the chosen grasps (bars) and the "
                 "belief's hypotheses of the first sensor's position (dots; red x: the truth)")
        report["figure"] = str(save_png(active_episode_figure(points, snapshots, title=title), figure))
        print(f"figure: {report['figure']}")
    return report


def _yaw_deg(closing) -> float:
    """The grasp's yaw about the object's z: 0 where the closing axis runs along -y (the
    simulator's convention), degrees in (-180, 180]."""
    import numpy as np

    yaw = np.rad2deg(np.arctan2(closing[1], closing[0])) + 90.0
    return float(-((180.0 - yaw) % 360.0 - 180.0))


def _snapshot(step, T_world_object, centre, closing, error, within) -> dict:
    """What the figure shows of one step (object frame, mm)."""
    import numpy as np

    snapshot = {"label": step.chosen, "centre": centre, "closing": closing, "fused": step.fused,
                "width_mm": step.opening_mm or 20.0, "positions": None, "probabilities": None, "true": None,
                "within": within, "error_mm": error}
    if step.belief is not None:
        belief = step.belief
        # The hypotheses of the first touch's sensor pose, in the frame of the object where it truly is.
        snapshot.update(positions=np.asarray(belief.T_object_reference.translation()),
                        probabilities=np.asarray(belief.probabilities),
                        true=np.asarray((T_world_object.inverse() @ belief.T_world_reference).translation()))
    return snapshot


def _print_rows(rows: list[dict]) -> None:
    def number(value, digits=2):
        return "-" if value is None else f"{value:.{digits}f}"

    table = [[row["grasp"] or "-", row["chosen"], ", ".join(f"{v:.0f}" for v in row["centre_mm"]),
              f"{row['yaw_deg']:.0f}", "missed" if row["opening_mm"] is None else number(row["opening_mm"], 1),
              number(row["expected_gain"]), number(row["probability_within_2mm"]), number(row["error_mm"])]
             for row in rows]
    print("each executed grasp: its centre in the object frame (where the jaws held it) and yaw, the opening, "
          "the expected gain in P(within 2 mm) it was chosen for, and the belief after it (error: the fused touches' RMSE, up to "
          "symmetry)")
    print(format_table(["grasp", "chosen", "centre (mm)", "yaw (deg)", "opening (mm)", "expected gain",
                        "P(within 2 mm)", "error (mm)"], table))
