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

The veto has a blind side: a network that is wrong everywhere (another vehicle's) calls good
plans bad too, and mean + risk x spread lets it veto physics's plans. With a ``window`` of H
steps the pair first asks each member to predict the H steps just flown, from the state H steps
ago under the inputs that were applied: while the network's position error (vehicle and load)
is above ``ratio`` x physics's + ``floor``, it has no say and physics prices the plans alone
(``trusted`` False; the controller counts those steps, ``MPCStats.physics_only_steps``).

While trusted, each member's cost is weighted by its record over the same window
(``WEIGH_BY_RECORD``): weights 1 / (error + ``floor``)^2, the mean and the spread both
weighted (``contract.priced``). Equal errors give the plain pair; on a network's own vehicle,
where physics predicted the window 2-3x worse, physics no longer prices 75 % of a plan it
calls worse (risk 0.5: 0.75 x the worse + 0.25 x the better) but 25-40 %.
"""

from __future__ import annotations

import math

import numpy as np

from ..layout import LOAD_POS, POS
from .contract import CandidateModel
from .history import flown_window, history_tail

# steps (0.75 s) each member predicts of the path just flown, at most the plans' N: as long as
# the N = 25 the MPC plans with, a network right over 0.3 s and wrong over 0.75 s has no say
# (10 steps left three networks of other vehicles 0.8-12 % worse than physics)
TRUST_WINDOW = 25
TRUST_RATIO = 1.0  # the network takes part while its error is at most this x physics's ...
TRUST_FLOOR = 0.01  # m, + this (RMS over the window's steps and the six position components)
# a trusted network's cost and physics's weighted by 1 / (error over the window + floor)^2
WEIGH_BY_RECORD = True


def trust_steps(window: int | None, with_physics: bool) -> int:
    """A pair's window from a config: ``window`` as given, ``TRUST_WINDOW`` when None; 0 without
    physics. A window given without physics, or below 0, is a ``ValueError``."""
    if window is not None and (window < 0 or (window and not with_physics)):
        raise ValueError("--trust-window is the network's audit against physics: give "
                         f"--with-physics, and 0 steps or more (got {window})")  # fmt: skip
    if not with_physics:
        return 0
    return TRUST_WINDOW if window is None else window


class PhysicsPaired:
    """``network`` and ``physics`` (numpy candidate models) as one model of two members.

    window: steps of the flown path each member predicts before the network may take part (0:
    it always does, the veto alone); ratio, floor: the network takes part while its RMS position
    error over them is at most ratio x physics's + floor (m). ``trusted``: whether it took part
    in the last ``predict_candidates_members``; ``errors``: the two errors (m) that decided it.
    """

    numpy = True

    def __init__(
        self,
        network: CandidateModel,
        physics: CandidateModel,
        window: int = TRUST_WINDOW,
        ratio: float = TRUST_RATIO,
        floor: float = TRUST_FLOOR,
        weigh: bool | None = None,
    ) -> None:
        if window < 0 or not (ratio > 0 and floor >= 0):
            raise ValueError(f"PhysicsPaired: need window >= 0, ratio > 0 and floor >= 0; got "
                             f"{window}, {ratio}, {floor}")  # fmt: skip
        self.network, self.physics = network, physics
        self.window, self.ratio, self.floor = window, ratio, floor
        self.history = max(network.history, physics.history) + window
        self.name = f"{network.name}+physics" + (f"-trust{window}" if window else "")
        self.horizon = getattr(network, "horizon", None)
        self.weigh = WEIGH_BY_RECORD if weigh is None else weigh
        self.trusted = True
        self.errors = (math.nan, math.nan)
        self.member_weights: np.ndarray | None = None  # (2,), read by the controller's price

    def _call(self, model: CandidateModel, x_hist, u_past, plans) -> np.ndarray:
        last = history_tail(x_hist, u_past, model.history)
        return np.asarray(model.predict_candidates(*last, plans), dtype=np.float64)

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13): the network's prediction."""
        return self._call(self.network, x_hist, u_past, plans)

    def predict_candidates_members(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(2, K, N, 13): the network's prediction, then the physics model's; physics's twice
        when the network predicted the window just flown worse (``trusted`` False)."""
        physics = self._call(self.physics, x_hist, u_past, plans)
        self.trusted = not self.window or self._trust(x_hist, u_past, plans.shape[1])
        self.member_weights = None
        if self.trusted and self.window and self.weigh:
            self.member_weights = (np.asarray(self.errors) + self.floor) ** -2.0
        if not self.trusted:
            return np.stack([physics, physics])
        return np.stack([self._call(self.network, x_hist, u_past, plans), physics])

    def _trust(self, x_hist: np.ndarray, u_past: np.ndarray, n: int) -> bool:
        """Each member predicts the last H = min(window, n) measured states from the one H steps
        before them under the inputs applied since (padded to the plans' n steps: an exported
        network's N is fixed); the network is trusted unless its position error is larger."""
        h = min(self.window, n)
        w = flown_window(x_hist, u_past, h, n)
        errors = []
        for model in (self.network, self.physics):
            with np.errstate(all="ignore"):  # a diverging network is what this looks for
                got = self._call(model, w.x_hist, w.u_past, w.plan)
            got, flown = got[0, :h], w.flown
            diff = np.concatenate([got[:, POS] - flown[:, POS],
                                   got[:, LOAD_POS] - flown[:, LOAD_POS]], axis=1)  # fmt: skip
            errors.append(float(np.sqrt(np.mean(diff**2))))
        self.errors = (errors[0], errors[1])
        return math.isfinite(errors[0]) and errors[0] <= self.ratio * errors[1] + self.floor

    def prepare(self, m: int, k: int, n: int) -> None:
        for model in (self.network, self.physics):
            prepare = getattr(model, "prepare", None)
            if prepare is not None:
                prepare(model.history, k, n)
