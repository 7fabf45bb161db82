"""An ensemble's members per candidate (``MPCConfig.members`` "split").

``SplitMembers(model, samples)`` is a numpy ``mppi.CandidateModel`` around an ensemble whose
members can be called one by one (``members``: the torch ensemble through
``mpc.candidate_model``, its compiled ``.mpc.npz`` onboard): candidate k is predicted by member
k mod E alone. The MPC then pays one network's compute at equal K, where "all" (every member
predicts every candidate) pays E x, and each candidate's cost is its own member's, as
risk-aware MPPI samples its dynamics: the weighted plan averages over the members' views of
the plans, not over one mean view. The members' joint call and the calibrated interval
(``tracked``) go through as they are. numpy only (the onboard path).
"""

from __future__ import annotations

import numpy as np

from ..layout import STATE_DIM
from .contract import CandidateModel, has_members

__all__ = ["ALL", "MEMBERS_HELP", "MEMBER_USES", "SPLIT", "SplitMembers"]

ALL, SPLIT = "all", "split"
# ``MPCConfig.members``: how an ensemble's members predict the K candidates (the CLI's help)
MEMBER_USES: dict[str, str] = {
    ALL: "every member predicts every candidate, E x one network's compute at equal K (the "
    "members' mean, or priced by --risk)",
    SPLIT: "candidate k by member k mod E alone, one network's compute at equal K (each "
    "candidate's cost its own member's)",
}
MEMBERS_HELP = (
    "how an ensemble's members predict the MPC's candidates: "
    + "; ".join(f"{name}: {text}" for name, text in MEMBER_USES.items())
    + " (docs/control.md)"
)


class SplitMembers:
    """``model``'s members (E numpy candidate models of one history) each predicting every
    E-th of ``samples`` candidates: ``predict_candidates`` (K, N, 13), member i rows i, i + E,
    ...; ``predict_candidates_members`` and the calibration are ``model``'s own."""

    numpy = True

    def __init__(self, model: CandidateModel, samples: int) -> None:
        members = tuple(getattr(model, "members", ()))
        name = getattr(model, "name", "the model")
        if len(members) < 2 or not has_members(model):
            raise ValueError(
                f"MPCConfig.members 'split' predicts each candidate with one member of an "
                f"ensemble, and {name!r} has no members to call one by one (a network paired "
                f"with physics, or an ensemble's .mpc.onnx graph, predicts them together: give "
                f"the ensemble folder or its .mpc.npz, or members 'all')"
            )
        if samples < len(members):
            raise ValueError(f"MPCConfig.members 'split': K = {samples} candidates for "
                             f"{len(members)} members; give K >= {len(members)}")  # fmt: skip
        self.model, self.members = model, members
        self.name, self.history = model.name, model.history
        self.horizon = getattr(model, "horizon", None)
        self.predict_candidates_members = model.predict_candidates_members
        self.calibration = getattr(model, "calibration", None)
        self.params = getattr(model, "params", None)
        if hasattr(model, "novel"):
            self.novel = model.novel

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13) float64: row k member k mod E's prediction of plan k."""
        e = len(self.members)
        out = np.empty((*plans.shape[:2], STATE_DIM), np.float64)
        for i, member in enumerate(self.members):
            out[i::e] = member.predict_candidates(x_hist, u_past, plans[i::e])
        return out

    def prepare(self, m: int, k: int, n: int) -> None:
        """Each member's ``prepare`` (where it has one) for its share of the K candidates."""
        e = len(self.members)
        for i, member in enumerate(self.members):
            prepare = getattr(member, "prepare", None)
            if prepare is not None:
                prepare(m, len(range(i, k, e)), n)
