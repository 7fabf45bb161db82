"""Time one control step of the MPC: torch (the simulator's ``SamplingMPC``, eager network and
the compiled backend) beside onboard (``MPPIController.from_file``: the compiled file on numpy
+ Numba, and the ONNX graph on ONNX Runtime), the same network, interleaved.

    python examples/time_onboard_mpc.py [--run RUN_DIR | --size NAME] [--samples 256]

Without ``--run`` the network is a physics-step network of the named size (``--size``, a name
of ``config.MODEL_SIZES``; default the paper's) with random weights and normalisation fitted on
synthetic physics windows (speed does not depend on the weights). One
thread for torch and for ONNX Runtime. Each round times ``--calls`` control steps of each
controller in turn (the order rotates between rounds); the measurements are
the states of a synthetic flight, replayed. Prints median and p99 wall-clock ms per step, the
calling thread's CPU ms, and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

import numpy as np
import torch

from slungload.config import ModelConfig, VehicleParams, WindowConfig
from slungload.control.mpc import SamplingMPC
from slungload.control.mppi import InputLimits, MPCConfig, MPPIController, ReferenceAhead
from slungload.deploy.candidates import export_for_mpc
from slungload.deploy.compiled import with_backend
from slungload.deploy.predictor import Predictor
from slungload.deploy.timing import time_calls
from slungload.lab.bench.benchmarks import physics_windows
from slungload.models import build
from slungload.models.prediction import NetworkModel


def predictor(run: Path | None, size: str | None = None) -> Predictor:
    if run is not None:
        return Predictor.from_checkpoint(run, threads=None)
    torch.manual_seed(0)
    window = WindowConfig(history=50, horizon=15)
    config = ModelConfig(architecture="physics-step")
    model = build(config if size is None else config.resized(size), VehicleParams())
    fit = physics_windows(64, window)
    model.fit_normalization(fit.states, fit.inputs, origin_step=window.history - 1)
    return Predictor(model.eval(), window, VehicleParams(), "no-physics", threads=None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path)
    parser.add_argument("--size", help="a network size by name (without --run)")
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--horizon", type=int, default=15)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--calls", type=int, default=30)
    args = parser.parse_args()
    torch.set_num_threads(1)
    pred = predictor(args.run, args.size)
    cfg = MPCConfig(samples=args.samples, horizon=args.horizon)
    limits = InputLimits(4.0, 30.0, 4.0)
    network = NetworkModel(pred.model, pred.window.history)
    with tempfile.TemporaryDirectory() as folder:
        exported = export_for_mpc(pred, Path(folder) / "m-onnx.mpc.onnx", horizon=args.horizon)
        compiled = export_for_mpc(
            pred, Path(folder) / "m.mpc.npz", horizon=args.horizon, format="compiled"
        )
        controllers = {
            "torch MPC (eager network)": SamplingMPC(network, limits, cfg).core,
            "torch MPC (compiled backend)": SamplingMPC(
                with_backend(network, "compiled"), limits, cfg
            ).core,
            "onboard MPC (compiled file)": MPPIController.from_file(compiled.model, limits, cfg),
            "onboard MPC (onnxruntime)": MPPIController.from_file(exported.model, limits, cfg),
        }
    flight = physics_windows(1, WindowConfig(history=100, horizon=args.horizon)).states[0]
    states = flight.double().numpy()
    n = args.horizon
    ref = ReferenceAhead(np.tile(states[0, :3], (n, 1)), np.zeros((n, 3)), np.zeros(n))
    steppers = {
        name: (lambda i, c=c: c.step(states[i % len(states)], ref))
        for name, c in controllers.items()
    }
    wall = {name: [] for name in steppers}
    cpu = {name: [] for name in steppers}
    load = [os.getloadavg()[0]]
    for r in range(args.rounds):
        shift = r % len(steppers)
        names = list(steppers)[shift:] + list(steppers)[:shift]  # rotate the order
        for name in names:
            w, c = time_calls(steppers[name], args.calls, warmup=3)
            wall[name] += w
            cpu[name] += c
    load.append(os.getloadavg()[0])
    size = args.run or f"random physics-step, size {args.size or 'paper'}"
    print(f"{size}: K = {args.samples}, N = {n}, M = {pred.window.history}, one thread, "
          f"{args.rounds} x {args.calls} steps each, interleaved; load average (1 min) "
          f"{load[0]:.2f} before, {load[1]:.2f} after, {os.cpu_count()} cores")  # fmt: skip
    base = np.array(wall["torch MPC (compiled backend)"])
    for name in steppers:
        ms = np.array(wall[name]) * 1e3
        ratio = (
            np.median(ms) / np.median(base) / 1e3,
            np.percentile(ms, 99) / np.percentile(base, 99) / 1e3,
        )
        print(f"{name}: median {np.median(ms):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, "
              f"CPU median {statistics.median(cpu[name]) * 1e3:.1f} ms; / compiled backend "
              f"{ratio[0]:.2f}x median, {ratio[1]:.2f}x p99")  # fmt: skip


if __name__ == "__main__":
    main()
