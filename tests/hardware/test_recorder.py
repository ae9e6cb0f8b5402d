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


def test_both_fingers_are_recorded_at_their_jaws_and_maps_read_the_sensor_jaw(tmp_path, small_spec):
    from tactojax.geometry import opposite_sensor_pose, sensor_pose

    first = touch(small_spec)
    with Recorder(tmp_path / "r", small_spec) as recorder:
        recorder.write(first, object_id="x")
        recorder.write(first.replace(image=np.full_like(first.image, 7)), object_id="x", finger=1)
        with pytest.raises(ValueError, match="finger must be 0"):
            recorder.write(first, object_id="x", finger=2)
    data = open_dataset(tmp_path / "r").read(["finger", "T_world_sensor", "image"])
    assert data["finger"].tolist() == [0, 1] and np.all(data["image"][1] == 7)
    for finger, kinematics in ((0, sensor_pose), (1, opposite_sensor_pose)):
        expected = kinematics(first.T_world_gripper, np.float32(first.opening_mm)).wxyz_xyz
        np.testing.assert_allclose(data["T_world_sensor"][finger], np.asarray(expected), atol=1e-5)
    # The jaws face each other: the two sensors sit an opening apart.
    assert np.linalg.norm(data["T_world_sensor"][0, 4:] - data["T_world_sensor"][1, 4:]) > first.opening_mm / 2
    grasps = read_grasps(tmp_path / "r")
    assert grasps["index"].tolist() == [0]  # a map reads the sensor jaw's touches


def test_a_recording_made_before_the_finger_field_continues_with_the_first_finger(tmp_path, small_spec):
    from tactojax.io import DatasetWriter

    first = touch(small_spec)
    with Recorder(tmp_path / "r", small_spec) as recorder:
        recorder.write(first, object_id="x")
    # The same recording as an older version wrote it: no finger field.
    old = open_dataset(tmp_path / "r")
    record = {name: value[0] for name, value in old.read([f for f in old.fields if f != "finger"]).items()}
    with DatasetWriter(tmp_path / "old", metadata=old.metadata, chunk_size=1) as writer:
        writer.append(record)
    with Recorder(tmp_path / "old", small_spec) as recorder:
        recorder.write(first, object_id="x")
        with pytest.raises(ValueError, match="predates the finger field"):
            recorder.write(first, object_id="x", finger=1)
    assert len(open_dataset(tmp_path / "old")) == 2
