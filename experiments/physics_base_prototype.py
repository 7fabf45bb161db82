"""Prototype, not part of the package: the network's step built on the discrete model's step.

    x_hat_{k+1} = f(x_hat_k, u_k, aux_k) + delta_std * head_k

with aux = (vL, Omega_L) started from the causal estimate at step M-1 and carried by f, so a
zero head reproduces the physics-only rollout. Same layers and parameter count as the paper's
network. It replaces ``SlungLoadNet.forward`` in this process only (hence the private
imports), trains one variant with the ``default`` preset (no time cap) and evaluates it.
Measured in session 3: ``docs/BENCHMARKS.md``, "Session 3 prototype".

    python experiments/physics_base_prototype.py DATA_DIR VARIANT OUT_DIR [SEED]
"""

from __future__ import annotations

import dataclasses
import sys

import torch
import torch.nn.functional as F

from slungload.config import VehicleParams, load_vehicle
from slungload.data.flight import estimate_load_state
from slungload.models.base import Prediction
from slungload.models.lstm_attention import (
    SlungLoadNet,
    _check_shapes,
    _lstm_cell,
    _stacked_lstm_weights,
)
from slungload.physics import step
from slungload.state import STATE_DIM


def physics_base_forward(params):
    """A ``SlungLoadNet.forward`` whose steps correct f(x_hat_k, u_k, aux_k) (normalised model)."""

    def forward(self, x_hist, u_hist, u_future):
        _check_shapes(x_hist, u_hist, u_future)
        cfg = self.config
        origin = self.origin(x_hist[:, -1]).unsqueeze(1)  # (B, 1, 13)
        z_hist = self.normalize_state(x_hist - origin)
        v_hist, v_future = self.normalize_input(u_hist), self.normalize_input(u_future)
        enc, (h, c) = self.encoder(self.embed(torch.cat([z_hist, v_hist], dim=-1)))
        keys = self.attention.keys(enc)
        u_dec = torch.cat([u_hist[:, -1:], u_future[:, :-1]], dim=1)  # physical, for f
        v_dec = torch.cat([v_hist[:, -1:], v_future[:, :-1]], dim=1)
        gain = self.delta_std / self.state_std
        state_weight, head = self.embed.state_weight(), self.head.joined()
        weights = _stacked_lstm_weights(self.decoder)
        hs, cs = list(h.unbind(0)), list(c.unbind(0))
        z, x, o = z_hist[:, -1], x_hist[:, -1], origin[:, 0]
        aux = estimate_load_state(x_hist[:, -2:], params)[:, -1]  # (B, 6) at M-1
        states, slacks = [], []
        for k, part in enumerate(self.embed.input_part(v_dec).unbind(1)):
            context = self.attention(keys, enc, hs[-1])
            layer_in = torch.cat([context, self.embed.from_parts(z, part, state_weight)], -1)
            for i, (w, b) in enumerate(weights):
                if i > 0:
                    layer_in = F.dropout(layer_in, cfg.dropout, self.training)
                hs[i], cs[i] = _lstm_cell(layer_in, hs[i], cs[i], w, b)
                layer_in = hs[i]
            y = self.head.apply_joined(layer_in, head)
            x_f, aux = step(x, u_dec[:, k], aux, params)
            z = self.normalize_state(x_f - o) + y[:, :STATE_DIM] * gain
            x = self.denormalize_state(z) + o
            states.append(z)
            if cfg.slack:
                slacks.append(y[:, STATE_DIM:])
        x_hat = self.denormalize_state(torch.stack(states, dim=1)) + origin
        slack = torch.stack(slacks, dim=1) * self.delta_std if cfg.slack else None
        return Prediction(x_hat, slack)

    return forward


def main(data: str, variant: str, out: str, seed: int = 0) -> None:
    from slungload.evaluation.evaluator import evaluate
    from slungload.training.presets import PRESETS, Preset
    from slungload.training.trainer import train

    params = load_vehicle(data) or VehicleParams()
    SlungLoadNet.forward = physics_base_forward(params)
    base = PRESETS["default"]
    extras = dataclasses.replace(base.extras, max_time=None)
    preset = Preset("physics-base", base.config, extras, description="prototype")
    run = train(data, out=out, variant=variant, seed=seed, preset=preset, progress=False)
    print(run.epochs, run.stop_reason, f"{run.seconds:.0f} s", flush=True)
    evaluate([out], out=f"{out}_eval", timing=False, progress=False)
    print(open(f"{out}_eval/rmse.csv").read())


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], *map(int, sys.argv[4:5]))
