"""The oracle prediction model: the simulator's own plant as the MPC's model (a benchmark).

``PlantCandidates`` meets ``mppi.CandidateModel``: at every control step it flies the K
candidate plans from the flight's true state on copies of its plant, with everything the
simulator applies from Python (drag, downwash, latency, thrust scale and sag, the rate loop,
the thrust lag) and the wind held at its latest value (the future gusts are the one thing it
does not know). The MPC with this model shows how well a perfect model does in this controller
(measured: no better than the learned one, docs/BENCHMARKS.md). Not real time: the K
candidates step MuJoCo N x ``SimConfig.substeps`` times (``plant_batch.PlantBatch``: one
``mujoco.rollout`` call per substep, the Python-side forces batched in numpy between the calls;
``mujoco.rollout`` over whole plans would leave those forces out and simulate another plant).

It needs the plant: ``sim.simulate_flight`` hands it to a controller with an ``attach`` method
(``mpc.SamplingMPC`` passes it on), so a fresh ``PlantCandidates`` per flight.
"""

from __future__ import annotations

import numpy as np

from ...layout import LOAD_POS, POS, QUAT, STATE_DIM, VEL
from ...sim.chain import ChainPlant
from ...sim.plant import Plant
from .config import ORACLE
from .plant_batch import lookahead


class PlantCandidates:
    """The true plant as a numpy ``CandidateModel`` (see the module); one per flight."""

    name = ORACLE
    history = 2  # it reads the true state, not the measured history
    numpy = True  # numpy in and out: ``mpc.SamplingMPC`` takes it as it is

    def __init__(self, threads: int = 1) -> None:
        self.threads = threads  # MuJoCo threads stepping the candidates
        self.batch = None

    def attach(self, plant: Plant | ChainPlant) -> None:
        """The flight's plant, before its first step."""
        self.batch = lookahead(plant, self.threads)

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """True states (K, N, 13) (q w-x-y-z) after each step of each plan (K, N, 4) (T N,
        omega rad/s), from the plant's state now; the measured history is not used."""
        if self.batch is None:
            raise RuntimeError("the oracle needs the flight's plant: attach(plant) first")
        plant = self.batch.plant
        flown = self.batch.advance(np.asarray(plans, dtype=float), plant.wind)
        states = np.empty((*plans.shape[:2], STATE_DIM))
        states[..., POS], states[..., VEL] = flown["p"], flown["v"]
        states[..., QUAT], states[..., LOAD_POS] = flown["q"], flown["p_load"]
        return states
