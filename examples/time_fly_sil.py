"""Time the MPC over MAVLink in real time: state received -> command sent, per control period.

    python examples/time_fly_sil.py MODEL.mpc.npz [--plant chain] [--samples 256]
        [--maneuver fast_8_lap_xyz] [--duration 15] [--flights 3]

Starts ``slungload sil --real-time`` (the simulator behind a MAVLink endpoint on 127.0.0.1) in a
subprocess for each flight, flies the exported model through ``autopilot.bridge.fly`` (arming
and switching to OFFBOARD itself), and prints per flight the median, p99 and largest latency
and how many steps took longer than the control period, and the interpreter's full garbage
collections in its process (the bridge collects once at its start and leaves what is alive
then out of the later ones: with it in, one takes 30-90 ms). Run it with nothing else on the
machine: the endpoint takes one core, the bridge another.
"""

from __future__ import annotations

import argparse
import gc
import os
import socket
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np

from slungload.autopilot.bridge import fly
from slungload.autopilot.config import BridgeConfig
from slungload.control.mppi import MPCConfig


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FullCollections:
    """The durations (ms) of the interpreter's generation-2 collections while installed."""

    def __init__(self) -> None:
        self.ms: list[float] = []
        self._start = 0.0

    def __call__(self, phase: str, info: dict) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            self._start = time.perf_counter()
        else:
            self.ms.append((time.perf_counter() - self._start) * 1e3)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="an exported MPC model (.mpc.npz or .mpc.onnx)")
    parser.add_argument("--plant", default="default", help="the simulated vehicle (default)")
    parser.add_argument("--samples", type=int, default=256, help="K (default 256)")
    parser.add_argument("--maneuver", default="fast_8_lap_xyz")
    parser.add_argument("--duration", type=float, default=15.0, help="s of MPC flight (15)")
    parser.add_argument("--flights", type=int, default=1)
    parser.add_argument("--fifo", type=int, metavar="PRIORITY",
                        help="run the endpoint and the bridge under the real-time FIFO "
                        "scheduler at this priority, 1-99 (Linux, root or CAP_SYS_NICE; as "
                        "`chrt -f PRIORITY slungload fly ...`)")  # fmt: skip
    args = parser.parse_args(argv)
    chrt = []
    if args.fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.fifo))
        chrt = ["chrt", "-f", str(args.fifo)]
    period = BridgeConfig().period
    for _ in range(args.flights):
        port = free_port()
        sil = subprocess.Popen(
            [*chrt, sys.executable, "-m", "slungload.cli", "sil", "--plant", args.plant,
             "--real-time", "--connection", f"udpout:127.0.0.1:{port}", "--duration",
             str(args.duration + 30)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        collections = FullCollections()
        gc.callbacks.append(collections)
        try:
            cfg = replace(BridgeConfig(), connection=f"udpin:127.0.0.1:{port}", arm=True,
                          offboard=True, maneuver=args.maneuver, duration=args.duration,
                          mpc=replace(MPCConfig(), samples=args.samples))  # fmt: skip
            result = fly(args.model, cfg)
        finally:
            gc.callbacks.remove(collections)
            sil.kill()
            sil.wait()
        ms = np.array(result.latency) * 1e3
        full = ", ".join(f"{t:.1f}" for t in collections.ms)
        print(f"{result.end}, {result.steps} steps: state -> command median "
              f"{np.median(ms):.2f}, p99 {np.percentile(ms, 99):.2f}, max {ms.max():.2f} ms; "
              f"over {period * 1e3:.0f} ms: {(ms > period * 1e3).sum()} of {len(ms)}; "
              f"full collections (ms; the model's imports and the bridge's own at its start "
              f"included): {full}")  # fmt: skip


if __name__ == "__main__":
    main()
