"""Plain helpers shared by the test modules: synthetic flights and their file forms, and the
tiny training settings.

Each concept has one implementation here. ``conftest.py`` serves them to the tests as
fixtures (``physics_flight``, ``write_dataset``, ...); a test module imports from here only
what it needs at import time (module constants, parametrisation, code run in a subprocess)
or a plain converter (``file_rows``, ``predict_args``). Test modules never import from each
other.

Two kinds of flight:

* ``physics_flight``: rolled out by the paper's discrete model itself (package layout), so
  the physics-only predictor reproduces it exactly; ``file_arrays`` writes it in the
  published schema.
* ``flight_arrays``: analytic, in the published schema: a vehicle on a smooth curve with a
  load swinging on a cone of half-angle 0.3 rad around it (what the reader tests check).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from slungload.config import ModelConfig, VehicleParams, WindowConfig, to_dict
from slungload.fileio import write_json, write_npz, write_splits
from slungload.physics import hover_thrust, rollout
from slungload.state import QUAT, join_state

WXYZ_TO_XYZW = [1, 2, 3, 0]  # written out here, independently of state.py's helpers

# The tiny network and short windows of every test that trains (a run takes seconds).
TINY = ModelConfig(embed_sizes=(16, 16), hidden_size=8, num_layers=1, head_sizes=(16,), dropout=0)
SMALL = WindowConfig(history=6, horizon=4)
WINDOW_ARGS = ("--history", str(SMALL.history), "--horizon", str(SMALL.horizon))  # on the CLI
# The loads' tests: flights of loads drawn from ranges, their windows, an adaptive network.
ADAPTIVE_WINDOW = WindowConfig(history=50, horizon=25, stride=7)
ADAPTIVE = ModelConfig(
    architecture="physics-step", embed_sizes=(16, 16, 16), hidden_size=8, num_layers=2,
    head_sizes=(16, 16, 16), constants="window",
)  # fmt: skip
VARIED_LOADS = {"load_mass": (0.08, 0.30), "cable_length": (0.5, 1.0)}  # SimConfig.with_loads


class Flight(NamedTuple):
    """A flight in the package layout: states (T, 13) w-x-y-z, inputs (T, 4), aux (T, 6)."""

    name: str
    states: np.ndarray
    inputs: np.ndarray
    aux: np.ndarray


def roll_out_flight(
    x0: torch.Tensor, aux0: torch.Tensor, inputs: torch.Tensor, params: VehicleParams
) -> tuple[np.ndarray, np.ndarray]:
    """The discrete model driven from x0 (13,), aux0 (6,) by inputs (T, 4), x_{k+1} = f(x_k, u_k):
    states (T, 13) and aux (T, 6), the first row being x0, aux0 (the last input is unused)."""
    states, aux = rollout(x0, aux0, inputs[:-1], params)
    return torch.cat([x0[None], states]).numpy(), torch.cat([aux0[None], aux]).numpy()


def physics_flight(name: str, seed: int = 0, steps: int = 40) -> Flight:
    """A flight of the paper's discrete model: rolled up to 0.3 rad, a swinging load, thrust
    near hover and smoothly varying body rates. aux is the model's own (vL, Omega_L), so the
    physics-only predictor reproduces the flight (read from a file, aux is estimated)."""
    params = VehicleParams()
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * params.dt
    roll = rng.uniform(-0.3, 0.3)
    q0 = torch.tensor([np.cos(roll), np.sin(roll), 0.0, 0.0], dtype=torch.float64)
    p0 = torch.tensor(rng.uniform(-2, 2, 3))
    swing = torch.tensor([rng.uniform(-0.2, 0.2), 0.0, -0.67])
    x0 = join_state(p0, torch.zeros(3, dtype=torch.float64), q0, p0 + swing)
    u = np.zeros((steps, 4))
    u[:, 0] = hover_thrust(params) * (1 + 0.05 * np.sin(3 * t + seed))
    u[:, 1:] = 0.3 * np.sin(2 * t[:, None] + rng.uniform(0, 6, 3))
    states, aux = roll_out_flight(
        x0, torch.zeros(6, dtype=torch.float64), torch.from_numpy(u), params
    )
    return Flight(name, states, u, aux)


def conical_swing(t: np.ndarray, theta: float = 0.3, rate: float = 3.0) -> np.ndarray:
    """Unit cable directions (T, 3) of a load circling at ``theta`` rad from the vertical,
    ``rate`` rad/s, below the vehicle."""
    return np.stack(
        [
            np.sin(theta) * np.cos(rate * t),
            np.sin(theta) * np.sin(rate * t),
            -np.cos(theta) + 0 * t,
        ],
        axis=1,
    )


def flight_arrays(steps: int = 60, *, dt: float = 0.03, t0: float = 0.0, seed: int = 0) -> dict:
    """An analytic flight in the published schema; ``seed`` shifts the phases."""
    t = t0 + dt * np.arange(steps)
    phase = 0.7 * seed
    p = np.stack([np.sin(0.5 * t + phase), 0.5 * np.cos(0.3 * t), 1.0 + 0.1 * t], axis=1)
    v = np.stack([0.5 * np.cos(0.5 * t + phase), -0.15 * np.sin(0.3 * t), 0.1 + 0 * t], axis=1)
    yaw = 0.2 * t + phase
    attitude = np.stack([0 * t, 0 * t, np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)  # x-y-z-w
    xi = conical_swing(t)
    return {
        "time": t,
        "p": p,
        "v": v,
        "attitude": attitude,
        "p_load": p + VehicleParams().cable_length * xi,
        "w_ref": np.stack([0.1 * np.sin(t), 0 * t, 0.2 + 0 * t], axis=1),
        "T_ref": (14.2 + 0.1 * np.sin(t))[:, None],
    }


def file_rows(states: torch.Tensor, inputs: torch.Tensor) -> np.ndarray:
    """Package-layout states (..., T, 13) and inputs (..., T, 4) -> file rows (..., T, 17)."""
    s = states.double().numpy().copy()
    s[..., QUAT] = s[..., QUAT][..., WXYZ_TO_XYZW]
    return np.concatenate([s, inputs.double().numpy()], axis=-1)


def predict_args(windows) -> tuple[np.ndarray, np.ndarray]:
    """Windows -> the arguments of ``predict``: history file rows (W, M, 17), future inputs
    (W, N, 4), float64."""
    m = windows.window.history
    history = file_rows(windows.states[:, :m], windows.inputs[:, :m])
    return history, windows.inputs[:, m:].double().numpy()


def file_arrays(flight: Flight) -> dict[str, np.ndarray]:
    """A package-layout flight in the published file schema (quaternion x-y-z-w)."""
    rows = file_rows(torch.from_numpy(flight.states), torch.from_numpy(flight.inputs))
    return {
        "time": VehicleParams().dt * np.arange(len(rows)),
        "p": rows[:, 0:3],
        "v": rows[:, 3:6],
        "attitude": rows[:, 6:10],
        "p_load": rows[:, 10:13],
        "T_ref": rows[:, 13:14],
        "w_ref": rows[:, 14:17],
    }


def write_dataset(
    folder: Path,
    lengths: Mapping[str, int] | None = None,
    splits: Mapping[str, list[str]] | None = None,
    *,
    physics: bool = False,
    vehicle: bool = True,
) -> Path:
    """A dataset folder: flights ``name -> steps`` as .npz files, split lists, vehicle.json.

    lengths: default four flights f0 ... f3 of 40 steps. Flight i is ``flight_arrays(steps,
    seed=i)``, or with ``physics`` ``physics_flight(name, i, steps)`` in the file schema.
    splits: default all but the last two flights in train, the second last in val, the last
    in test. vehicle: write the paper's constants to vehicle.json (False: no file).
    """
    lengths = lengths or {f"f{i}": 40 for i in range(4)}
    folder.mkdir(parents=True, exist_ok=True)
    for i, (name, steps) in enumerate(lengths.items()):
        if physics:
            arrays = file_arrays(physics_flight(name, i, steps))
        else:
            arrays = flight_arrays(steps, seed=i)
        write_npz(folder / f"{name}.npz", arrays)
    if splits is None:
        names = list(lengths)
        if len(names) < 3:
            raise ValueError("write_dataset: name the splits of fewer than three flights")
        splits = {"train": names[:-2], "val": names[-2:-1], "test": names[-1:]}
    write_splits(folder, splits)
    if vehicle:
        write_json(folder / "vehicle.json", to_dict(VehicleParams()))
    return folder


def stop_gracefully_on_sigterm(marker: str) -> str:
    """A stand-in for a training run in a pool worker: writes ``marker`` once running, then
    waits; SIGTERM makes it raise (as Lightning's graceful stop ends ``train`` with
    ``TrainingInterrupted``) instead of killing the process."""
    import signal
    import time

    def on_sigterm(signum, frame):
        raise RuntimeError("stopped by SIGTERM")

    signal.signal(signal.SIGTERM, on_sigterm)
    Path(marker).write_text("running")
    time.sleep(120)
    return "done"
