"""Sliding windows cut from flights.

A window is M + N consecutive steps of one flight: the first M are the history the network
sees, the last N the future it predicts. Windows never cross flights. ``data.load_dataset``
builds them per split; this module knows nothing about files or splits.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np
import torch
from torch import Tensor

from ..config import WindowConfig, to_dict
from ..input_lag import NO_LAG, check_lag, lagged
from ..load_state import estimate_load_state
from ..physics import VehicleConstants, rollout
from ..state import STATE_DIM


class Segment(NamedTuple):
    """Part of a batch of windows: states (W, S, 13), inputs (W, S, 4), aux (W, S, 6)."""

    states: Tensor
    inputs: Tensor
    aux: Tensor


class FlightSeries(Protocol):
    """What ``make_windows`` needs of a flight (``data.Flight`` has it)."""

    name: str
    states: np.ndarray  # (T, 13)
    inputs: np.ndarray  # (T, 4)
    aux: np.ndarray  # (T, 6)
    constants: Any  # the flight's own ``VehicleParams`` (varied loads), or None: the dataset's


@dataclass(frozen=True)
class Windows:
    """Sliding windows of one split, float32.

    states (W, M+N, 13), inputs (W, M+N, 4), aux (W, M+N, 6) = estimated (vL, Omega_L);
    flight (W,) int64 index into ``names``; start (W,) int64 first step of each window in its
    flight. ``history`` / ``future`` give the first M / last N steps. constants (W, 7) float64:
    each window's flight's own constants (``physics.VehicleConstants`` order) where some flight
    records them (simulated varied loads; the rest hold the dataset's), else None.
    """

    states: Tensor
    inputs: Tensor
    aux: Tensor
    flight: Tensor
    start: Tensor
    names: tuple[str, ...]
    window: WindowConfig
    constants: Tensor | None = None

    def __len__(self) -> int:
        return self.states.shape[0]

    @property
    def history(self) -> Segment:
        """The first M steps of every window (what the encoder sees)."""
        m = self.window.history
        return Segment(self.states[:, :m], self.inputs[:, :m], self.aux[:, :m])

    @property
    def future(self) -> Segment:
        """The last N steps of every window (what is predicted)."""
        m = self.window.history
        return Segment(self.states[:, m:], self.inputs[:, m:], self.aux[:, m:])

    def __getitem__(self, index: Tensor | slice | Sequence[int] | int) -> Windows:
        """A subset: an index or boolean tensor, a slice, a list; an int keeps a window axis."""
        if isinstance(index, int):
            index = [index]
        if not isinstance(index, slice):
            index = torch.as_tensor(index)
        return Windows(
            states=self.states[index],
            inputs=self.inputs[index],
            aux=self.aux[index],
            flight=self.flight[index],
            start=self.start[index],
            names=self.names,
            window=self.window,
            constants=None if self.constants is None else self.constants[index],
        )

    subset = __getitem__

    def vehicle(self) -> VehicleConstants | None:
        """Each window's flight's own constants, one set per window (tensors (W,) float64, as
        ``VehicleConstants.stack`` gives), or None when no flight records its own."""
        if self.constants is None:
            return None
        return VehicleConstants(*self.constants.unbind(-1))

    def to(self, device: torch.device | str) -> Windows:
        """The same windows on another device."""
        return Windows(
            self.states.to(device),
            self.inputs.to(device),
            self.aux.to(device),
            self.flight.to(device),
            self.start.to(device),
            self.names,
            self.window,
            None if self.constants is None else self.constants.to(device),
        )

    def to_payload(self) -> dict[str, Any]:
        """Plain tensors and strings, for the cache (``from_payload`` inverts it)."""
        return {
            "states": self.states,
            "inputs": self.inputs,
            "aux": self.aux,
            "flight": self.flight,
            "start": self.start,
            "names": list(self.names),
            "window": to_dict(self.window),
            "constants": self.constants,
        }

    @classmethod
    def from_payload(cls, data: dict[str, Any]) -> Windows:
        return cls(
            states=data["states"],
            inputs=data["inputs"],
            aux=data["aux"],
            flight=data["flight"],
            start=data["start"],
            names=tuple(data["names"]),
            window=WindowConfig(**data["window"]),
            constants=data.get("constants"),
        )


def make_windows(
    flights: Sequence[FlightSeries], window: WindowConfig, params: Any = None
) -> Windows:
    """Cut every flight into windows (never across flights), concatenated in flight order.
    ``params`` (the dataset's ``VehicleParams``) fills ``Windows.constants`` for the flights
    without their own when some flight has its own; without ``params`` it stays None."""
    sets: list[tuple[int, Any]] = []  # (windows, the flight's own constants or None)
    parts: dict[str, list[Tensor]] = {
        "states": [],
        "inputs": [],
        "aux": [],
        "flight": [],
        "start": [],
    }
    for i, flight in enumerate(flights):
        count = window.count(len(flight.states))
        if count == 0:
            continue
        if flight.aux is None:
            raise ValueError(f"{flight.name}: read without its load-state estimate; windows need "
                             "it (readers.load_flight(..., load_state=True))")  # fmt: skip
        for key in ("states", "inputs", "aux"):
            series = torch.from_numpy(np.asarray(getattr(flight, key), dtype=np.float32))
            # unfold: (T, C) -> (W, C, L) views; one copy at the concatenation below.
            cut = series.unfold(0, window.length, window.stride)[:count]
            parts[key].append(cut.transpose(1, 2))
        parts["flight"].append(torch.full((count,), i, dtype=torch.int64))
        own = getattr(flight, "constants", None)
        sets.append((count, own))
        parts["start"].append(torch.arange(count, dtype=torch.int64) * window.stride)
    dims = {"states": 13, "inputs": 4, "aux": 6}
    out: dict[str, Tensor] = {}
    for key, chunks in parts.items():
        if chunks:
            out[key] = torch.cat(chunks).contiguous()
        elif key in dims:
            out[key] = torch.zeros(0, window.length, dims[key])
        else:
            out[key] = torch.zeros(0, dtype=torch.int64)
    constants = None
    if params is not None and any(own is not None for _, own in sets):
        rows = [
            torch.tensor(VehicleConstants.of(own or params), dtype=torch.float64).expand(n, -1)
            for n, own in sets
        ]
        constants = torch.cat(rows)
    return Windows(**out, names=tuple(f.name for f in flights), window=window, constants=constants)


def physics_rollout(
    windows: Windows,
    params: Any,
    batch_size: int | None = 8192,
    lag: Sequence[float] = NO_LAG,
) -> Tensor:
    """The physics-only open-loop prediction of every window (the paper's "physics" row),
    (W, N, 13) float64: ``physics.rollout`` from the last history state x_{M-1} with the data's
    load-state estimate there and the true inputs u_{M-1} ... u_{M+N-2}.

    The one place that cuts a window for the physics model: the physics prediction model,
    training's ``physics_step_mse`` and ``identify``'s fits all call it. params: a
    ``VehicleParams`` or anything with its attributes (e.g. fitted constants as float64
    tensors); nothing is detached, so the result is differentiable in them. batch_size:
    windows per rollout, or None for all at once (no copy into a joined result). lag: the
    commands' time constants (s, ``input_lag.lagged``), the history's inputs warming the filter
    (one set of constants only); none: the inputs as recorded.
    """
    if batch_size is None:
        return _rollout_from_history(windows, params, lag)
    parts = [torch.zeros(0, windows.window.horizon, STATE_DIM, dtype=torch.float64)]
    for i in range(0, len(windows), batch_size):
        part = slice(i, i + batch_size)
        parts.append(_rollout_from_history(windows[part], _constants_of(params, part), lag))
    return torch.cat(parts)


def _per_window(params: Any) -> bool:
    """Whether ``params`` holds one set of constants per window (a ``VehicleConstants`` with
    tensors (W,), as ``VehicleConstants.stack`` and ``Windows.vehicle`` give) rather than one
    set."""
    return isinstance(params, tuple) and any(isinstance(c, Tensor) and c.dim() > 0 for c in params)


def _constants_of(params: Any, part: slice) -> Any:
    """The constants of windows ``part``: per-window constants sliced, one set as it is."""
    if not _per_window(params):
        return params
    return type(params)(*(c[part] if isinstance(c, Tensor) and c.dim() > 0 else c for c in params))


def _rollout_from_history(windows: Windows, params: Any, lag: Sequence[float]) -> Tensor:
    """One batch: x_{M-1}, aux_{M-1}, u_{M-1} ... u_{M+N-2} (through ``lag``) -> (W, N, 13)
    float64. With one set of constants per window the load rate at M-1 is estimated again with
    each window's cable length (the data's aux used the dataset's)."""
    m, n = windows.window.history, windows.window.horizon
    x0, aux0 = windows.states[:, m - 1].double(), windows.aux[:, m - 1].double()
    if _per_window(params):
        params = type(params)(*(c.double() if isinstance(c, Tensor) else c for c in params))
        aux0 = estimate_load_state(windows.states[:, m - 2 : m].double(), params)[:, -1]
    inputs = windows.inputs.double()
    future = inputs[:, m - 1 : m + n - 1]
    if any(check_lag(lag)):
        received = lagged(inputs[:, : m - 1].numpy(), future.numpy(), lag, float(params.dt))
        future = torch.from_numpy(received)
    states, _ = rollout(x0, aux0, future, params)
    return states
