"""A network and the physics model priced together: each plan must look good under both.

``PhysicsPaired(network, physics)`` is a numpy ``mppi.CandidateModel`` whose two members are a
network and the first-principles model (both numpy candidate models: ``mpc.candidate_model``
of either, or exported files). Its ``predict_candidates`` is the network's alone; its
``predict_candidates_members`` (2, K, N, 13) is what ``MPCConfig.risk`` prices: a plan's cost
is the mean of its two costs + risk x their spread, so ``risk`` = 1 charges the worse of the
two (a plan the network likes and physics does not costs what physics says) and 0 their
mean. Where the network is right and physics wrong, the network's plans still win whenever
physics does not call them worse; where the network leaves what it was trained on (a new
plant, few flights), physics vetoes the plans only the network believes in. docs/control.md,
"A network vetoed by physics". numpy only.
"""

from __future__ import annotations

import numpy as np

from .mppi import CandidateModel


class PhysicsPaired:
    """``network`` and ``physics`` (numpy candidate models) as one model of two members."""

    numpy = True

    def __init__(self, network: CandidateModel, physics: CandidateModel) -> None:
        self.network, self.physics = network, physics
        self.history = max(network.history, physics.history)
        self.name = f"{network.name}+physics"
        self.horizon = getattr(network, "horizon", None)

    def _call(self, model: CandidateModel, x_hist, u_past, plans) -> np.ndarray:
        m = model.history  # the last M measured states and the M - 1 inputs between them
        return np.asarray(model.predict_candidates(x_hist[-m:], u_past[len(u_past) - (m - 1):],
                                                   plans), dtype=np.float64)  # fmt: skip

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13): the network's prediction."""
        return self._call(self.network, x_hist, u_past, plans)

    def predict_candidates_members(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(2, K, N, 13): the network's prediction, then the physics model's."""
        return np.stack([self._call(self.network, x_hist, u_past, plans),
                         self._call(self.physics, x_hist, u_past, plans)])  # fmt: skip

    def prepare(self, m: int, k: int, n: int) -> None:
        for model in (self.network, self.physics):
            prepare = getattr(model, "prepare", None)
            if prepare is not None:
                prepare(model.history, k, n)
