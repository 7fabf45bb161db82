"""The README's nine flights through ``slungload fly`` and the simulated PX4, beside the same
flights of ``slungload control``.

    python examples/sil_against_control.py RUN MODEL.mpc.npz [--real-time] [--samples 32]
        [--maneuvers baf_very_fast,roll_35,fast_8_lap_xyz] [--seeds 100,101,102] [--steps N]
        [--plant default] [--out results.json]

RUN: what ``slungload control --model RUN --backend compiled`` flies in process (a trained run,
or "physics"); MODEL: the same model exported (``slungload export RUN --for-mpc --format
compiled --out MODEL.mpc.npz``; for physics ``slungload export physics --for-mpc ...``). For each
maneuver and seed: the in-process flight (``lab.control.comparison.compare``, the code of
``slungload control``), then ``slungload sil --maneuver M --seed S --start-on-offboard`` in a
subprocess (lockstep, or ``--real-time``: its own core) and the bridge here, flying from the
simulator's start point with its warm-up as ``--settle``, its arena as ``--box``, its thrust and
rate limits as the MPC's box. A SIL flight is scored as ``control`` scores its own (measured
states, cut where the vehicle leaves the simulator's arena). Prints per flight both load
RMSEs, their relative difference, the largest state difference over the steps both flew and,
in real time, the latency from state received to command sent.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
from dataclasses import replace

import numpy as np

from slungload.autopilot.bridge import Bridge
from slungload.autopilot.config import BridgeConfig
from slungload.control.closed_loop import Arena, FlightLog, flight_metrics
from slungload.control.mppi import InputLimits, MPCConfig, knots_for
from slungload.deploy.backends import load_exported
from slungload.lab.control.comparison import compare
from slungload.lab.control.config import ComparisonConfig
from slungload.layout import POS
from slungload.models.prediction import PHYSICS
from slungload.sim.flight import flight_setup
from slungload.sim.maneuvers import ARENA_BOX
from slungload.sim.plants import plant_config


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def through_sil(args, model, sim, maneuver: str, seed: int) -> tuple[FlightLog, list[float]]:
    """One flight through the simulated PX4: its log as ``control`` logs a flight, latencies."""
    port = free_port()
    hover = sim.total_mass * sim.gravity
    cmd = [sys.executable, "-m", "slungload.cli", "sil", "--plant", args.plant,
           "--maneuver", maneuver, "--seed", str(seed), "--start-on-offboard",
           "--hover-throttle", repr(hover / sim.max_thrust), "--lockstep-wait", "10",
           "--connection", f"udpout:127.0.0.1:{port}"]  # fmt: skip
    if args.steps:
        cmd += ["--steps", str(args.steps)]
    if args.real_time:
        cmd.append("--real-time")
    start = flight_setup(maneuver, seed, sim, args.steps).plant.p
    mpc = MPCConfig(samples=args.samples, horizon=args.horizon, knots=knots_for(args.horizon))
    cfg = BridgeConfig(
        connection=f"udpin:127.0.0.1:{port}", offboard=True, maneuver=maneuver, seed=seed,
        duration=args.steps and args.steps * sim.control_dt, settle=sim.warmup,
        origin=(*map(float, start), 0.0), box=ARENA_BOX, newtons_per_throttle=sim.max_thrust,
        rate_max=sim.max_rate, mpc=mpc, fence_radius=10.0, fence_height=10.0, max_tilt=3.0,
        connect_timeout=60.0,
    )  # fmt: skip
    sil = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        bridge = Bridge(cfg, model, model.params)
        result = bridge.run()
    finally:
        sil.kill()
        sil.wait()
    states, commands = np.array(result.states), np.array(result.commands)
    # cut where the simulator's arena would have stopped the flight (before that state's step)
    arena = Arena()
    out = [k for k, x in enumerate(states) if arena.outside(x[POS])]
    n = out[0] if out else len(states)
    warm = round(sim.warmup / sim.control_dt)
    t = (np.arange(n) - warm) * sim.control_dt
    log = FlightLog(maneuver, seed, "sil", len(bridge.reference.yaw) - warm, t, states[:n],
                    bridge.reference.position[:n], commands[:n], np.zeros(n),
                    "left the arena" if out else None)  # fmt: skip
    return log, result.latency


def main(argv: list[str] | None = None) -> None:
    default = ComparisonConfig()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="what `slungload control --model` flies (or physics)")
    parser.add_argument("model", help="the same model exported (.mpc.npz)")
    parser.add_argument("--plant", default=default.plant)
    parser.add_argument("--samples", type=int, default=MPCConfig.samples)
    parser.add_argument("--horizon", type=int, default=default.horizon)
    parser.add_argument("--maneuvers", default=",".join(default.maneuvers))
    parser.add_argument("--seeds", default=",".join(map(str, default.seeds)))
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--real-time", action="store_true")
    parser.add_argument("--out", default=None, help="a JSON file of the rows")
    args = parser.parse_args(argv)
    maneuvers, seeds = args.maneuvers.split(","), [int(s) for s in args.seeds.split(",")]
    sim = plant_config(args.plant)
    config = replace(default, maneuvers=tuple(maneuvers), seeds=tuple(seeds),
                     samples=(args.samples,), horizon=args.horizon, steps=args.steps,
                     backend="compiled", plant=args.plant)  # fmt: skip
    runs = [] if args.run == PHYSICS else [args.run]
    flown = compare(runs, None, config, progress=None)
    physics = args.run == PHYSICS
    own = {(log.maneuver, log.seed): log for log in flown.logs
           if log.controller.startswith("mpc-") and log.controller.startswith("mpc-physics")
           == physics}  # fmt: skip
    model = load_exported(args.model)
    limits = InputLimits.from_sim(sim)
    rows = []
    for maneuver in maneuvers:
        for seed in seeds:
            inproc = own[(maneuver, seed)]
            sil, latency = through_sil(args, model, sim, maneuver, seed)
            a = flight_metrics(inproc, limits, sim.cable_length)
            b = flight_metrics(sil, limits, sim.cable_length)
            n = min(len(inproc.states), len(sil.states))
            diff = float(np.abs(inproc.states[:n] - sil.states[:n]).max())
            ms = np.array(latency) * 1e3
            row = dict(maneuver=maneuver, seed=seed, control=a["load_rmse"], sil=b["load_rmse"],
                       relative=b["load_rmse"] / a["load_rmse"] - 1, state_diff=diff,
                       control_lost=a["stopped"], sil_lost=b["stopped"],
                       latency_median=float(np.median(ms)),
                       latency_p99=float(np.percentile(ms, 99)),
                       late=int((ms > sim.control_dt * 1e3).sum()), periods=len(ms))  # fmt: skip
            rows.append(row)
            print(f"{maneuver} s{seed}: load RMSE control {a['load_rmse']:.6f} m, sil "
                  f"{b['load_rmse']:.6f} m ({100 * row['relative']:+.4f} %), largest state "
                  f"difference {diff:.2e}, lost {bool(a['stopped'])} / {bool(b['stopped'])}; "
                  f"latency {row['latency_median']:.1f} / {row['latency_p99']:.1f} ms, "
                  f"{row['late']} of {len(ms)} late", flush=True)  # fmt: skip
    both = [r for r in rows if not r["control_lost"] and not r["sil_lost"]]
    if both:
        c, s = np.mean([r["control"] for r in both]), np.mean([r["sil"] for r in both])
        print(f"{len(both)} flights both finished: load RMSE control {c:.4f} m, sil {s:.4f} m "
              f"({100 * (s / c - 1):+.3f} %)")  # fmt: skip
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
