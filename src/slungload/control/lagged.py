"""The physics model fed what the vehicle receives of the MPC's plans (``MPCConfig.input_lag``).

``with_input_lag(model, lag, dt)`` wraps a numpy candidate model so that its physics model
predicts each plan through the commands' first-order lags (``input_lag.lagged``), the filter
warmed on the commands just flown: the physics model alone, or the physics half of a pair
(``paired.PhysicsPaired``). A network, an ensemble or the oracle flies as it is: it learned,
or is, the vehicle's response, lag included. numpy only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..input_lag import check_lag, lagged, warm_rows
from ..reporting import PHYSICS_LABEL
from .contract import CandidateModel
from .history import history_tail
from .paired import PhysicsPaired


class LaggedPhysics:
    """A physics candidate model (numpy) predicting plans through the commands' lags: it keeps
    ``warm_rows`` more history than the model, whose commands warm the filter."""

    numpy = True

    def __init__(self, physics: CandidateModel, lag: Sequence[float], dt: float) -> None:
        self.physics, self.lag, self.dt = physics, check_lag(lag), dt
        self.name = physics.name
        self.history = physics.history + warm_rows(self.lag, dt)
        if hasattr(physics, "prepare"):  # a compiled or graphed model's warm-up, passed on
            self.prepare = self._prepare

    def _prepare(self, m: int, k: int, n: int) -> None:
        """``mppi.CandidateModel.prepare`` for the model's own history (it gets the tail)."""
        self.physics.prepare(self.physics.history, k, n)

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """x_hist (M, 13), u_past (M-1, 4), plans (K, N, 4) -> states (K, N, 13): the model's
        prediction of the plans as the vehicle receives them."""
        received = lagged(u_past, plans, self.lag, self.dt)
        last = history_tail(x_hist, u_past, self.physics.history)
        return np.asarray(self.physics.predict_candidates(*last, received), dtype=np.float64)


def with_input_lag(model: CandidateModel, lag: Sequence[float], dt: float) -> CandidateModel:
    """``model`` with its physics model fed through ``lag`` (s; ``input_lag.LAG_CHANNELS``),
    rows dt s apart: the physics model itself, or a pair with its physics half so wrapped (a
    new pair); any other model, or no lag: ``model`` as it is."""
    if not any(check_lag(lag)):
        return model
    if isinstance(model, PhysicsPaired):
        return PhysicsPaired(model.network, LaggedPhysics(model.physics, lag, dt), model.window,
                             model.ratio, model.floor, model.weigh)  # fmt: skip
    if model.name != PHYSICS_LABEL:  # a network, an ensemble, the oracle: no physics to feed
        return model
    return LaggedPhysics(model, lag, dt)
