"""The oracle prediction model: the simulator's own plant as the MPC's model (a benchmark).

``PlantCandidates`` meets ``mppi.CandidateModel``: at every control step it rolls each of the K
candidate plans out on a twin of the flight's plant (``sim.plant.Plant.fork``), from the true
state, with everything the simulator applies from Python (drag, downwash, latency, thrust scale
and sag, the rate loop, the thrust lag) and the wind held at its latest value (the future gusts
are the one thing it does not know). The MPC with this model shows how well *any* model could
do in this controller: the ceiling a learned model is measured against. Not real time: each
candidate steps MuJoCo N x ``SimConfig.substeps`` times from Python (about 0.3-0.5 s per
control step at K = 32, N = 15 on one core). ``mujoco.rollout`` alone would leave out the
Python-side forces and simulate another plant.

It needs the plant: ``sim.simulate_flight`` hands it to a controller with an ``attach`` method
(``mpc.SamplingMPC`` passes it on), so a fresh ``PlantCandidates`` per flight.
"""

from __future__ import annotations

import numpy as np

from ..layout import LOAD_POS, POS, QUAT, STATE_DIM, VEL
from ..sim.plant import Plant

ORACLE = "oracle"


class PlantCandidates:
    """The true plant as a numpy ``CandidateModel`` (see the module); one per flight."""

    name = ORACLE
    history = 2  # it reads the true state, not the measured history
    numpy = True  # numpy in and out: ``mpc.SamplingMPC`` takes it as it is

    def __init__(self) -> None:
        self.plant: Plant | None = None
        self.twin: Plant | None = None

    def attach(self, plant: Plant) -> None:
        """The flight's plant, before its first step."""
        self.plant = plant
        self.twin = plant.fork()

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """True states (K, N, 13) (q w-x-y-z) after each step of each plan (K, N, 4) (T N,
        omega rad/s), from the plant's state now; the measured history is not used."""
        if self.plant is None or self.twin is None:
            raise RuntimeError("the oracle needs the flight's plant: attach(plant) first")
        plant, twin = self.plant, self.twin
        states = np.empty((*plans.shape[:2], STATE_DIM))
        for i, plan in enumerate(plans):
            twin.sync(plant)
            for j, u in enumerate(plan):
                twin.advance(float(u[0]), u[1:], plant.wind)
                row = states[i, j]
                row[POS], row[VEL], row[QUAT], row[LOAD_POS] = (twin.p, twin.v, twin.q, twin.p_load)
        return states
