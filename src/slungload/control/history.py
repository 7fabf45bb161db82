"""The controller's history: the last M measured states and the inputs applied at them.

A prediction model (``models.prediction.PredictionModel``) takes them as
``predict_candidates(x_hist (M, 13), u_past (M - 1, 4), plans)``; ``History.window`` gives
exactly those two arrays (numpy, float64), padded with the first row until M steps have been
seen. numpy only: the onboard controller (``mppi``) keeps its history here without torch.
"""

from __future__ import annotations

import numpy as np


class History:
    """The last M measured states and the inputs applied at them (numpy, float64).

    ``push_state(x)`` at each control step before deciding, ``push_input(u)`` after. Until M
    states have been seen, the window is padded with the first state and input (the flight
    starts in hover).
    """

    def __init__(self, m: int) -> None:
        if m < 2:
            raise ValueError(f"History: need M >= 2, got {m}")
        self.m = m
        self.states: list[np.ndarray] = []
        self.inputs: list[np.ndarray] = []

    def push_state(self, x: np.ndarray) -> None:
        self.states = [*self.states, np.asarray(x, dtype=float)][-self.m :]

    def push_input(self, u: np.ndarray) -> None:
        self.inputs = [*self.inputs, np.asarray(u, dtype=float)][-(self.m - 1) :]

    def window(self, first_input: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x_hist (M, 13) and u_past (M-1, 4), float64 arrays; ``first_input`` pads the
        inputs before any was applied."""
        if not self.states:
            raise ValueError("History: no state pushed yet")
        xs = [self.states[0]] * (self.m - len(self.states)) + self.states
        us = self.inputs or [np.asarray(first_input, dtype=float)]
        us = [us[0]] * (self.m - 1 - len(us)) + us
        return np.stack(xs), np.stack(us[-(self.m - 1) :])
