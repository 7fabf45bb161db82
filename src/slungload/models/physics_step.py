"""The physics-step network: the paper's network correcting one step of the discrete model.

Each decoder step starts from the discrete model f (``physics.step``) and adds the network's
correction, in physical units::

    x_hat_{k+1} = f(x_hat_k, u_k, a_k) + delta_std * out_k
    a_{k+1}     = the load state that f returns with it

for k = M-1 ... M+N-2, with x_hat_{M-1} the last measured state, out_k the head's 13 state
rows and a = (vL, Omega_L) the unmeasured load state: a_{M-1} is the causal estimate from the
last two measured states (``load_state.estimate_load_state``, as the data's estimate at that
step) or, with ``ModelConfig.load_estimate = "smoothed"``, the slopes of quadratics fitted
through the last 9 (``load_state.fit_load_state``: less noise, no lag at constant
acceleration); from there f carries it; the network never sees or corrects it. In network units
the correction is out_k * delta_std / state_std, the paper network's residual gain, so the
head's output has the same scale in both architectures: one step's typical change.

A zero head (last head layer's weight and bias zero) therefore predicts ``physics.rollout``
from the estimated load state (with the data's estimate: the paper's physics-only row), and
the slack outputs are zero.

With ``ModelConfig.constants = "window"`` f runs with each window's own cable length and load
mass, estimated from its history in flight (``constants_estimate.adapted``): one network for
many loads. The estimate needs M >= 17 history steps (``estimate_constants``). With
``ModelConfig.constants_input`` the correction network sees them too: f's cable length and load
mass as ratios to the network's own (``reference``) minus one, two more embedding inputs at
every step (``conditioning``), so the correction itself can change with the load.
Same layers, parameters, attention and decoder as ``SlungLoadNet``; only the decoder's state
update (``start_rollout``/``next_state``) differs. Shapes: B batch, M history steps (M >= 2),
N horizon steps.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from .. import physics
from ..config import ModelConfig, VehicleParams
from ..constants_estimate import adapted
from ..load_state import estimate_load_state, fit_load_state
from ..smoothing import LOAD_FIT_STEPS
from ..vehicle_constants import constant_ratios
from .lstm_attention import SlungLoadNet


class PhysicsCarry(NamedTuple):
    """What the physics-step decoder carries from step k to k + 1 (physical units)."""

    x: Tensor  # (B, 13) x_hat_k, positions relative to the origin (``SlungLoadNet.origin``)
    aux: Tensor  # (B, 6) a_k = (vL m/s, Omega_L rad/s), carried by f alone
    inputs: tuple[Tensor, ...]  # N x (B, 4) u_{M-1} ... u_{M+N-2}, (T N, omega rad/s)
    scale: Tensor | None  # (13,) delta_std, state units; None without normalisation
    params: physics.Vehicle  # f's constants: the network's, or one set per window (B,)


class PhysicsStepNet(SlungLoadNet):
    """``SlungLoadNet`` whose decoder steps correct the discrete model: x_hat_{k+1} =
    f(x_hat_k, u_k, a_k) + delta_std * out_k (see the module doc).

    Takes and returns what ``SlungLoadNet`` does (physical units, ``Prediction`` with slack as
    in the paper network) and has the same parameters: 238,906 with the default
    ``ModelConfig`` (the physics adds none). The vehicle constants ``params`` are a plain
    attribute, not a buffer: a checkpoint records them in its configs and ``load_checkpoint``
    rebuilds the network with them. Needs M >= 2 history steps (the load-state estimate is a
    backward difference).
    """

    architecture = "physics-step"  # its name in ``models.MODELS``

    def __init__(
        self, config: ModelConfig | None = None, params: VehicleParams | None = None
    ) -> None:
        cfg = config or ModelConfig(architecture=self.architecture)
        if not cfg.residual:
            # The head's output is always a correction added to f's step: there is no
            # "predict the state itself" form of this architecture.
            raise ValueError(
                "PhysicsStepNet adds its output to a step of the discrete model; it has no "
                "residual=False form (use the 'lstm-attention' architecture for that)"
            )
        super().__init__(cfg, params)
        self.params = params or VehicleParams()
        # What ``conditioning`` measures f's constants against: the constants the network was
        # built with, kept when a caller gives f others (``load_prediction_model``).
        self.reference = self.params

    def start_rollout(self, x_rel: Tensor, u_hist: Tensor, u_future: Tensor) -> PhysicsCarry:
        """The decoder's starting point: x_{M-1}, the estimate a_{M-1} and the physical inputs
        f takes at each step, computed once per sequence.

        x_rel (B, M, 13) history, positions relative to the origin; u_hist (B, M, 4);
        u_future (B, N, 4); physical units. f runs in these relative coordinates: it depends
        on positions only through pL - p, so shifting p and pL by the origin commutes with it
        (and float32 keeps more digits near zero).
        """
        if x_rel.shape[1] < 2:
            raise ValueError(
                f"PhysicsStepNet needs M >= 2 history steps to estimate the load state "
                f"(vL, Omega_L); got M = {x_rel.shape[1]}"
            )
        params: physics.Vehicle = self.params
        if self.config.adapts_constants:
            params = adapted(x_rel, u_hist, self.params)  # (B,) each
        if self.config.load_estimate == "smoothed":
            window = min(LOAD_FIT_STEPS, x_rel.shape[1])
            if window < 3:
                raise ValueError(
                    f"the smoothed load estimate needs M >= 3 history steps; got M = {window}"
                )
            aux = fit_load_state(x_rel[:, -window:], params)  # (B, 6) at step M-1
        else:
            aux = estimate_load_state(x_rel[:, -2:], params)[:, -1]  # (B, 6) at step M-1
        inputs = torch.cat([u_hist[:, -1:], u_future[:, :-1]], dim=1)  # (B, N, 4)
        scale = self.delta_std if self.config.normalize else None
        return PhysicsCarry(x_rel[:, -1], aux, inputs.unbind(1), scale, params)

    def next_state(
        self, z: Tensor, out: Tensor, k: int, carry: PhysicsCarry
    ) -> tuple[Tensor, PhysicsCarry]:
        """z_{M+k} = normalised f(x_hat_{M-1+k}, u_{M-1+k}, a_{M-1+k}) + out * delta_std.

        ``z`` (the previous state in network units) is not needed: ``carry.x`` holds the same
        state in physical units, which f takes. out (B, 13) -> z (B, 13) and the next carry.
        """
        x, aux = physics.step(carry.x, carry.inputs[k], carry.aux, carry.params)
        x = x + out if carry.scale is None else torch.addcmul(x, out, carry.scale)
        return self.normalize_state(x), carry._replace(x=x, aux=aux)

    def conditioning(self, carry: PhysicsCarry) -> Tensor | None:
        """With ``ModelConfig.constants_input``, f's constants as the embedding sees them:
        (B, C) ``constant_ratios`` of ``carry.params`` against ``reference``; else None."""
        if not self.config.constants_input:
            return None
        like = carry.x
        ratios = constant_ratios(carry.params, self.reference)
        b = like.shape[0]  # a float is filled on the device: no copy (CUDA graphs allow none)
        return torch.stack(
            [r.to(like).expand(b) if isinstance(r, Tensor) else like.new_full((b,), r)
             for r in ratios], dim=-1,
        )  # fmt: skip
