"""The evaluations sharded over two devices equal the single-device ones.

A CPU shows two devices with ``XLA_FLAGS=--xla_force_host_platform_device_count=2``, which
must be set before JAX starts: the two-device run is a subprocess (started first, so that it
runs beside this process's single-device run), fed the session's small map and episodes.
"""

import os
import pickle
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from tactojax.localize.evaluation import evaluate_localization, evaluate_new_grasps

REPOSITORY = Path(__file__).resolve().parents[2]

ON_TWO_DEVICES = """
import pickle, sys
import jax
from tactojax.localize.evaluation import evaluate_localization, evaluate_new_grasps

assert jax.device_count() == 2, jax.devices()
with open(sys.argv[1], "rb") as file:
    case = pickle.load(file)
out = {}
if case["leave_one_out"]:
    errors = evaluate_localization(jax.random.key(0), case["map"], case["leave_one_out"], **case["options"])
    out["leave_one_out"] = {name: vars(e) for name, e in errors.items()}
if case["new_grasps"]:
    results = evaluate_new_grasps(case["view"], case["episodes"], case["new_grasps"], **case["new_options"])
    out["new_grasps"] = [vars(r) for r in results]
with open(sys.argv[2], "wb") as file:
    pickle.dump(out, file)
"""

FIELDS = ("rmse", "symmetric_rmse", "translation", "rotation", "probability")


def compare_on_two_devices(tmp_path, case):
    """Start the two-device run of ``case``, run it here on one device meanwhile, and check
    that every per-query error and probability agrees."""
    with open(tmp_path / "case.pkl", "wb") as file:
        pickle.dump(jax.device_get(case), file)
    env = {**os.environ, "JAX_PLATFORMS": "cpu",
           "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2".strip()}
    process = subprocess.Popen([sys.executable, "-c", ON_TWO_DEVICES, str(tmp_path / "case.pkl"),
                                str(tmp_path / "out.pkl")], cwd=REPOSITORY, env=env, stderr=subprocess.PIPE, text=True)
    assert jax.device_count() == 1
    here = {}
    if case["leave_one_out"]:
        errors = evaluate_localization(jax.random.key(0), case["map"], case["leave_one_out"], **case["options"])
        here["leave_one_out"] = {name: vars(e) for name, e in errors.items()}
    if case["new_grasps"]:
        here["new_grasps"] = [vars(r) for r in evaluate_new_grasps(case["view"], case["episodes"], case["new_grasps"],
                                                                    **case["new_options"])]
    _, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr[-3000:]
    with open(tmp_path / "out.pkl", "rb") as file:
        there = pickle.load(file)
    pairs = [(here["leave_one_out"][name], there["leave_one_out"][name]) for name in here.get("leave_one_out", {})]
    pairs += list(zip(here.get("new_grasps", []), there.get("new_grasps", []), strict=True))
    assert pairs
    for one, two in pairs:
        assert one["method"] == two["method"]
        for field in FIELDS:
            np.testing.assert_allclose(two[field], one[field], rtol=1e-4, atol=1e-4, err_msg=f"{one['method']} {field}")
        if "imprint_index" in one:
            np.testing.assert_array_equal(two["imprint_index"], one["imprint_index"])
    return here


def test_sharded_baselines_equal_the_single_device_run(tmp_path, bumps_map, bumps_view, bumps_episodes):
    """Leave-one-out CTI (25 queries, 8 per device and call: padded chunks) and new grasps'
    single touches with CTI-ICP-1 (4 touches, 2 per device)."""
    here = compare_on_two_devices(tmp_path, {
        "map": bumps_map, "leave_one_out": ["cti"], "options": {"chunk_size": 8},
        "view": bumps_view, "episodes": bumps_episodes, "new_grasps": ["cti-icp-1"], "new_options": {}})
    assert len(here["leave_one_out"]["cti"]["rmse"]) == 25 and len(here["new_grasps"][0]["rmse"]) == 4


@pytest.mark.slow  # the belief compiles for minutes on 2 cores
def test_sharded_belief_equals_the_single_device_run(tmp_path, bumps_map, bumps_view, bumps_episodes, belief_settings):
    """The belief: leave-one-out in 3 folds, and new grasps' single touches and fused episodes."""
    compare_on_two_devices(tmp_path, {
        "map": bumps_map, "leave_one_out": ["belief"],
        "options": {"belief_settings": belief_settings, "folds": 3, "chunk_size": 4, "pad_to_multiple": 1},
        "view": bumps_view, "episodes": bumps_episodes, "new_grasps": ["belief"],
        "new_options": {"settings": belief_settings}})
