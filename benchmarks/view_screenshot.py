"""Screenshot of ``tactojax view --serve`` in a real headless Chromium (the web view check of issue 18).

Needs Debian's Chromium and its WebDriver (``apt-get install -y chromium chromium-driver``; not
part of CI, which has no apt step) and the ``viz`` extra. The script builds nothing: give it the
maps, test dataset and estimates that ``tactojax view`` takes. It starts ``tactojax view ...
--serve`` on localhost, drives Chromium through chromedriver's W3C WebDriver HTTP API (standard
library only: no selenium), waits for the viewer to stream and draw the recording, saves the
screenshot, and stops both processes it started. Run from the repository root, e.g.:

    tactojax simulate gum_box --scale 0.5 --grid-mm 20 --yaws-deg 0 --out data/gum
    tactojax simulate gum_box --scale 0.5 --grid-mm 30 --yaws-deg 20 --turns-deg 0 90 --out data/gum-test
    tactojax map data/gum --out gum.npz
    python benchmarks/view_screenshot.py gum.npz --test data/gum-test --example-estimates est.json --out view.png

``--example-estimates PATH`` writes (then shows) stand-in estimates of the test touches: their true
poses shifted by N(0, 2 mm) per axis (``--seed``, default 0), probability 0.8, and on every odd touch a belief
of four hypotheses (0.6, 0.25, 0.1, 0.05) spread 0, 4, 8, 12 mm: the README's screenshot.
"""

from __future__ import annotations

import argparse
import base64
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import add_common_arguments, machine_info, write_json  # noqa: E402

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--enable-unsafe-swiftshader"]


def write_example_estimates(test: str, path: str, seed: int = 0) -> None:
    import numpy as np

    from tactojax.viz import read_test_touches

    touches = read_test_touches(test)
    rng = np.random.default_rng(seed)
    entries = []
    for index, (object_id, pose) in enumerate(zip(touches["object_id"], touches["T_object_sensor"])):
        estimate = pose.copy()
        estimate[4:] += rng.normal(0, 2, 3)
        entry = {"object_id": str(object_id), "T_object_sensor_wxyz_xyz": estimate.tolist(), "probability": 0.8,
                 "touch": index}
        if index % 2 == 1:  # touch 9 (the last, shown) has a belief
            hypotheses = []
            for k, probability in enumerate([0.6, 0.25, 0.1, 0.05]):
                hypothesis = pose.copy()
                hypothesis[4:] += rng.normal(0, 4, 3) * k
                hypotheses.append({"T_object_sensor_wxyz_xyz": hypothesis.tolist(), "probability": probability})
            entry["belief"] = hypotheses
        entries.append(entry)
    Path(path).write_text(json.dumps(entries))


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def webdriver(port: int, method: str, path: str, payload: dict | None = None) -> dict:
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}", method=method,
                                     data=None if payload is None else json.dumps(payload).encode(),
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=120) as response:
        return json.loads(response.read())


def wait_for_line(process: subprocess.Popen, prefix: str, timeout_s: float) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line and process.poll() is not None:
            raise RuntimeError(f"tactojax view exited with {process.returncode}")
        if line.startswith(prefix):
            return line
    raise TimeoutError(f"tactojax view printed no {prefix!r} line in {timeout_s} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maps", nargs="+")
    parser.add_argument("--test")
    parser.add_argument("--estimates")
    parser.add_argument("--example-estimates", metavar="PATH", help="write stand-in estimates there and show them")
    parser.add_argument("--out", default="view.png")
    parser.add_argument("--wait-s", type=float, default=25.0, help="time the viewer gets to load and draw")
    parser.add_argument("--size", default="1600,1000")
    add_common_arguments(parser, quick="5 s for the viewer to draw", seed_help="stand-in estimates")
    args = parser.parse_args()
    if args.quick:
        args.wait_s = min(args.wait_s, 5.0)
    for tool in ("chromium", "chromedriver"):
        if shutil.which(tool) is None:
            sys.exit(f"{tool} not found: apt-get install -y chromium chromium-driver")
    if args.example_estimates:
        if not args.test:
            sys.exit("--example-estimates needs --test")
        write_example_estimates(args.test, args.example_estimates, args.seed)
        args.estimates = args.example_estimates
    web_port, grpc_port, driver_port = free_port(), free_port(), free_port()
    view = [sys.executable, "-c", "import sys; from tactojax.cli import main; sys.exit(main(sys.argv[1:]))",
            "view", *args.maps, "--serve", "--web-port", str(web_port),
            "--grpc-port", str(grpc_port)]
    view += ["--test", args.test] if args.test else []
    view += ["--estimates", args.estimates] if args.estimates else []
    server = subprocess.Popen(view, stdout=subprocess.PIPE, text=True)
    driver = subprocess.Popen(["chromedriver", f"--port={driver_port}"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        url = wait_for_line(server, "web viewer:", 300).split()[2]
        print(f"serving {url}", flush=True)
        with tempfile.TemporaryDirectory() as profile:
            flags = CHROMIUM_FLAGS + [f"--user-data-dir={profile}", f"--window-size={args.size}"]
            capabilities = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {
                "binary": shutil.which("chromium"), "args": flags}}}}
            time.sleep(1.0)
            session = webdriver(driver_port, "POST", "/session", capabilities)["value"]["sessionId"]
            try:
                webdriver(driver_port, "POST", f"/session/{session}/url", {"url": url})
                time.sleep(args.wait_s)
                png = base64.b64decode(webdriver(driver_port, "GET", f"/session/{session}/screenshot")["value"])
            finally:
                webdriver(driver_port, "DELETE", f"/session/{session}")
        Path(args.out).write_bytes(png)
        print(f"screenshot: {args.out} ({len(png)} bytes)")
        if args.json:
            write_json(args.json, {"screenshot": args.out, "bytes": len(png), "wait_s": args.wait_s,
                                   "size": args.size, "seed": args.seed, "machine": machine_info()})
    finally:
        for process in (driver, server):
            process.terminate()
            process.wait(timeout=30)


if __name__ == "__main__":
    main()
