"""A trained model behind numpy in, numpy out: the facade for embedding it in a controller.

    predictor = Predictor.from_checkpoint("runs/proposed")   # a run folder or a .ckpt
    states = predictor.predict(history, future_inputs)        # (N, 13)

Columns follow the data files (``layout.HISTORY_COLUMNS``): quaternions are **x-y-z-w** here,
as in the files, while the package works in w-x-y-z inside (``layout.py``); the conversion
happens only at this edge. ``history`` row k holds x_k then u_k::

    p (3) m | v (3) m/s | q x-y-z-w (4) | pL (3) m | T (1) N | omega (3) rad/s    (17 columns)

``future_inputs`` holds u_M ... u_{M+N-1} (T, omega); the result holds x_M ... x_{M+N-1} in
the first 13 columns' layout, with a unit quaternion. The network's recursion uses u_{M-1}
(the last history row) and u_M ... u_{M+N-2}; the last future input does not change the result.

``inputs.check_inputs`` is the one gate every predictor (this one, ``CompiledPredictor``,
``OnnxPredictor``) calls. ``flight_window`` cuts those arrays, and the true
future states, out of a ``data.Flight``. ``Predictor`` runs on one torch thread by default
(``threads``), as a control loop wants: more threads cost more than they save at batch 1.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np
import torch
from torch import Tensor, nn

from ..config import VehicleParams, WindowConfig
from ..constants_estimate import constants_shift
from ..layout import (
    INPUT_DIM,
    QUAT,
    STATE_DIM,
    WXYZ_TO_XYZW,
)
from ..models.checkpoints import load_checkpoint
from ..models.ensemble import Calibration, read_manifest, spread
from ..models.lstm_attention import SlungLoadNet
from ..online_interval import OnlineInterval, OnlineIntervalConfig, normalized_errors
from ..state import (
    quat_continuous,
    quat_normalize,
    quat_wxyz_to_xyzw,
    quat_xyzw_to_wxyz,
    with_unit_quaternion,
)
from .inputs import check_inputs, unbatch

# Largest |difference| from this eager predictor, physical units, that a faster path (the ONNX
# export, the compiled predictor) may show on real windows; checked at export and in tests.
PARITY_TOLERANCE = 1e-4


def states_to_file(states: Tensor) -> Tensor:
    """(..., 13) package layout (q w-x-y-z) -> file layout (q x-y-z-w)."""
    out = states.clone()
    out[..., QUAT] = quat_wxyz_to_xyzw(states[..., QUAT])
    return out


def states_from_file(states: Tensor) -> Tensor:
    """(..., T, 13) file layout (q x-y-z-w) -> package layout (q w-x-y-z), prepared as the
    data module prepares flights: unit quaternions without sign jumps along the time axis."""
    out = states.clone()
    out[..., QUAT] = quat_continuous(quat_normalize(quat_xyzw_to_wxyz(states[..., QUAT])))
    return out


class FileLayoutNet(nn.Module):
    """The network behind file-layout arrays: what ``Predictor`` runs and ``export`` writes.

    history (B, M, 17) rows x_k, u_k with q x-y-z-w; future_inputs (B, N, 4) u_M ... u_{M+N-1}
    -> states (B, N, 13) x_M ... x_{M+N-1}, q x-y-z-w with unit norm. The slack outputs are
    dropped.
    """

    def __init__(self, model: SlungLoadNet) -> None:
        super().__init__()
        self.model = model

    def forward(self, history: Tensor, future_inputs: Tensor) -> Tensor:
        x_hist = states_from_file(history[..., :STATE_DIM])
        pred = self.model(x_hist, history[..., STATE_DIM:], future_inputs)
        return states_to_file(with_unit_quaternion(pred.states))


@dataclass
class Predictor:
    """A trained network predicting N future states from M past states and inputs.

    threads: torch intra-op threads during ``predict`` (set for the call, then restored);
    1 by default, the fastest at batch 1 on a machine that also runs a controller. None
    leaves torch's setting alone. any_history: accept histories of any length M >= 1 (the
    network runs, but was trained on ``window.history`` rows); by default another length is
    refused.
    """

    model: SlungLoadNet
    window: WindowConfig  # the M and N it was trained with (other horizons also work)
    params: VehicleParams
    variant: str
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    threads: int | None = 1
    any_history: bool = False
    network: FileLayoutNet = field(init=False, repr=False)  # ``model`` behind file layouts

    def __post_init__(self) -> None:
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"Predictor: threads must be >= 1 or None, got {self.threads}")
        self.network = FileLayoutNet(self.model)

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        *,
        device: str | torch.device = "cpu",
        threads: int | None = 1,
        any_history: bool = False,
    ) -> Predictor:
        """Load a run folder (its ``best.ckpt``) or a ``.ckpt`` written by ``train``.

        threads: torch threads during ``predict`` (default 1; None: torch's setting).
        """
        loaded = load_checkpoint(path)
        device = torch.device(device)
        return cls(
            loaded.model.to(device).eval(),
            loaded.window,
            loaded.params,
            loaded.variant,
            device,
            threads=threads,
            any_history=any_history,
        )

    @property
    def history(self) -> int:
        """M, the number of past rows ``predict`` expects (the window it was trained with)."""
        return self.window.history

    def predict(self, history: np.ndarray, future_inputs: np.ndarray) -> np.ndarray:
        """Predict the next N states.

        history (M, 17) or (B, M, 17): rows x_k, u_k (file convention, see the module doc),
        M = ``self.history``; future_inputs (N, 4) or (B, N, 4): T (N), omega (rad/s) at steps
        M ... M+N-1. Returns (N, 13) or (B, N, 13) float64 states, quaternion unit and x-y-z-w.
        """
        hist, fut, single = check_inputs(
            history, future_inputs, history_rows=None if self.any_history else self.history
        )
        dtype = next(self.model.parameters()).dtype
        with torch_threads(self.threads), torch.inference_mode():
            h = torch.as_tensor(hist, dtype=dtype, device=self.device)
            u_future = torch.as_tensor(fut, dtype=dtype, device=self.device)
            states = self.network(h, u_future)
        return unbatch(states.cpu().numpy(), single)


class Interval(NamedTuple):
    """An ensemble's prediction (file layout, as ``Predictor.predict``'s) with its interval."""

    mean: np.ndarray  # (N, 13) or (B, N, 13): the members' mean, unit quaternion x-y-z-w
    half_width: np.ndarray  # same shape: the interval is mean +- half_width
    novel: np.ndarray  # () or (B,) bool: the spread is beyond what the calibration saw
    surprised: bool = False  # the tracked interval: resolved errors beyond the calibration's


@dataclass
class EnsemblePredictor:
    """An ensemble folder (``models.ensemble``) behind numpy: ``predict`` gives the members'
    mean as ``Predictor.predict`` does; ``predict_interval`` adds the calibrated interval and
    the novelty flag (the model outside what it has seen; needs a calibrated ensemble).

    In flight, ``resolve`` feeds it the prediction whose steps have all been flown; the
    interval is then the one tracked in flight (``online_interval``: widened per step and
    state group where resolved predictions missed it) and ``Interval.surprised`` says when
    the model's errors run beyond its calibration's by ``tracking.surprise``."""

    members: tuple[Predictor, ...]
    calibration: Calibration | None = None
    tracking: OnlineIntervalConfig = field(default_factory=OnlineIntervalConfig)
    tracker: OnlineInterval | None = field(default=None, repr=False)

    @classmethod
    def from_folder(
        cls,
        path: str | Path,
        *,
        device: str | torch.device = "cpu",
        threads: int | None = 1,
        any_history: bool = False,
    ) -> EnsemblePredictor:
        manifest = read_manifest(path)
        members = tuple(
            Predictor.from_checkpoint(m, device=device, threads=threads, any_history=any_history)
            for m in manifest.members
        )
        return cls(members, manifest.calibration)

    @property
    def history(self) -> int:
        return self.members[0].history

    def _members(self, history: np.ndarray, future_inputs: np.ndarray) -> tuple[Tensor, bool]:
        """(E, B, N, 13) float64 in the package layout (q w-x-y-z), and whether unbatched."""
        single = np.asarray(history).ndim == 2
        out = [m.predict(history, future_inputs) for m in self.members]
        states = torch.as_tensor(np.stack([o[None] if single else o for o in out]))
        return states_from_file(states.double()), single

    def _calibration(self) -> Calibration:
        if self.calibration is None:
            raise ValueError("an uncalibrated ensemble states no interval: slungload calibrate")
        return self.calibration

    def _shift(self, history: np.ndarray, future_inputs: np.ndarray) -> Tensor | None:
        """(B, N, 13) float64: the windows' constants shift against the members' constants
        where the calibration widens the spread by it (``Calibration.constants_shift``)."""
        if not self._calibration().constants_shift:
            return None
        hist, fut, _ = check_inputs(history, future_inputs, caller="EnsemblePredictor")
        h = torch.as_tensor(hist, dtype=torch.float64)
        u_future = torch.as_tensor(fut, dtype=torch.float64)
        x_hist = states_from_file(h[..., :STATE_DIM])
        return constants_shift(x_hist, h[..., STATE_DIM:], u_future, self.members[0].params)

    def predict(self, history: np.ndarray, future_inputs: np.ndarray) -> np.ndarray:
        """The members' mean, as ``Predictor.predict`` (same arguments and layout)."""
        states, single = self._members(history, future_inputs)
        return unbatch(states_to_file(spread(states).mean).numpy(), single)

    def predict_interval(
        self, history: np.ndarray, future_inputs: np.ndarray, level: float | None = None
    ) -> Interval:
        """The mean, the half width of the ``level`` interval (default the calibration's;
        tracked in flight once ``resolve`` has been called, its multipliers tracked at the
        calibration's level) and the novelty flag per window."""
        calibration = self._calibration()
        states, single = self._members(history, future_inputs)
        mean, std = spread(states)
        shift = self._shift(history, future_inputs)
        half = calibration.half_width(std, level, shift)
        if self.tracker is not None:
            factor = self.tracker.component_multiplier(half.shape[-2])
            half = half * torch.as_tensor(factor, dtype=half.dtype)
        half[..., QUAT] = half[..., QUAT][..., list(WXYZ_TO_XYZW)]  # the file's x-y-z-w
        novel = calibration.novel(std, shift).numpy()
        return Interval(
            unbatch(states_to_file(mean).numpy(), single),
            unbatch(half.numpy(), single),
            novel[0] if single else novel,
            self.tracker is not None and self.tracker.surprised,
        )

    def resolve(self, history: np.ndarray, applied_inputs: np.ndarray, flown: np.ndarray) -> None:
        """Feed the tracked interval one resolved prediction, file layout: ``history`` (M, 17)
        ending at the step the prediction starts from, ``applied_inputs`` (N, 4) the inputs
        applied since (as ``predict``'s future_inputs), ``flown`` (N, 13) the states flown
        since. Once per control step with the window N steps back keeps it current."""
        calibration = self._calibration()
        flown = np.asarray(flown, dtype=np.float64)
        n = np.asarray(applied_inputs).shape[-2]
        if flown.shape != (n, STATE_DIM):
            raise ValueError(
                f"EnsemblePredictor.resolve: flown must be ({n}, {STATE_DIM}) like "
                f"applied_inputs' {n} steps, got {flown.shape}"
            )
        states, _ = self._members(history, applied_inputs)
        mean, std = spread(states[:, 0])
        shift = self._shift(history, applied_inputs)
        half = calibration.half_width(std, shift=None if shift is None else shift[0])
        truth = states_from_file(torch.as_tensor(flown))
        if self.tracker is None:
            self.tracker = OnlineInterval(calibration.horizon, calibration.level, self.tracking)
        self.tracker.update(normalized_errors(mean.numpy(), half.numpy(), truth.numpy()))


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """torch on ``threads`` intra-op threads inside the block, restored after (None: as is)."""
    before = torch.get_num_threads()
    if threads is None or threads == before:
        yield
        return
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


# --- cutting predict's arguments from a flight ---------------------------------------------


class FlightLike(Protocol):
    """What ``flight_window`` reads: a ``data.Flight`` or anything with its two arrays."""

    states: np.ndarray  # (T, 13), package layout: quaternion w-x-y-z
    inputs: np.ndarray  # (T, 4): T_ref (N), w_ref (rad/s)


class FlightWindow(NamedTuple):
    """``predict``'s arguments cut from a flight, and what it should answer (file layout)."""

    history: np.ndarray  # (M, 17): x_k, u_k for k = start ... start+M-1, q x-y-z-w
    future_inputs: np.ndarray  # (N, 4): u_k for the N steps after the history
    truth: np.ndarray  # (N, 13): the measured x_k at those N steps, q x-y-z-w


def flight_window(flight: FlightLike, start: int, *, history: int, horizon: int) -> FlightWindow:
    """M = ``history`` rows from step ``start`` and the N = ``horizon`` steps after them.

    flight: a ``data.Flight`` (``read_flight``), states in the package layout (w-x-y-z); the
    result is in the file layout ``predict`` takes (x-y-z-w), so that
    ``predictor.predict(w.history, w.future_inputs)`` compares with ``w.truth``.
    """
    states = np.asarray(flight.states, dtype=np.float64)
    inputs = np.asarray(flight.inputs, dtype=np.float64)
    shape_ok = states.ndim == 2 and states.shape[1] == STATE_DIM
    if not shape_ok or inputs.shape != (len(states), INPUT_DIM):
        raise ValueError(
            f"flight_window: expected states (T, {STATE_DIM}) and inputs (T, {INPUT_DIM}), got "
            f"{states.shape} and {inputs.shape}"
        )
    if history < 1 or horizon < 1:
        raise ValueError(
            f"flight_window: history and horizon must be >= 1, got {history} and {horizon}"
        )
    end = start + history + horizon
    if start < 0 or end > len(states):
        name = getattr(flight, "name", "the flight")
        raise ValueError(
            f"flight_window: steps {start} ... {end - 1} (M = {history} + N = {horizon}) do not "
            f"fit in {name} ({len(states)} steps); start must be 0 ... "
            f"{len(states) - history - horizon}"
        )
    file_states = states.copy()
    file_states[:, QUAT] = states[:, QUAT][:, list(WXYZ_TO_XYZW)]
    mid = start + history
    return FlightWindow(
        history=np.concatenate([file_states[start:mid], inputs[start:mid]], axis=1),
        future_inputs=inputs[mid:end].copy(),
        truth=file_states[mid:end],
    )
