"""Shared fixtures: one small sensor so that jitted functions compile once per session."""

import pytest

from tactojax.sensor import gelslim


@pytest.fixture(scope="session")
def small_spec():
    """GelSlim at a quarter resolution: 60 x 80 px, 0.4 mm/px, same 32 x 24 mm field of view."""
    return gelslim(scale=0.25)


@pytest.fixture(scope="session")
def calibration_dataset(tmp_path_factory, small_spec):
    """A small simulated calibration dataset: 3 calibration shapes x 40 touches at 60 x 80 px."""
    import jax

    from tactojax.io import simulate_to_dataset
    from tactojax.objects import get_object
    from tactojax.simulate import CalibrationProtocol

    path = tmp_path_factory.mktemp("data") / "calibration"
    for index, name in enumerate(["calib_sphere", "calib_semicone_1", "calib_semipyramid"]):
        simulate_to_dataset(path, jax.random.key(index), small_spec, get_object(name),
                            CalibrationProtocol(touches=40), progress=False)
    return path


@pytest.fixture(scope="session")
def shape_data(calibration_dataset):
    """The calibration dataset as in-memory (image, heightmap, mask) pairs."""
    from tactojax.io import load_shape_data

    return load_shape_data(calibration_dataset)
