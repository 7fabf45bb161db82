"""How a flight through the bridge went (``bridge.fly``'s answer) and its one-line summary."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..control.mppi import MPCStats
from .safety import SafetyLog


@dataclass
class BridgeResult:
    """How a flight through the bridge went."""

    end: str  # why it ended: "flight complete", "left offboard", "handed back: <fault>", ...
    steps: int = 0  # MPC steps flown
    sent: int = 0  # set-points sent (0 in shadow mode)
    safety: SafetyLog = field(default_factory=SafetyLog)
    mpc: MPCStats | None = None
    ignored: Counter = field(default_factory=Counter)  # message type -> count (bad, unknown)
    latency: list[float] = field(default_factory=list)  # s, state received -> command sent
    states: list[np.ndarray] = field(default_factory=list)  # (13,) each MPC step's state
    commands: list[np.ndarray] = field(default_factory=list)  # (4,) thrust N, rates FLU

    def summary(self) -> str:
        """One line: how it ended, steps, set-points, safety events, the MPC's fallbacks, the
        share of steps physics priced alone (a pair's trust window) and of steps a calibrated
        ensemble was surprised (``control.tracked``), the latency."""
        safety = ", ".join(f"{k} {n}" for k, n in self.safety.counts.items()) or "none"
        line = (f"{self.end}: {self.steps} MPC steps, {self.sent} set-points sent, safety "
                f"events: {safety}")  # fmt: skip
        if self.mpc is not None:
            line += f", MPC fallbacks {self.mpc.fallback_steps}"
            if self.mpc.physics_only_steps and self.mpc.steps:
                share = 100 * self.mpc.physics_only_steps / self.mpc.steps
                line += (f", physics alone priced {share:.0f} % of the steps (the network "
                         "predicted the steps just flown worse)")  # fmt: skip
            if self.mpc.surprised_steps and self.mpc.steps:
                share = 100 * self.mpc.surprised_steps / self.mpc.steps
                line += (f", the ensemble surprised on {share:.0f} % of the steps (its errors on "
                         "the steps just flown beyond its calibration's)")  # fmt: skip
        if self.latency:
            ms = np.array(self.latency) * 1e3
            line += (f"; state -> command {np.median(ms):.2f} ms median, "
                     f"{np.percentile(ms, 99):.2f} ms p99")  # fmt: skip
        return line
