"""``tactojax map-catalog``: many objects into one directory, resumable; ``info`` summarises it and
the commands that take maps take it."""

import json

import pytest

from tactojax.cli import main
from tactojax.cli._maps import maps_and_query_encoder
from tactojax.io import (catalog_maps, encoder_label, load_tactile_map, maps_encoder_name, read_catalog,
                         save_shape_model, save_tactile_map, stored_surface, tactile_map_metadata)
from tactojax.objects import get_object


@pytest.mark.slow  # simulates and maps two objects, then runs four commands on them (~16 s)
def test_map_catalog_builds_resumes_and_feeds_the_commands(lookup_model, tiny_encoder_path, tmp_path, capsys):
    model = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    out = tmp_path / "catalog"
    common = ["--out", str(out), "--grid-mm", "40", "--scale", "0.25", "--model", str(model), "--encoder",
              str(tiny_encoder_path), "--points", "64", "--no-progress"]
    assert main(["map-catalog", "cylinder", "missing.stl", *common]) == 0
    index = read_catalog(out)
    assert index["objects"]["cylinder"]["status"] == "built"
    assert index["objects"]["missing.stl"]["status"] == "failed"
    assert "does not exist" in index["objects"]["missing.stl"]["error"]
    cylinder = load_tactile_map(out / "cylinder.npz")
    assert cylinder.object_id == "cylinder" and cylinder.features.shape[1] > 0  # the encoder's, stored
    assert index["objects"]["cylinder"]["imprints"] == len(cylinder)
    # The object's symmetry travels with the map, and the index says it in words.
    assert cylinder.symmetry == get_object("cylinder").symmetry
    assert index["objects"]["cylinder"]["symmetry"] == "continuous about x, flipped about z"
    assert not (out / ".data" / "cylinder").exists()  # the simulated dataset is not kept

    # Interrupted while building the gum box (its half-written dataset is left), then resumed.
    leftover = out / ".data" / "gum_box"
    leftover.mkdir(parents=True)
    (leftover / "chunk-junk.npz").write_bytes(b"half")
    built_at = (out / "cylinder.npz").stat().st_mtime_ns
    capsys.readouterr()
    assert main(["map-catalog", "cylinder", "gum_box", *common]) == 0
    assert "1 of 2 objects already built" in capsys.readouterr().out
    assert (out / "cylinder.npz").stat().st_mtime_ns == built_at
    assert not leftover.exists()
    assert catalog_maps(out) == [out / "cylinder.npz", out / "gum_box.npz"]

    assert main(["info", str(out), "--json", str(tmp_path / "info.json")]) == 0
    assert "2 of 3 objects mapped" in capsys.readouterr().out
    assert json.loads((tmp_path / "info.json").read_text())["objects"]["gum_box"]["status"] == "built"

    # The catalog stands for its maps: identification among them (leave-one-out retrieval).
    assert main(["identify", str(out), "--json", str(tmp_path / "id.json"), "--figure", str(tmp_path / "id.png")]) == 0
    assert json.loads((tmp_path / "id.json").read_text())["objects"] == ["cylinder", "gum_box"]

    # Each map stores its surface, which localization reads instead of building it anew.
    assert stored_surface(out / "gum_box.npz") is not None
    capsys.readouterr()
    assert main(["info", str(out / "gum_box.npz")]) == 0
    printed = capsys.readouterr().out
    assert "surface   stored" in printed and "belief    the default (no fit of its own" in printed

    # The maps record their encoder, and the commands encode new touches with it by default.
    assert tactile_map_metadata(out / "cylinder.npz")["metadata"]["features_encoder"] == encoder_label(tiny_encoder_path)
    assert maps_encoder_name(catalog_maps(out), None) == encoder_label(tiny_encoder_path)
    _, encoder = maps_and_query_encoder(catalog_maps(out), None, progress=False)
    assert encoder.feature_dim == cylinder.features.shape[1]
    other = tmp_path / "other.npz"  # a map whose features say they come from the bundled encoder
    save_tactile_map(other, cylinder.replace(object_id="other"), metadata={"features_encoder": "bundled:features-tactile"})
    with pytest.raises(ValueError, match="features of different encoders"):
        maps_encoder_name([out / "cylinder.npz", other], None)

    # Other settings are another catalog.
    assert main(["map-catalog", "cylinder", *common[:-1], "--grid-mm", "30", "--no-progress"]) == 2
    assert "was built with other settings" in capsys.readouterr().err


def test_a_ycb_scan_that_a_catalog_object_is_goes_by_the_catalog_name():
    from tactojax.cli._map_catalog import expand_objects
    from tactojax.objects import CATALOG_YCB_SCANS, ycb_scans

    expanded = expand_objects(["scissors", "ycb:all", "ycb:037_scissors"])
    assert expanded[0] == "scissors" and expanded.count("scissors") == 1
    assert not {f"ycb:{scan}" for scan in CATALOG_YCB_SCANS.values()} & set(expanded)
    assert set(CATALOG_YCB_SCANS) <= set(expanded)  # named by ycb:all, mapped under the catalog's names
    assert len(expanded) == len(ycb_scans())  # every scan once, four of them by their catalog names
    assert get_object("screwdriver").parameters["ycb_id"] == CATALOG_YCB_SCANS["screwdriver"]


@pytest.mark.slow  # simulates and maps a cylinder, then runs the belief over one calibration episode (~30 s)
def test_map_catalog_calibrate_fits_the_search_term_into_the_map(lookup_model, tiny_encoder_path, tmp_path, capsys,
                                                                  monkeypatch):
    """``--calibrate N``: N episodes of the object's own grasps, the belief run over them, and its
    calibration fit and stored in the map's header, where the belief reads it. Features of an
    encoder other than the default's get every scale fit (``calibrate-belief``'s rule); the
    default's, only the missed-search term (``--search-only``: the default's scales belong to them)."""
    from tactojax.io import load_localization_map
    from tactojax.localize import BeliefCalibration, calibration_to_json

    model = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    out = tmp_path / "catalog"
    common = ["--out", str(out), "--grid-mm", "40", "--scale", "0.25", "--model", str(model), "--encoder",
              str(tiny_encoder_path), "--points", "64", "--no-progress"]
    assert main(["map-catalog", "cylinder", *common, "--calibrate", "1"]) == 0
    assert "P(search found), 1 touch" in capsys.readouterr().out
    entry = read_catalog(out)["objects"]["cylinder"]
    report = tactile_map_metadata(out / "cylinder.npz")["metadata"]["belief_calibration"]
    assert report["shape_fit"] and not report["search_only"]  # the tiny encoder's features: every scale
    assert report["episodes"] == 1 and report["fingers"] == 2 and report["encoder"] == encoder_label(tiny_encoder_path)
    assert 0.0 < entry["calibration"]["found_after_1_touch"] <= 1.0
    fitted = calibration_to_json(load_localization_map(out / "cylinder.npz").calibration)  # what the belief reads
    assert fitted == pytest.approx({name: report[name] for name in fitted}, abs=1e-6)
    assert fitted != pytest.approx(calibration_to_json(BeliefCalibration.default()))
    assert not (out / ".data" / "cylinder-calibration").exists()
    capsys.readouterr()
    assert main(["info", str(out / "cylinder.npz")]) == 0
    assert "belief    every scale fit on 1 episodes of its object's grasps (2 fingers)" in capsys.readouterr().out
    # With the default encoder's features only the search term is fit (the default's scales belong to them).
    import argparse

    import tactojax.cli._calibrate_belief as calibrate_belief
    from tactojax.cli._map_catalog import _calibrate
    from tactojax.io import DEFAULT_ENCODER, load_tactile_map, resolve_encoder, resolve_shape_model
    from tactojax.sensor import sensor_preset

    asked = {}

    def fake_fit(path, tactile_map, episodes, **options):
        asked.update(options)
        return BeliefCalibration.default(), {"beliefs": 0}

    monkeypatch.setattr(calibrate_belief, "calibrate_map_file", fake_fit)
    args = argparse.Namespace(calibrate=1, calibration_turns_deg=[0.0], seed=0, no_progress=True, keep_data=False)
    _calibrate(out / "cylinder.npz", load_tactile_map(out / "cylinder.npz"), get_object("cylinder"),
               sensor_preset("gelslim", scale=0.25), resolve_shape_model(str(model)),
               resolve_encoder(str(tiny_encoder_path)), encoder_label(DEFAULT_ENCODER),
               out / ".data" / "cylinder-calibration", args)
    assert asked == {"fit_shape": False, "search_only": True, "rounds": 1, "progress": False}
    assert tactile_map_metadata(out / "cylinder.npz")["metadata"]["belief_calibration"]["encoder"] == \
        encoder_label(DEFAULT_ENCODER)
    # A catalog built without calibration is another catalog.
    assert main(["map-catalog", "cylinder", *common]) == 2
    assert "was built with other settings" in capsys.readouterr().err
    assert main(["map-catalog", "cylinder", *common, "--calibrate", "-1"]) == 2
    assert "number of episodes" in capsys.readouterr().err
