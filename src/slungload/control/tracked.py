"""An ensemble flown by the MPC, its interval tracked in flight.

``TrackedMembers(model, calibration, window)`` is a numpy ``mppi.CandidateModel`` around a
calibrated ensemble (any with ``predict_candidates_members``: the torch ensemble through
``mpc.candidate_model``, its compiled or ONNX file onboard). Before each control step's
prediction it resolves the one a vehicle can check now: the members predict the last H =
min(window, N) states flown from the state H steps ago under the inputs since applied, and
their errors over the calibrated half width move ``online_interval.OnlineInterval``. While it
is ``surprised`` (errors some ``surprise`` times what the calibration expects: a longer cable,
where the members agree on a wrong prediction and the spread-based novelty flag stays silent)
the controller counts the step (``MPCStats.surprised_steps``). It flags; it does not change
the plans. A calibration fitted with the constants shift (``Calibration.constants_shift``)
gets it here too, against the constants the members learned (the model's ``params``, an
exported file's sidecar; else the ``constants`` given), by ``deploy.compiled.physics.
candidates_shift``: for the window resolved and for the nominal plan the novelty count asks
about (plan 0 of the last call). numpy only (the onboard path; Numba where the shift is asked).
"""

from __future__ import annotations

import numpy as np

from ..config import ESTIMATE_MIN_STEPS, VehicleParams
from ..deploy.members import calibration_of, members_half_width, members_mean
from ..online_interval import OnlineInterval, OnlineIntervalConfig, normalized_errors
from ..vehicle_constants import VehicleConstants
from .contract import CandidateModel, has_members
from .history import flown_window, history_tail

__all__ = ["TrackedMembers", "calibration_of"]


class TrackedMembers:
    """``model`` (an ensemble's numpy candidate model) whose interval is tracked over the
    last ``window`` steps flown; ``calibration``: its ``Calibration`` as a dict; ``constants``:
    the vehicle's, for a calibration with the constants shift where the model carries no
    ``params`` of its own (the members' constants, which the shift is measured against)."""

    numpy = True

    def __init__(
        self,
        model: CandidateModel,
        calibration: dict,
        window: int,
        config: OnlineIntervalConfig | None = None,
        constants: VehicleParams | VehicleConstants | None = None,
    ) -> None:
        if not has_members(model):
            raise ValueError(f"TrackedMembers: {getattr(model, 'name', model)!r} has no members")
        if window < 1:
            raise ValueError(f"TrackedMembers: window must be >= 1 step, got {window}")
        self.model, self.window, self.calibration = model, window, calibration
        self.constants: VehicleConstants | None = None
        if calibration.get("constants_shift"):
            learned = getattr(model, "params", None) or constants
            if learned is None:
                raise ValueError("TrackedMembers: a calibration with the constants shift needs "
                                 "the constants the members learned")  # fmt: skip
            if model.history < ESTIMATE_MIN_STEPS:
                raise ValueError(f"TrackedMembers: the constants shift needs M >= "
                                 f"{ESTIMATE_MIN_STEPS} history steps; {model.name} keeps "
                                 f"{model.history}")  # fmt: skip
            from ..deploy.compiled.physics import candidates_shift  # Numba: fail before flying

            self.constants, self._candidates_shift = VehicleConstants.of(learned), candidates_shift
        self.nominal: tuple[np.ndarray, ...] | None = None  # the last call's history, plan 0
        self.name = model.name
        self.history = model.history + window
        self.horizon = getattr(model, "horizon", None)
        self.tracker = OnlineInterval(window, calibration["level"], config)
        self.unresolved = 0  # windows whose prediction raised or was not finite
        if hasattr(model, "novel"):
            self.novel = self._novel

    def _shift(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray | None:
        """(K, N, 13) the plans' constants shift from the members' history, where the
        calibration widens by it; else None."""
        if self.constants is None:
            return None
        return self._candidates_shift(x_hist, u_past, plans, self.constants)

    def _novel(self, members: np.ndarray) -> np.ndarray:
        """The model's novelty flag of members (E, 1, N, 13) of the last call's nominal plan,
        with its constants shift where the calibration asks for it (a shift that cannot be
        computed flags nothing: the flag never changes a plan)."""
        if self.constants is None:
            return self.model.novel(members)
        if members.shape[1] != 1 or self.nominal is None:
            raise ValueError(
                "TrackedMembers.novel: the last call's nominal plan alone (E, 1, N, 13)"
            )
        try:
            with np.errstate(all="ignore"):
                return self.model.novel(members, self._shift(*self.nominal))
        except (ValueError, FloatingPointError):
            return np.zeros(1, bool)

    @property
    def surprised(self) -> bool:
        """The tracked interval's multiplier on some step and group beyond ``surprise``."""
        return self.tracker.surprised

    def resolve(self, x_hist: np.ndarray, u_past: np.ndarray, n: int) -> None:
        """Move the tracker by the prediction of the last H = min(window, n) states flown
        (padded to the plans' n steps: an exported ensemble's N is fixed). A prediction that
        raises or is not finite moves nothing (``unresolved`` counts it)."""
        h = min(self.window, n)
        w = flown_window(x_hist, u_past, h, n)
        with np.errstate(all="ignore"):
            try:
                then = history_tail(w.x_hist, w.u_past, self.model.history)
                members = self.model.predict_candidates_members(*then, w.plan)
                shift = self._shift(*then, w.plan)
            except (RuntimeError, ValueError):  # the plans' call decides the fallback
                self.unresolved += 1
                return
            members = np.asarray(members, np.float64)
            half = members_half_width(members, self.calibration, shift)
            ratio = normalized_errors(members_mean(members)[0, :h], half[0, :h], w.flown)
        if np.isfinite(ratio).all():
            self.tracker.update(ratio)
        else:
            self.unresolved += 1

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13): the members' mean, after resolving the window just flown."""
        self.resolve(x_hist, u_past, plans.shape[1])
        return self.model.predict_candidates(
            *history_tail(x_hist, u_past, self.model.history), plans
        )

    def predict_candidates_members(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(E, K, N, 13): each member's prediction, after resolving the window just flown."""
        self.resolve(x_hist, u_past, plans.shape[1])
        tail = history_tail(x_hist, u_past, self.model.history)
        self.nominal = (*tail, plans[:1])
        return self.model.predict_candidates_members(*tail, plans)

    def prepare(self, m: int, k: int, n: int) -> None:
        """The model's own warm-up, and the shift's compiled physics where it is asked (its
        first call compiles: seconds, not the first control step's)."""
        prepare = getattr(self.model, "prepare", None)
        if prepare is not None:
            prepare(self.model.history, k, n)
        if self.constants is not None:
            from ..deploy.compiled.columns import hovering  # with the shift's Numba kernels

            with np.errstate(all="ignore"):
                self._shift(*hovering(self.model.history, 1, n, self.constants))
