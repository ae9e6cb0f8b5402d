#!/usr/bin/env bash
# The GPU figures of the benchmarks page (benchmarks/results/gpu.json): batched evaluation
# throughput, the belief update, the next-grasp ranking and the live loop (the frame's parts; the loop
# with 20 frames held per grasp), on a map and its new-grasps test set (two fingers).
#   bash benchmarks/gpu_figures.sh MAP.npz TEST_DIR OUT_DIR
# Set JAX_PLATFORMS=cpu for the same figures on the CPU of the same machine.
set -uo pipefail
map=$1 test=$2 out=$3
mkdir -p "$out"
cd "$(dirname "$0")/.."
python3 -c "import jax; print('jax', jax.__version__, jax.devices())"
python3 benchmarks/batch_eval.py "$map" --test "$test" --touch-batch-size 32 --episode-batch-size 8 --repeats 2 \
    --json "$out/batch_eval.json"
python3 benchmarks/belief_speed.py "$map" --test "$test" --episodes 8 --json "$out/belief_speed.json"
python3 benchmarks/active_ranking.py "$map" --test "$test" --episodes 4 --json "$out/active_ranking.json"
python3 benchmarks/live_frame.py "$map" --test "$test" --json "$out/live_frame.json"
python3 benchmarks/live.py "$map" --test "$test" --fingers 2 --episodes 8 --hold 20 --gap 20 --no-reference \
    --json "$out/live.json"
