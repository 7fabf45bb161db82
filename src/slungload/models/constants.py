"""Physical constants of the discrete model as trainable parameters.

The paper's model takes its constants from a scale and a tape measure; here the ones a flight
log can tell apart are fitted to the data: the load mass mL, the cable length l, the load
damping d and a thrust gain k_T (achieved / commanded thrust). The vehicle mass mQ stays fixed:
scaling every mass and the thrust together leaves the motion unchanged, so kinematics alone
cannot tell mQ from k_T.

Positivity by construction: a positive constant is ``initial * exp(theta)``, the damping
``sigmoid(logit(d0) + theta)`` in (0, 1); theta starts at zero, so an untrained module gives
the initial constants (to rounding) (from ``vehicle.json`` or the defaults).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..config import VehicleParams
from ..physics import VehicleConstants

POSITIVE = ("mass_load", "cable_length", "thrust_gain")  # fitted as initial * exp(theta)
FITTED = (*POSITIVE, "load_damping")


class LearnedConstants(nn.Module):
    """The discrete model's fitted constants; ``current()`` gives them to ``physics.step``."""

    def __init__(self, initial: VehicleParams, fitted: tuple[str, ...] = FITTED) -> None:
        super().__init__()
        unknown = set(fitted) - set(FITTED)
        if unknown:
            raise ValueError(f"cannot fit {sorted(unknown)}; fittable constants: {FITTED}")
        damping = initial.load_damping
        if "load_damping" in fitted and not 0.0 < damping < 1.0:
            raise ValueError(f"load_damping must be in (0, 1) to be fitted, got {damping}")
        self.initial = initial
        self.fitted = tuple(name for name in FITTED if name in fitted)
        self.theta = nn.Parameter(torch.zeros(len(self.fitted), dtype=torch.float64))

    def current(self) -> VehicleConstants:
        """The constants now (differentiable in ``theta``): 0-d float64 tensors where fitted,
        the initial floats elsewhere."""
        values = {name: getattr(self.initial, name) for name in VehicleConstants._fields}
        for i, name in enumerate(self.fitted):
            if name == "load_damping":
                d0 = self.initial.load_damping
                values[name] = torch.sigmoid(math.log(d0 / (1.0 - d0)) + self.theta[i])
            else:
                values[name] = values[name] * torch.exp(self.theta[i])
        return VehicleConstants(**values)

    def params(self) -> VehicleParams:
        """The constants now as plain ``VehicleParams`` (for files and the physics predictor)."""
        with torch.no_grad():
            now = self.current()._asdict()
        return VehicleParams(**{k: float(v) for k, v in now.items()})

    def table(self) -> dict[str, dict[str, float]]:
        """name -> {"value", "initial"} of every fitted constant (run folders and reports)."""
        now = self.params()
        return {
            name: {"value": getattr(now, name), "initial": getattr(self.initial, name)}
            for name in self.fitted
        }
