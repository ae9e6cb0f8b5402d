"""Import speed of ``tactojax.hardware.import_bag`` against plain ``rosbags`` reading of the same bag.

A synthetic session is written with ``rosbags``' own writers in each storage (ROS 2 sqlite3,
ROS 2 MCAP, ROS 1): ``--seconds`` of a 30 Hz camera at ``--height`` x ``--width`` rgb8, 100 Hz
joint states and gripper poses, one grasp every 2 s (the gripper closes, holds 0.7 s, opens).
Per storage, in one process: the reference (``AnyReader`` iterating and deserializing every
message of the three topics, images as numpy views, nothing decoded further) and the import
(two passes, grasp detection, pairing, rectification to gelslim at half resolution, writing
the dataset). Run from the repository root:

    python benchmarks/bag_import.py --json bag_import.json             # 60 s, 640 x 480
    python benchmarks/bag_import.py --seconds 10 --json quick.json
    python benchmarks/bag_import.py --quick              # smoke run: 4 s at 240 x 320
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import add_common_arguments, format_table, machine_info, write_json  # noqa: E402

from tactojax.hardware import import_bag  # noqa: E402
from tactojax.sensor import gelslim  # noqa: E402


def write_session(path: Path, kind: str, seconds: float, height: int, width: int, seed: int = 0) -> int:
    """Write the synthetic session; returns its size in bytes."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    serialize, types = (store.serialize_ros1 if ros1 else store.serialize_cdr), store.types
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=(
        StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3))
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 255, (height, width, 3), np.uint8) for _ in range(4)]

    def header(t):
        t = t + 1.0  # stamps start at 1 s (0 means "not stamped")
        stamp = types["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int((t - int(t)) * 1e9))
        return types["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=stamp, frame_id="")

    messages = []
    for t in np.arange(0, seconds, 0.01):
        local = t % 2.0
        width_mm = 80 - 50 * np.clip((local - 0.2) / 0.3, 0, 1) + 50 * np.clip((local - 1.2) / 0.3, 0, 1)
        messages.append((t, "/joint_states", types["sensor_msgs/msg/JointState"](
            header=header(t), name=["left", "right"], position=np.full(2, width_mm / 2000), velocity=np.zeros(2),
            effort=np.zeros(2))))
        pose = types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](x=0.1 * (t // 2), y=0, z=0.3),
                                               orientation=types["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1))
        messages.append((t, "/pose", types["geometry_msgs/msg/PoseStamped"](header=header(t), pose=pose)))
    for index, t in enumerate(np.arange(0, seconds, 1 / 30)):
        messages.append((t, "/image", types["sensor_msgs/msg/Image"](
            header=header(t), height=height, width=width, encoding="rgb8", is_bigendian=0, step=width * 3,
            data=frames[index % 4].reshape(-1))))
    messages.sort(key=lambda m: m[0])
    with writer:
        connections = {}
        for t, topic, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=store)
            writer.write(connections[topic], int((t + 1.0) * 1e9), serialize(message, message.__msgtype__))
    return sum(p.stat().st_size for p in ([path] if path.is_file() else path.iterdir()))


def read_everything(path: Path) -> int:
    """The reference: iterate and deserialize every message with rosbags' AnyReader."""
    from rosbags.highlevel import AnyReader

    count = 0
    with AnyReader([path]) as reader:
        for connection, _, raw in reader.messages():
            reader.deserialize(raw, connection.msgtype)
            count += 1
    return count


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--width", type=int, default=640)
    add_common_arguments(parser, quick="4 s of a 240 x 320 camera", seed_help="the synthetic camera frames")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.height, args.width = min(args.seconds, 4.0), min(args.height, 240), min(args.width, 320)
    return args


def one_storage(args, scratch: Path, kind: str) -> dict:
    """Write the session in one storage, read it with rosbags, import it: sizes and seconds."""
    spec = gelslim(scale=0.5)
    aspect = spec.width_px / spec.height_px
    corners = [[0, 0], [args.height * aspect, 0], [args.height * aspect, args.height], [0, args.height]]
    bag = scratch / ("session.bag" if kind == "ros1" else f"session-{kind}")
    size = write_session(bag, kind, args.seconds, args.height, args.width, args.seed)
    start = time.perf_counter()
    messages = read_everything(bag)
    reference_s = time.perf_counter() - start
    start = time.perf_counter()
    summary = import_bag(bag, scratch / f"out-{kind}", spec, image_topic="/image", pose_topic="/pose",
                         gripper_topic="/joint_states", corners=corners, progress=False)
    import_s = time.perf_counter() - start
    frames = summary.image_messages
    return {"bag_mb": size / 1e6, "messages": messages, "image_messages": frames, "touches": summary.recorded,
            "reference_s": reference_s, "import_s": import_s, "import_frames_per_s": frames / import_s,
            "import_mb_per_s": size / 1e6 / import_s}


def main() -> None:
    args = parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        results = {kind: one_storage(args, Path(scratch), kind) for kind in ("sqlite3", "mcap", "ros1")}
    rows = [[kind, f"{r['bag_mb']:.0f}", r["image_messages"], r["touches"], r["reference_s"], r["import_s"],
             r["import_frames_per_s"], r["import_s"] / r["reference_s"]] for kind, r in results.items()]
    print(format_table(["storage", "MB", "frames", "touches", "rosbags read (s)", "import (s)", "import frames/s",
                        "import / read"], rows))
    if args.json:
        write_json(args.json, {"machine": machine_info(), "seconds": args.seconds, "height": args.height,
                               "width": args.width, "seed": args.seed, "results": results})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
