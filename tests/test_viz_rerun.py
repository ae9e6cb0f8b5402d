"""The rerun 3-D view: recordings written to .rrd, read back with rerun's own reader, and checked
value by value (points, colours, frames, estimates, beliefs); the estimates reader's errors;
``tactojax view`` and ``tactojax localize-live --view-save``."""

import json
import subprocess
import sys
from collections import defaultdict

import jaxlie
import numpy as np
import pytest

pytest.importorskip("rerun")

from rerun.chunk import RrdReader  # noqa: E402

from tactojax.cli import main  # noqa: E402
from tactojax.hardware import write_video  # noqa: E402
from tactojax.io import open_dataset, save_shape_model, save_tactile_map  # noqa: E402
from tactojax.mapping import stitched_point_cloud  # noqa: E402
from tactojax.viz import height_colors, log_view, open_recording, read_estimates, read_test_touches  # noqa: E402


def rrd_rows(path) -> dict[str, list[dict]]:
    """Every logged row of a recording: ``{entity: [{component or timeline: value}, ...]}``."""
    rows = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if ":" in n or n in ("touch", "frame")]
        for row in range(chunk.num_rows):
            rows[chunk.entity_path].append({n: batch.column(n)[row].as_py() for n in names})
    for entity in rows:
        rows[entity].sort(key=lambda r: (r.get("touch", -1), r.get("frame", -1)))
    return rows


def test_importing_tactojax_and_its_viz_does_not_import_rerun():
    code = "import sys, tactojax, tactojax.viz, tactojax.cli; assert 'rerun' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.fixture(scope="module")
def estimates_file(tmp_path_factory, mapping_dataset):
    """Estimates of the cylinder's first three touches: shifted 2 mm, one with a belief, one belief only."""
    touches = read_test_touches(mapping_dataset)
    true = touches["T_object_sensor"][:3]
    shifted = true.copy()
    shifted[:, 4] += 2.0
    belief = [{"T_object_sensor_wxyz_xyz": (true[2] + [0, 0, 0, 0, 0, 0, dz]).tolist(), "probability": p}
              for dz, p in ((0.0, 0.7), (5.0, 0.2), (-5.0, 0.1))]
    entries = [
        {"object_id": "cylinder", "T_object_sensor_wxyz_xyz": shifted[0].tolist(), "probability": 0.9},
        {"object_id": "cylinder", "T_object_sensor_wxyz_xyz": shifted[1].tolist(),
         "T_object_sensor_true_wxyz_xyz": true[1].tolist(), "belief": belief[:2]},
        {"object_id": "cylinder", "belief": belief},
    ]
    path = tmp_path_factory.mktemp("estimates") / "estimates.json"
    path.write_text(json.dumps(entries))
    return path, true, shifted


def test_a_recording_holds_the_maps_touches_estimates_and_beliefs(tmp_path, cylinder_map, gum_box_map,
                                                                   mapping_dataset, estimates_file):
    path, true, shifted = estimates_file
    recording, url = open_recording(save=tmp_path / "view.rrd")
    assert url is None
    counts = log_view(recording, [cylinder_map, gum_box_map], test=mapping_dataset, estimates=read_estimates(path))
    recording.flush()
    recording.disconnect()
    rows = rrd_rows(tmp_path / "view.rrd")
    touches = open_dataset(mapping_dataset).read(["T_world_sensor", "T_world_object", "mask"])
    assert counts["touches"] == len(touches["mask"]) and counts["estimates"] == 3 and counts["beliefs"] == 2

    # The map's cloud, coloured by height, in its object frame; the second map placed beside it.
    cloud, _ = stitched_point_cloud(cylinder_map, voxel_mm=0.5)
    (points,) = rows["/maps/cylinder/points"]
    np.testing.assert_allclose(points["Points3D:positions"], cloud, atol=1e-4)
    colors = np.array(points["Points3D:colors"], np.uint32)
    expected = height_colors(cloud).astype(np.uint32)
    np.testing.assert_array_equal(colors, (expected[:, 0] << 24) | (expected[:, 1] << 16) | (expected[:, 2] << 8) | 255)
    assert colors[np.argmin(cloud[:, 2])] != colors[np.argmax(cloud[:, 2])]
    assert rows["/maps/cylinder"][0]["Transform3D:translation"] == [[0.0, 0.0, 0.0]]
    (spacing,) = rows["/maps/gum_box"][0]["Transform3D:translation"]
    assert spacing[0] > np.ptp(cloud[:, 0]) and spacing[1:] == [0.0, 0.0]

    # Imprint frames: three arrows per valid imprint at its sensor origin, z along its rotation's z.
    (frames,) = rows["/maps/cylinder/imprint_frames"]
    valid = np.asarray(cylinder_map.imprint_valid)
    poses = jaxlie.SE3(np.asarray(cylinder_map.T_object_sensor.wxyz_xyz)[valid])
    origins, vectors = np.array(frames["Arrows3D:origins"]), np.array(frames["Arrows3D:vectors"])
    assert len(origins) == 3 * valid.sum()
    np.testing.assert_allclose(origins[::3], np.asarray(poses.translation()), atol=1e-3)
    np.testing.assert_allclose(vectors[2::3] / 3.0, np.asarray(poses.rotation().as_matrix())[:, :, 2], atol=1e-5)

    # Touches at their true poses (object frame), one per step of the touch timeline.
    touch_rows = rows["/maps/cylinder/touch/points"]
    assert [r["touch"] for r in touch_rows] == list(range(len(touches["mask"])))
    T_object_sensor = (jaxlie.SE3(touches["T_world_object"].astype(np.float64)).inverse()
                       @ jaxlie.SE3(touches["T_world_sensor"].astype(np.float64)))
    first = np.array(rows["/maps/cylinder/touch/true_frame"][0]["Arrows3D:origins"])
    np.testing.assert_allclose(first[0], np.asarray(T_object_sensor.translation())[0], atol=1e-3)
    assert len(touch_rows[0]["Points3D:positions"]) == min(int(touches["mask"][0].sum()), 2000)

    # Estimates: their frames, the true ones (from the entry or the test touch), the 2 mm error.
    estimated = rows["/maps/cylinder/estimate/frame"]
    np.testing.assert_allclose([r["Arrows3D:origins"][0] for r in estimated[:2]], shifted[:2, 4:], atol=1e-4)
    errors = [r["Scalars:scalars"][0] for r in rows["/metrics/translation_error_mm"]]
    np.testing.assert_allclose(errors, [2.0, 2.0, 0.0], atol=1e-4)
    (line, *_) = rows["/maps/cylinder/estimate/error"]
    np.testing.assert_allclose(line["LineStrips3D:strips"][0], [true[0, 4:], shifted[0, 4:]], atol=1e-4)
    assert [r["Scalars:scalars"][0] for r in rows["/metrics/probability"]] == pytest.approx([0.9, 0.7])

    # Beliefs: one point per hypothesis, bigger and more opaque the more probable.
    beliefs = rows["/maps/cylinder/belief"]  # touch 0 has none: the entity is cleared there
    assert [(r["touch"], r.get("Points3D:positions") is None) for r in beliefs] == [(0, True), (1, False), (2, False)]
    beliefs = beliefs[1:]
    assert len(beliefs[1]["Points3D:positions"]) == 3
    np.testing.assert_allclose(np.array(beliefs[1]["Points3D:positions"])[:, 2] - true[2, 6], [0, 5, -5], atol=1e-4)
    radii, alphas = beliefs[1]["Points3D:radii"], [c & 255 for c in beliefs[1]["Points3D:colors"]]
    assert radii[0] > radii[1] > radii[2] and alphas[0] > alphas[1] > alphas[2]


def test_estimates_files_are_checked_entry_by_entry(tmp_path):
    path = tmp_path / "e.json"
    good = [1, 0, 0, 0, 1.0, 2.0, 3.0]
    for payload, message in [
        ([{"object_id": "a", "T_object_sensor_wxyz_xyz": [1, 0, 0, 0, 1, 2]}], r"entry 0: a pose must be 7"),
        ([{"object_id": "a", "T_object_sensor_wxyz_xyz": good}, {"T_object_sensor_wxyz_xyz": good}],
         r"entry 1: expected an object with an 'object_id'"),
        ([{"object_id": "a", "T_object_sensor_wxyz_xyz": [2, 0, 0, 0, 0, 0, 0]}], "not a unit quaternion"),
        ([{"object_id": "a", "T_object_sensor_wxyz_xyz": good, "probability": 1.5}], r"\[0, 1\]"),
        ([{"object_id": "a", "belief": [{"T_object_sensor_wxyz_xyz": good}]}], r"entry 0 belief 0: 'probability'"),
        ([{"object_id": "a"}], r"needs 'T_object_sensor_wxyz_xyz' or a 'belief'"),
    ]:
        path.write_text(json.dumps(payload))
        with pytest.raises(ValueError, match=message):
            read_estimates(path)
    # localize --json (one object) and localize-live --json ({"estimates": [...]}) are read as they are.
    path.write_text(json.dumps({"object_id": "a", "T_object_sensor_wxyz_xyz": good, "method": "cti-icp-5"}))
    assert read_estimates(path)[0]["touch"] == 0
    path.write_text(json.dumps({"estimates": [{"frame": 4, "object_id": "b", "T_object_sensor_wxyz_xyz": good,
                                               "confidence": 0.4}] * 2}))
    assert [(e["touch"], e["probability"]) for e in read_estimates(path)] == [(0, 0.4), (1, 0.4)]


def test_view_command_saves_a_recording(tmp_path, cylinder_map, mapping_dataset, estimates_file, capsys):
    save_tactile_map(tmp_path / "cylinder.npz", cylinder_map)
    assert main(["view", str(tmp_path / "cylinder.npz"), "--test", str(mapping_dataset), "--estimates",
                 str(estimates_file[0]), "--save", str(tmp_path / "view.rrd")]) == 0
    printed = capsys.readouterr().out
    assert "estimates" in printed and "rerun " in printed
    rows = rrd_rows(tmp_path / "view.rrd")
    assert len(rows["/maps/cylinder/estimate/frame"]) == 3 and "/maps/cylinder/points" in rows
    assert main(["view", str(tmp_path / "cylinder.npz"), "--estimates", str(tmp_path / "missing.json"),
                 "--save", str(tmp_path / "x.rrd")]) == 2
    assert "no estimates file" in capsys.readouterr().err


@pytest.mark.slow  # a live localizer for the gum box map compiles (~20 s); the in-process test above covers the viewer
def test_localize_live_streams_its_estimates_to_a_recording(tmp_path, gum_box_map, lookup_model, tiny_encoder_path,
                                                           capsys):
    save_tactile_map(tmp_path / "gum_box.npz", gum_box_map)
    model = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    held = int(np.flatnonzero(np.asarray(gum_box_map.imprint_valid))[0])
    images = np.asarray(gum_box_map.images)[[held] * 3]  # one grasp held still: it settles on its 3rd frame
    images = images if images.dtype == np.uint8 else np.round(np.clip(images, 0, 1) * 255).astype(np.uint8)
    video = write_video(tmp_path / "touches.mkv", images, fps=30.0)
    assert main(["localize-live", "--camera", str(video), "--map", str(tmp_path / "gum_box.npz"), "--opening",
                 str(float(gum_box_map.openings[held])), "--model", str(model), "--encoder", str(tiny_encoder_path),
                 "--view-save", str(tmp_path / "live.rrd"), "--json",
                 str(tmp_path / "live.json")]) == 0
    capsys.readouterr()
    rows = rrd_rows(tmp_path / "live.rrd")
    live = json.loads((tmp_path / "live.json").read_text())["estimates"]
    assert [r["frame"] for r in rows["/live/image"]] == [0, 1, 2]
    np.testing.assert_allclose([r["Scalars:scalars"][0] for r in rows["/live/probability_within_2mm"]],
                               [e["probability_within_2mm"] for e in live], atol=1e-6)
    assert [r["frame"] for r in rows["/live/object_probability/gum_box"]] == [0, 1, 2]
    estimated = [e for e in live if e["T_object_sensor_wxyz_xyz"] is not None]  # from the grasp's settled frame on
    poses = rows["/maps/gum_box/live"]
    assert len(poses) == len(estimated) >= 1
    np.testing.assert_allclose(poses[0]["Arrows3D:origins"][0], estimated[0]["T_object_sensor_wxyz_xyz"][4:],
                               atol=1e-3)
    assert "/maps/gum_box/points" in rows
