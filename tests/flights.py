"""Synthetic flights of the paper's discrete model, shared by the test modules.

Plain helpers (not fixtures): each test module picks its own sizes and seeds.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from slungload.config import VehicleParams
from slungload.data.flight import estimate_load_state
from slungload.physics import hover_thrust, rollout
from slungload.state import QUAT, join_state

WXYZ_TO_XYZW = [1, 2, 3, 0]  # written out here, independently of state.py's helpers


def roll_out_flight(
    x0: torch.Tensor, aux0: torch.Tensor, inputs: torch.Tensor, params: VehicleParams
) -> tuple[np.ndarray, np.ndarray]:
    """The discrete model driven from x0 (13,), aux0 (6,) by inputs (T, 4), x_{k+1} = f(x_k, u_k):
    states (T, 13) and aux (T, 6), the first row being x0, aux0 (the last input is unused)."""
    states, aux = rollout(x0, aux0, inputs[:-1], params)
    return torch.cat([x0[None], states]).numpy(), torch.cat([aux0[None], aux]).numpy()


def swinging_flight(name: str, seed: int, steps: int = 40) -> SimpleNamespace:
    """A flight of the physics model (package layout): rolled, swinging, smoothly varying inputs;
    aux estimated from the states as for real data. Fields: name, states, inputs, aux."""
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
    states, _ = roll_out_flight(
        x0, torch.zeros(6, dtype=torch.float64), torch.from_numpy(u), params
    )
    return SimpleNamespace(
        name=name, states=states, inputs=u, aux=estimate_load_state(states, params)
    )


def file_rows(states: torch.Tensor, inputs: torch.Tensor) -> np.ndarray:
    """Package-layout states (..., T, 13) and inputs (..., T, 4) -> file rows (..., T, 17)."""
    s = states.double().numpy().copy()
    s[..., QUAT] = s[..., QUAT][..., WXYZ_TO_XYZW]
    return np.concatenate([s, inputs.double().numpy()], axis=-1)


def stop_gracefully_on_sigterm(marker: str) -> str:
    """A stand-in for a training run in a pool worker: writes ``marker`` once running, then
    waits; SIGTERM makes it raise (as Lightning's graceful stop ends ``train`` with
    ``TrainingInterrupted``) instead of killing the process."""
    import signal
    import time
    from pathlib import Path

    def on_sigterm(signum, frame):
        raise RuntimeError("stopped by SIGTERM")

    signal.signal(signal.SIGTERM, on_sigterm)
    Path(marker).write_text("running")
    time.sleep(120)
    return "done"
