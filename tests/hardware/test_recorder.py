"""The recorder: a SIGKILLed recording reads back every completed touch; bad touches are refused."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import jaxlie
import numpy as np
import pytest

from tactojax.hardware import Recorder, SynchronisedTouch
from tactojax.io import Dataset, open_dataset, read_grasps

RECORD_FOREVER = textwrap.dedent("""
    import sys
    from tactojax.hardware import Recorder, record_protocol, simulated_cell
    from tactojax.objects import get_object
    from tactojax.sensor import gelslim
    from tactojax.simulate import MappingProtocol, mapping_plan

    spec, obj = gelslim(scale=0.25), get_object("gum_box")
    plan = mapping_plan(obj, MappingProtocol(grid_mm=10.0))
    with simulated_cell(spec, obj, fps=20.0) as cell, Recorder(sys.argv[1], spec) as recorder:
        record_protocol(cell.robot, cell.camera, cell.gripper.opening_mm, cell.poses, plan, recorder,
                        object_id=obj.name, place_object=cell.scene.place_object, progress=False)
""")


def recorded_count(path) -> int:
    try:
        return len(Dataset(path))
    except Exception:  # not created yet
        return 0


def test_a_killed_recording_keeps_every_completed_touch(tmp_path, small_spec):
    path = tmp_path / "recording"
    process = subprocess.Popen([sys.executable, "-c", RECORD_FOREVER, str(path)], stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while recorded_count(path) < 4:
            assert process.poll() is None, process.stderr.read().decode()[-2000:]
            assert time.monotonic() < deadline, "the recorder wrote nothing in 120 s"
            time.sleep(0.05)
        os.kill(process.pid, signal.SIGKILL)  # mid-run: between or inside writes
        process.wait(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == -signal.SIGKILL
    dataset = open_dataset(path)
    count = len(dataset)
    assert count >= 4
    records = dataset.read()  # every listed touch is complete and readable
    assert records["image"].shape == (count, *small_spec.shape, 3)
    assert np.all(records["opening_mm"] > 0) and np.all(np.diff(records["plan_index"]) > 0)
    grasps = read_grasps(path)  # and it is a dataset ``tactojax map`` takes
    assert len(grasps["openings"]) == count
    # Recording can go on: the dead writer's lock is taken over.
    with Recorder(path, small_spec) as recorder:
        recorder.write(touch(small_spec), object_id="gum_box")
    assert len(open_dataset(path)) == count + 1


def touch(spec, *, shape=None, opening=30.0):
    image = np.zeros(shape or (*spec.shape, 3), np.uint8)
    return SynchronisedTouch(image=image, timestamp_s=1.0, opening_mm=opening,
                             T_world_gripper=jaxlie.SE3(np.array([1.0, 0, 0, 0, 0, 0, 0])))


def test_bad_touches_are_refused_before_anything_is_written(tmp_path, small_spec):
    with Recorder(tmp_path / "r", small_spec) as recorder:
        with pytest.raises(ValueError, match="touch image must be"):
            recorder.write(touch(small_spec, shape=(10, 10, 3)), object_id="x")
        with pytest.raises(ValueError, match="positive gripper opening"):
            recorder.write(touch(small_spec, opening=float("nan")), object_id="x")
        recorder.write(touch(small_spec), object_id="x")
    assert len(open_dataset(tmp_path / "r")) == 1
