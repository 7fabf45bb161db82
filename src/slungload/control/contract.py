"""What the MPC asks of its prediction model (``mppi.MPPIController``), numpy only: the
``CandidateModel`` contract, the in-flight ``ConstantsEstimate``, and whether a model has the
members ``MPCConfig.risk`` prices."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class CandidateModel(Protocol):
    """A prediction model for the controller, numpy in and out (float64 arrays): the
    ``models.prediction.PredictionModel`` contract's control entry point without torch. A
    model may also have ``prepare(M, K, N)`` (a GPU model captures its graph there): the
    controller calls it when built, so that what the model cannot run is an error then rather
    than a fallback in flight. An ensemble adds ``predict_candidates_members`` (E, K, N, 13)."""

    name: str
    history: int  # M: measured states the model needs (>= 2)

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray: ...


class ConstantsEstimate(Protocol):
    """The controller's in-flight estimate of the load: (x_hist (M, 13), u_past (M-1, 4)) ->
    (cable length m, load mass kg); ``mpc.window_estimate`` is the package's."""

    def __call__(self, x_hist: np.ndarray, u_past: np.ndarray) -> tuple[float, float]: ...


def has_members(model: object) -> bool:
    """Whether ``model`` predicts each member's states (an ensemble, a network paired with
    physics: ``predict_candidates_members``), which ``MPCConfig.risk`` prices."""
    return hasattr(model, "predict_candidates_members")


def priced(costs: np.ndarray, risk: float, weights: np.ndarray | None = None) -> np.ndarray:
    """(E, K) member costs -> (K,): their mean + ``risk`` x their spread (std), both weighted
    by ``weights`` (E,) where a model gives them (``member_weights``), else equal."""
    mean = np.average(costs, axis=0, weights=weights)
    return mean + risk * np.sqrt(np.average((costs - mean) ** 2, axis=0, weights=weights))


def check_members(model: CandidateModel, risk: float | None) -> None:
    """ValueError where ``risk`` (``MPCConfig.risk``) prices members and ``model`` has none."""
    if risk is not None and not has_members(model):
        raise ValueError(
            f"MPCConfig.risk prices each member's prediction: it needs an ensemble (slungload "
            f"train --ensemble K) or a network paired with physics (--with-physics), and "
            f"{getattr(model, 'name', 'the model')!r} is one network"
        )
