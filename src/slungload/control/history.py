"""The controller's history: the last M measured states and the inputs applied at them.

A prediction model (``models.prediction.PredictionModel``) takes them as
``predict_candidates(x_hist (M, 13), u_past (M - 1, 4), plans)``; ``History.window`` gives
exactly those two arrays (numpy, float64), padded with the first row until M steps have been
seen. numpy only: the onboard controller (``mppi``) keeps its history here without torch.
"""

from __future__ import annotations

from typing import NamedTuple

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


def history_tail(x_hist: np.ndarray, u_past: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The last m states (m, 13) of ``x_hist`` and the m - 1 inputs between them: what a model
    of history M = m is given from a longer history (a pair's, a tracked ensemble's)."""
    return x_hist[len(x_hist) - m :], u_past[len(u_past) - (m - 1) :]


class FlownWindow(NamedTuple):
    """The last h steps flown, as a prediction model is asked them: the history ending h steps
    ago, the inputs applied since as one plan padded to n steps, the states flown since."""

    x_hist: np.ndarray  # (M', 13): every state up to h steps ago
    u_past: np.ndarray  # (M' - 1, 4)
    plan: np.ndarray  # (1, n, 4): the h inputs applied since, the last held to n steps
    flown: np.ndarray  # (h, 13)


def flown_window(x_hist: np.ndarray, u_past: np.ndarray, h: int, n: int) -> FlownWindow:
    """Cut ``x_hist`` (M, 13), ``u_past`` (M - 1, 4) at h steps ago (h <= n: an exported model's
    N is fixed, so the plan is padded to the plans' n steps): what the pair's trust window and
    an ensemble's tracked interval both ask the models to predict."""
    applied = u_past[len(u_past) - h :]
    plan = np.concatenate([applied, np.repeat(applied[-1:], n - h, axis=0)])[None]
    return FlownWindow(x_hist[: len(x_hist) - h], u_past[: len(u_past) - h], plan,
                       x_hist[len(x_hist) - h :])  # fmt: skip
