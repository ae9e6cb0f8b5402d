"""``tactojax simulate --protocol grasps`` end to end: a tiny two-finger test set, then ``info``."""

import json

import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.cli import main
from tactojax.geometry import opposite_sensor_pose, sensor_pose
from tactojax.io import read_test_grasps

TINY = ["--protocol", "grasps", "--episodes", "2", "--grasps-per-episode", "2", "--scale", "0.25",
        "--no-progress"]


def test_simulate_grasps_then_info(tmp_path, capsys):
    out = tmp_path / "test_set"
    assert main(["simulate", "cuboid", "--out", str(out), *TINY, "--fingers", "2", "--yaw-range-deg", "10",
                 "--turns-deg", "0", "90", "--seed", "3"]) == 0
    assert "wrote 8 imprints (grasps" in capsys.readouterr().out
    data = read_test_grasps(out)
    np.testing.assert_array_equal(data["episode"], np.repeat([0, 1], 4))
    np.testing.assert_array_equal(data["finger"], np.tile([0, 1], 4))
    assert np.all(np.abs(data["yaw_rad"]) <= np.deg2rad(10.0))
    assert set(np.round(np.rad2deg(data["turn_rad"])).astype(int)) <= {0, 90}
    T_world_gripper, opening = jaxlie.SE3(jnp.asarray(data["T_world_gripper"])), jnp.asarray(data["opening_mm"])
    expected = np.where(data["finger"][:, None] == 0, np.asarray(sensor_pose(T_world_gripper, opening).wxyz_xyz),
                        np.asarray(opposite_sensor_pose(T_world_gripper, opening).wxyz_xyz))
    np.testing.assert_allclose(data["T_world_sensor"], expected, atol=1e-5)
    # The cuboid (80 x 20 x 25 mm) is pinched across its 20 mm side at turn 0 and along its
    # 80 mm at turn 90, less both gels' 1 mm; a yawed gripper meets it between the face's
    # width and the box's extent along the closing axis.
    across = np.where(np.round(np.rad2deg(data["turn_rad"])) == 0, 20.0, 80.0)
    along = 100.0 - across
    cos, sin = np.cos(data["yaw_rad"]), np.abs(np.sin(data["yaw_rad"]))
    assert np.all(data["opening_mm"] >= across * cos - 2.0 - 1e-3)
    assert np.all(data["opening_mm"] <= across * cos + along * sin - 2.0 + 1e-3)

    summary_path = tmp_path / "info.json"
    assert main(["info", str(out), "--json", str(summary_path)]) == 0
    printed = capsys.readouterr().out
    assert "protocol  grasps" in printed and "cuboid" in printed
    summary = json.loads(summary_path.read_text())
    assert summary["groups"] == {"cuboid": 8}
    assert summary["metadata"]["protocol"]["fingers"] == 2


def test_bad_grasps_settings_are_clear_errors(tmp_path, capsys):
    assert main(["simulate", "cuboid", "--out", str(tmp_path / "x"), *TINY, "--episodes", "0"]) == 2
    assert "at least one episode" in capsys.readouterr().err
