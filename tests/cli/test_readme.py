"""The README's command list and its Python example, run exactly as written.

Each ``tactojax ...`` line of the bash block under "## Command line" runs in order in one
folder, so every file a line reads is what an earlier line wrote (the defaults must compose).
Only two things change, to keep the test within a few tens of seconds on 2 cores:

* flags appended to a line (``SMALLER``; argparse keeps the last value): coarser grids, fewer
  touches, steps and queries. The README's own flags and defaults (sensor resolution, shape
  model, encoder, methods) are all kept, except ``map-catalog``'s calibration (``--calibrate 0``:
  it compiles the belief once per object; ``tests/cli/test_catalog_cli.py`` runs it).
* the user's own files that the list names (``my_part.stl``, ``touch.png``, ``touches.mkv``,
  ``session.bag``) are made from simulated data just before the line that reads them.

``SLOW`` lines are skipped here and say why; ``TACTOJAX_README_ALL=1`` runs them too, and prints
each line's time. ``.ci/run`` sets it: CI runs every line, ``tactojax demo`` included.

The Python example then runs in the same folder, on the maps and test grasps the list made, as
``tactojax calibrate-belief`` leaves the maps (their retrieval features stored; with
``TACTOJAX_README_ALL`` unset the calibration stays the default one, as that line is skipped).
The quick start's test command is what ``.ci/run`` runs.
"""

from __future__ import annotations

import contextlib
import io
import os
import shlex
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tactojax.cli import main

README = Path(__file__).resolve().parents[2] / "README.md"

SMALLER = {
    "simulate": ["--grid-mm", "30", "--yaws-deg", "0", "--turns-deg", "0", "90", "--touches", "6", "--no-progress"],
    "demo": ["--objects", "tape_roll", "gum_box", "--grid-mm", "40", "--calibration-touches", "2", "--queries", "3",
             "--episodes", "1", "--grasps", "2"],
    "train": ["--steps", "3", "--pixel-steps", "3", "--batch-size", "2", "--test-per-object", "2", "--no-progress"],
    "eval-shape": ["--held-out", "2"],
    "map": ["--points", "256", "--no-progress"],
    "map-catalog": ["--grid-mm", "40", "--points", "256", "--calibrate", "0", "--no-progress"],
    "eval-localization": ["--queries", "3"],
    "train-features": ["--steps", "2", "--batch-size", "4", "--no-progress"],
    "record": ["--grid-mm", "30", "--yaws-deg", "0", "--turns-deg", "0"],
    "localize-live": ["--frames", "3"],
    "calibrate-belief": ["--rounds", "1"],
}
"""Flags appended to each command's README line: small grids, few touches and steps."""

SMALLER_GRASPS = ["--episodes", "2", "--grasps-per-episode", "2", "--no-progress"]
"""For ``simulate --protocol grasps`` (its turns are the README's: the scissors fit only at 0 and 180)."""

SMALLER_SLIP = ["--sequences", "1", "--frames", "4", "--no-progress"]
"""For ``simulate --protocol slip``."""


def smaller(argv: list[str]) -> list[str]:
    """The flags appended to one README line."""
    if argv[0] == "simulate" and "grasps" in argv:
        return SMALLER_GRASPS
    if argv[0] == "simulate" and "slip" in argv:
        return SMALLER_SLIP
    return SMALLER.get(argv[0], [])

SLOW = {
    "demo": "the whole paper in one command: 70 s even for 2 objects on a 40 mm grid; the lines after it "
            "run each of its steps",
    "train": "compiles a training step: 12 s for 3 steps",
    "eval-shape": "reads the model that `train` writes; 7 s with --robustness",
    "calibrate": "fits taxim's real GelSight frames (8 s) and writes a model that no later line reads",
    "eval-localization": "leave-one-out with four methods: 44 s for 3 touches a map, mostly compiling",
    "train-features": "compiles contrastive training: 21 s for 2 steps",
    "localize-live": "compiles the whole touch program once: 9 s for 3 frames",
    "calibrate-belief": "compiles the belief update and runs it on every calibration touch: about 60 s; "
                        "tests/cli/test_belief_cli.py runs it on a small map",
}
"""Commands skipped unless TACTOJAX_README_ALL=1, and why (seconds on 2 quiet cores with the SMALLER
flags). All 25 lines took 3.7 min that way; the others take 49 s."""


PRINTS = {
    "simulate": ["gelslim 120x160"],  # the bundled shape model's resolution, by default
    "map": ["distance to true surface"],
    "fit-shape": ["converged"],
    "identify": ["identification top-1"],
    "map-catalog": ["3 of 3 objects mapped"],
    # Both maps are weighed (on these coarse maps a single touch may favour either object: accuracy
    # is measured by `identify` and the benchmarks, not by this run of the list).
    "localize": ["scissors ", "tape_roll ", "(P(object)", "P(within 2 mm)"],
    "repair": ["every chunk is intact"],
    "import-bag": ["touches written"],
}
"""What a command's output must show (beyond exiting 0)."""


def readme_commands(text: str) -> list[list[str]]:
    """The argv (without ``tactojax``) of every line of the README's command-line block."""
    section = text.split("## Command line", 1)[1]
    block = section.split("```bash\n", 1)[1].split("```", 1)[0].replace("\\\n", " ")
    commands = [shlex.split(line, comments=True) for line in block.splitlines()]
    commands = [argv for argv in commands if argv]
    assert all(argv[0] == "tactojax" for argv in commands), commands
    return [argv[1:] for argv in commands]


def _write_part(path: Path) -> None:
    """A user's mesh in mm: a 40 x 25 x 12 mm block."""
    trimesh.creation.box((40.0, 25.0, 12.0)).export(path)


def _write_touch(path: Path) -> None:
    """One tactile image of the scissors, at an opening near the README's 12.5 mm."""
    import cv2

    from tactojax.io import open_dataset

    records = open_dataset("data/scissors").read(["image", "opening_mm"])
    contact = np.abs(records["image"].astype(np.float32) - np.median(records["image"], axis=0)).sum(axis=(1, 2, 3))
    index = int(np.argmax(contact - 1e9 * (np.abs(records["opening_mm"] - 12.5) > 2.0)))
    cv2.imwrite(str(path), cv2.cvtColor(records["image"][index], cv2.COLOR_RGB2BGR))


def _write_touches(path: Path) -> None:
    """A lossless video of the simulated recording's touches across the gum box's 22 mm side."""
    from tactojax.hardware import write_video
    from tactojax.io import open_dataset

    records = open_dataset("data/gum_box-sim").read(["image", "opening_mm"])
    thin = np.flatnonzero(np.abs(records["opening_mm"] - 21.0) < 2.0)[:4]
    write_video(path, records["image"][thin], fps=30.0)


def _write_bag(path: Path) -> None:
    """A ROS 1 bag of the simulated recording's first four gum box touches (``tests/rosbag_writer.py``)."""
    import jax.numpy as jnp
    from rosbag_writer import write_bag

    from tactojax.io import open_dataset
    from tactojax.sensor import gelslim, render_image

    records = open_dataset("data/gum_box-sim").read(["image", "opening_mm", "T_world_gripper"])
    spec = gelslim(scale=0.5)
    background = np.round(np.clip(np.asarray(render_image(spec, jnp.zeros(spec.shape))), 0, 1) * 255)
    session = {"images": records["image"][:4], "openings": records["opening_mm"][:4].astype(np.float64),
               "poses": records["T_world_gripper"][:4].astype(np.float64), "background": background.astype(np.uint8)}
    write_bag(path, session, kind="ros1")


USER_FILES = {"my_part.stl": _write_part, "touch.png": _write_touch, "touches.mkv": _write_touches,
              "session.bag": _write_bag}


def test_readme_lists_the_commands_it_runs():
    commands = readme_commands(README.read_text())
    assert [argv[0] for argv in commands][:2] == ["info", "simulate"]
    assert {argv[0] for argv in commands} >= {"simulate", "map", "localize", "repair"}
    assert set(SMALLER) | set(SLOW) <= {argv[0] for argv in commands}


def readme_python_example(text: str) -> str:
    """The README's Python example (the first ``python`` block after its quick start)."""
    section = text.split("## Quick start", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


def _store_features(path: str) -> None:
    """What ``tactojax calibrate-belief`` stores in a map besides the calibration: the retrieval
    features of its imprints, from the default encoder."""
    from tactojax.cli._maps import load_maps_with_features
    from tactojax.io import save_tactile_map, tactile_map_metadata

    (tactile_map,), _ = load_maps_with_features([path], None, progress=False)
    save_tactile_map(path, tactile_map, metadata=tactile_map_metadata(path).get("metadata", {}))


def test_readme_test_command_is_the_ci_script():
    quick_start = README.read_text().split("## Quick start", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    commands = [line for line in quick_start.splitlines() if line and not line.startswith("#")]
    assert commands[1] == "bash .ci/run", commands
    ci = (README.parent / ".ci" / "run").read_text()
    assert "-m pytest" in ci and "mkdocs build --strict" in ci


@pytest.fixture(scope="module")
def readme_folder(tmp_path_factory):
    """A folder where the README's command list ran, line by line until one failed, and each
    line's (argv, exit code, stdout, stderr, seconds)."""
    folder = tmp_path_factory.mktemp("readme")
    run_all = os.environ.get("TACTOJAX_README_ALL") == "1"
    results = []
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        for argv in readme_commands(README.read_text()):
            if argv[0] in SLOW and not run_all:
                continue
            for name in argv:
                if name in USER_FILES and not Path(name).exists():
                    USER_FILES[name](Path(name))
            out, err = io.StringIO(), io.StringIO()
            started = time.perf_counter()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = main([*argv, *smaller(argv)])
            results.append((argv, code, out.getvalue(), err.getvalue(), time.perf_counter() - started))
            if code != 0:
                break
    finally:
        os.chdir(cwd)
    return folder, results


@pytest.mark.slow  # each command is tested in tests/cli; this runs the list as written (-m slow)
def test_readme_command_list_runs_as_written(readme_folder, capsys):
    _, results = readme_folder
    for argv, code, out, err, _ in results:
        assert code == 0, f"tactojax {' '.join(argv)} exited {code}:\n{out[-2000:]}\n{err[-2000:]}"
        for expected in PRINTS.get(argv[0], []):
            assert expected in out, f"tactojax {' '.join(argv)} did not print {expected!r}:\n{out}"
    run_all = os.environ.get("TACTOJAX_README_ALL") == "1"
    assert len(results) == sum(1 for argv in readme_commands(README.read_text()) if run_all or argv[0] not in SLOW)
    if run_all:
        with capsys.disabled():
            for argv, _, _, _, seconds in results:
                print(f"{seconds:6.1f} s  tactojax {' '.join(argv)}")


@pytest.mark.slow
def test_readme_python_example_runs_as_written(readme_folder, monkeypatch, capsys):
    folder, results = readme_folder
    assert all(code == 0 for _, code, *_ in results), "the README's command list failed (see its test)"
    monkeypatch.chdir(folder)
    for path in ("scissors.npz", "tape_roll.npz"):
        _store_features(path)
    namespace = {}
    exec(compile(readme_python_example(README.read_text()), "README.md", "exec"), namespace)
    printed = capsys.readouterr().out
    belief, estimate = namespace["belief"], namespace["estimate"]
    assert 0.0 <= float(belief.probability_within(2.0)) <= 1.0
    assert belief.T_world_object.wxyz_xyz.shape == (7,)
    assert estimate.object_id in {"scissors", "tape_roll"} and 1 <= estimate.grasps <= len(namespace["frames"])
    assert abs(sum(estimate.object_probabilities.values()) - 1.0) < 1e-4
    assert estimate.T_world_object is not None and 0.0 <= estimate.probability_within <= 1.0
    assert estimate.object_id in printed
