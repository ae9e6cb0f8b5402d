"""Shared fixtures: one small sensor so that jitted functions compile once per session.

Most of the suite's time is XLA compilation, and the same programs come back: in both xdist
workers (each builds the session fixtures), in the commands and notebook kernels the tests start,
and wherever a command or a test jits a new closure of the same computation. One compilation cache for the run serves them all: a temporary folder
made by the controller (every run starts cold, so timings stay honest), or the folder in
``TACTOJAX_TEST_JAX_CACHE`` if set (kept between runs, e.g. while iterating on one test);
``TACTOJAX_TEST_JAX_CACHE=off`` compiles everything afresh.
"""

import os
import subprocess
import sys
import tempfile

_QUICK_COMPILE = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")
"""The suite's programs are compiled far more than they run. Without LLVM's optimisation passes
XLA:CPU compiles them about a third faster, and with its older loop emitters instead of the MLIR
fusion emitters over twice as fast again (the belief's update: 5.9 against 2.5 s on 2 cores).
Set before the backend starts (importing tactojax starts it); the processes the tests start
inherit them."""


def _xla_knows(flag: str) -> bool:
    """Whether the installed XLA accepts ``flag`` (it aborts the process on an unknown one: a
    later jaxlib may drop a flag, and the suite must then run without it, not die)."""
    probe = subprocess.run([sys.executable, "-c", "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"],
                           env={**os.environ, "XLA_FLAGS": flag, "JAX_PLATFORMS": "cpu"}, capture_output=True)
    return probe.returncode == 0


for _flag in _QUICK_COMPILE:  # the controller probes; the workers inherit what it set
    if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", "") and _xla_knows(_flag):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_flag}".strip()

import jax  # noqa: E402
import pytest  # noqa: E402

from tactojax.sensor import gelslim  # noqa: E402

_CACHE_VARIABLE = "TACTOJAX_TEST_JAX_CACHE"


def pytest_configure(config):
    """Point JAX's persistent compilation cache at one folder shared by the run's processes."""
    if os.environ.get(_CACHE_VARIABLE) == "off":
        return
    if not os.environ.get(_CACHE_VARIABLE):  # the controller (or a run without xdist): workers inherit it
        os.environ[_CACHE_VARIABLE] = tempfile.mkdtemp(prefix="tactojax-jax-cache-")
        config.add_cleanup(_remove_cache_folder(os.environ[_CACHE_VARIABLE]))
    jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_VARIABLE])
    # Every program, however quick to compile: the eager operations (one small program each)
    # come back in every process, and together they take as long as the large ones.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # The same for the processes the tests start (commands, notebook kernels): JAX reads these.
    os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ[_CACHE_VARIABLE]
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"


def _remove_cache_folder(path):
    def remove():
        import shutil

        for variable in (_CACHE_VARIABLE, "JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"):
            os.environ.pop(variable, None)
        shutil.rmtree(path, ignore_errors=True)
    return remove


@pytest.fixture(scope="session")
def small_spec():
    """GelSlim at a quarter resolution: 60 x 80 px, 0.4 mm/px, same 32 x 24 mm field of view."""
    return gelslim(scale=0.25)


@pytest.fixture(scope="session")
def calibration_dataset(tmp_path_factory, small_spec):
    """A small simulated calibration dataset: 3 calibration shapes x 40 touches at 60 x 80 px."""
    import jax

    from tactojax.objects import get_object
    from tactojax.simulate import CalibrationProtocol, simulate_to_dataset

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


@pytest.fixture(scope="session")
def lookup_model(shape_data):
    """The classical lookup shape model fitted on the calibration dataset (all but 8 per shape)."""
    from tactojax.shape import fit_lookup_model, split_held_out

    train, _ = split_held_out(shape_data, 8)
    return fit_lookup_model(train, bins=16)


@pytest.fixture(scope="session")
def mapping_dataset(tmp_path_factory, small_spec):
    """A small mapping-protocol dataset of the Table II cylinder: 20 mm grid, yaw 0, all 4 turns."""
    import jax

    from tactojax.objects import get_object
    from tactojax.simulate import MappingProtocol, simulate_to_dataset

    path = tmp_path_factory.mktemp("data") / "mapping"
    simulate_to_dataset(path, jax.random.key(0), small_spec, get_object("cylinder"),
                        MappingProtocol(grid_mm=20.0, yaws_deg=(0.0,)),
                        progress=False)
    return path


@pytest.fixture(scope="session")
def cylinder_map(mapping_dataset, lookup_model):
    """The cylinder's tactile map built with the lookup model (predicted heightmaps)."""
    from tactojax.io import read_grasps
    from tactojax.mapping import build_tactile_map

    grasps = read_grasps(mapping_dataset)
    return build_tactile_map(lookup_model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                             grasps["object_id"], T_world_object=grasps["T_world_object"],
                             points_per_imprint=256, batch_size=16, progress=False)


@pytest.fixture(scope="session")
def gum_box_map(tmp_path_factory, small_spec, lookup_model):
    """A second object's map for identification: the gum box, 30 mm grid, yaw 0, all 4 turns."""
    import jax

    from tactojax.io import read_grasps
    from tactojax.mapping import build_tactile_map
    from tactojax.objects import get_object
    from tactojax.simulate import MappingProtocol, simulate_to_dataset

    path = tmp_path_factory.mktemp("data") / "gum_box"
    simulate_to_dataset(path, jax.random.key(1), small_spec, get_object("gum_box"),
                        MappingProtocol(grid_mm=30.0, yaws_deg=(0.0,)), progress=False)
    grasps = read_grasps(path)
    return build_tactile_map(lookup_model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                             grasps["object_id"], T_world_object=grasps["T_world_object"],
                             points_per_imprint=256, batch_size=16, progress=False)


@pytest.fixture(scope="session")
def tiny_encoder_path(tmp_path_factory):
    """A randomly initialised ResNetTiny encoder checkpoint (32 x 40 input) for CLI tests."""
    import jax

    from tactojax.features import init_encoder
    from tactojax.io import save_encoder

    encoder = init_encoder(jax.random.key(0), "resnet_tiny", (32, 40))
    return save_encoder(tmp_path_factory.mktemp("encoders") / "tiny.msgpack", encoder)
