"""Ball presses from disk (taxim, dataPack .npz, PNG directory), their errors, and `tactojax calibrate`."""

import argparse
import csv
import json

import cv2
import numpy as np
import pytest

from tactojax.io._presses import load_ball_presses
from tactojax.io._shape import load_shape_model, shape_model_metadata

MM_PER_PX = 0.05
BALL_RADIUS_MM = 2.0


def _lambertian_presses(count=12, shape=(120, 160), seed=0):
    """(background RGB uint8, images RGB uint8, centres, radii) of ball presses on a Lambertian gel,
    in closed form: colour change = M (n - n_flat) for the ball's unit normal n inside the disc."""
    rng = np.random.default_rng(seed)
    mixing = np.array([[0.25, -0.10, 0.10], [-0.12, 0.22, 0.12], [0.05, 0.05, -0.25]])
    background = np.full((*shape, 3), 0.45)
    rows, cols = np.indices(shape)
    images, centers, radii = [], [], []
    for _ in range(count):
        contact_px = BALL_RADIUS_MM * rng.uniform(0.5, 0.75) / MM_PER_PX
        x = rng.uniform(contact_px + 2, shape[1] - contact_px - 3)
        y = rng.uniform(contact_px + 2, shape[0] - contact_px - 3)
        dx, dy = (cols - x) * MM_PER_PX, (rows - y) * MM_PER_PX
        inside = dx**2 + dy**2 < (contact_px * MM_PER_PX) ** 2
        normal_z = np.sqrt(np.maximum(BALL_RADIUS_MM**2 - dx**2 - dy**2, 0)) / BALL_RADIUS_MM
        normal = np.stack([dx / BALL_RADIUS_MM, dy / BALL_RADIUS_MM, normal_z - 1.0], -1) * inside[..., None]
        image = background + normal @ mixing.T + rng.normal(0, 1 / 255, background.shape)
        images.append(np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
        centers.append((x, y))
        radii.append(contact_px)
    return (np.round(background * 255).astype(np.uint8), np.stack(images), np.array(centers, np.float32),
            np.array(radii, np.float32))


def _write_directory(path, background, images, centers, radii):
    path.mkdir()
    cv2.imwrite(str(path / "background.png"), background[..., ::-1])
    with (path / "presses.csv").open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["image", "center_x_px", "center_y_px", "radius_px"])
        for index, (image, (x, y), radius) in enumerate(zip(images, centers, radii)):
            cv2.imwrite(str(path / f"press_{index:02d}.png"), image[..., ::-1])
            writer.writerow([f"press_{index:02d}.png", x, y, radius])
    return path


@pytest.fixture(scope="module")
def presses_arrays():
    return _lambertian_presses()


def test_directory_round_trip(tmp_path, presses_arrays):
    background, images, centers, radii = presses_arrays
    presses = load_ball_presses(_write_directory(tmp_path / "presses", *presses_arrays), mm_per_px=MM_PER_PX)
    np.testing.assert_array_equal(presses.images, images)  # PNG is lossless; BGR -> RGB undone
    np.testing.assert_allclose(presses.background, background / 255.0, atol=1e-7)
    np.testing.assert_allclose(presses.centers_px, centers, rtol=1e-6)
    np.testing.assert_allclose(presses.radii_px, radii, rtol=1e-6)
    assert presses.mm_per_px == MM_PER_PX and presses.sensor == "presses"


def test_npz_in_taxim_layout_is_bgr(tmp_path, presses_arrays):
    background, images, centers, radii = presses_arrays
    path = tmp_path / "dataPack.npz"
    np.savez(path, f0=background[..., ::-1], imgs=images[..., ::-1], touch_center=centers.astype(np.float64),
             touch_radius=radii.round().astype(np.int64))
    presses = load_ball_presses(path, mm_per_px=MM_PER_PX)
    np.testing.assert_array_equal(presses.images, images)
    np.testing.assert_array_equal(presses.radii_px, radii.round())
    np.savez(tmp_path / "partial.npz", f0=background, imgs=images)
    with pytest.raises(ValueError, match="missing arrays"):
        load_ball_presses(tmp_path / "partial.npz", mm_per_px=MM_PER_PX)
    np.savez(tmp_path / "gray.npz", f0=background[..., 0], imgs=images, touch_center=centers, touch_radius=radii)
    with pytest.raises(ValueError, match=r"f0 must be \(H, W, 3\)"):
        load_ball_presses(tmp_path / "gray.npz", mm_per_px=MM_PER_PX)
    (tmp_path / "corrupt.npz").write_bytes(b"not a zip archive")
    with pytest.raises(ValueError, match="not a .npz archive"):
        load_ball_presses(tmp_path / "corrupt.npz", mm_per_px=MM_PER_PX)
    with pytest.raises(ValueError, match="--mm-per-px"):
        load_ball_presses(path)


def test_taxim_frames_load_with_their_pitch():
    pytest.importorskip("taxim")
    presses = load_ball_presses("taxim:gelsight")
    assert presses.images.shape == (48, 480, 640, 3) and presses.mm_per_px == pytest.approx(0.0295)
    assert presses.sensor == "gelsight" and presses.background.dtype == np.float32
    with pytest.raises(ValueError, match="unknown taxim sensor"):
        load_ball_presses("taxim:digit")


@pytest.mark.parametrize(
    ("damage", "error", "message"),
    [
        ("no_csv", FileNotFoundError, "no presses.csv"),
        ("no_image", FileNotFoundError, "is missing"),
        ("corrupt_png", ValueError, "cannot read image"),
        ("gray_png", ValueError, "8-bit colour"),
        ("wrong_size", ValueError, "but background.png is"),
        ("radius_out_of_image", ValueError, "reaches outside"),
        ("bad_number", ValueError, "must be numbers"),
        ("bad_header", ValueError, "lacks columns"),
        ("empty_csv", ValueError, "lists no presses"),
    ],
)
def test_damaged_directories_get_clear_errors(tmp_path, presses_arrays, damage, error, message):
    path = _write_directory(tmp_path / "presses", *presses_arrays)
    table = path / "presses.csv"
    lines = table.read_text().splitlines()
    if damage == "no_csv":
        table.unlink()
    elif damage == "no_image":
        (path / "press_03.png").unlink()
    elif damage == "corrupt_png":
        (path / "press_03.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    elif damage == "gray_png":
        cv2.imwrite(str(path / "press_03.png"), presses_arrays[1][3, ..., 0])
    elif damage == "wrong_size":
        cv2.imwrite(str(path / "press_03.png"), presses_arrays[1][3, :-4])
    elif damage == "radius_out_of_image":
        lines[2] = "press_01.png,10.0,40.0,30.0"
    elif damage == "bad_number":
        lines[2] = "press_01.png,ten,40.0,30.0"
    elif damage == "bad_header":
        lines[0] = "image,x,y,r"
    elif damage == "empty_csv":
        lines = lines[:1]
    table.write_text("\n".join(lines) + "\n") if table.exists() or damage != "no_csv" else None
    with pytest.raises(error, match=message):
        load_ball_presses(path, mm_per_px=MM_PER_PX)


def test_missing_source_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no ball presses"):
        load_ball_presses(tmp_path / "nowhere", mm_per_px=MM_PER_PX)
    with pytest.raises(ValueError, match="mm_per_px must be positive"):
        load_ball_presses(tmp_path, mm_per_px=-1.0)


def _calibrate_command(argv):
    """``tactojax calibrate`` through its own parser (the lead registers it in cli/_main.py)."""
    from tactojax.cli import _calibrate

    parser = argparse.ArgumentParser(prog="tactojax")
    _calibrate.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["calibrate", *argv])
    return args.run(args)


def test_calibrate_command_end_to_end(tmp_path, presses_arrays, capsys):
    frames = _write_directory(tmp_path / "presses", *presses_arrays)
    out, report_path = tmp_path / "calib.msgpack", tmp_path / "report.json"
    # No --ball-radius-mm: the radius is estimated from this Lambertian gel, and said so.
    assert _calibrate_command([str(frames), "--mm-per-px", str(MM_PER_PX), "--out", str(out),
                               "--json", str(report_path), "--bins", "16"]) == 0
    printed = capsys.readouterr().out
    assert "estimated from the presses" in printed and "identifiable: yes" in printed
    assert "held-out presses (3)" in printed and "mean" in printed
    report = json.loads(report_path.read_text())
    assert report["held_out_presses"] == [3, 7, 11] and report["ball_radius_estimated"]
    assert report["ball_radius_mm"] == pytest.approx(BALL_RADIUS_MM, rel=0.05)
    assert report["held_out"]["mean"]["fitted_radius_mm"] == pytest.approx(report["ball_radius_mm"], rel=0.05)
    assert report["held_out"]["mean"]["mask_iou"] > 0.85
    model = load_shape_model(out)
    metadata = shape_model_metadata(out)
    assert model.preset == "lookup" and model.image_shape == (120, 160) and model.mm_per_px == MM_PER_PX
    assert metadata["ball_radius_mm"] == report["ball_radius_mm"] and metadata["ball_radius_estimated"] is True
    assert metadata["report"]["mask_threshold_mm"] == pytest.approx(float(model.params["mask_threshold_mm"]))


def test_calibrate_command_refuses_an_impossible_radius(tmp_path, presses_arrays):
    frames = _write_directory(tmp_path / "presses", *presses_arrays)
    with pytest.raises(ValueError, match="not smaller than the ball radius"):
        _calibrate_command([str(frames), "--mm-per-px", str(MM_PER_PX), "--out", str(tmp_path / "c.msgpack"),
                            "--ball-radius-mm", "1.0"])
    assert not (tmp_path / "c.msgpack").exists()
