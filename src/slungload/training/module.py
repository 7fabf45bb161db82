"""The network and its loss in a Lightning module: training and validation steps (non-finite
losses and gradients skipped and counted), the validation RMSE per state group, the optimiser
and its warm-up + cosine schedule, per-batch reseeding of dropout.
"""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.utilities import rank_zero_warn
from torch import Tensor

from ..config import LossWeights, TrainConfig, VehicleParams, WindowConfig
from ..loss import LossTerms, compute_loss
from ..models.base import Prediction
from ..models.checkpoints import CKPT_KEY
from ..models.lstm_attention import SlungLoadNet
from ..state import GROUPS, group_errors, with_unit_quaternion
from .batches import augment_yaw

MONITOR = "val/total"  # drives early stopping and the best checkpoint


class TrainingDiverged(ValueError):
    """The training loss stayed non-finite for ``TrainConfig.max_bad_steps`` steps in a row."""


def _terms(loss_terms: LossTerms) -> dict[str, Tensor]:
    """LossTerms -> {name: scalar tensor}, Nones dropped."""
    return {k: v for k, v in loss_terms._asdict().items() if isinstance(v, Tensor)}


class SlungLoadModule(L.LightningModule):
    """The network and its loss: Adam (L2 decay) or AdamW (``TrainConfig.optimizer``), optional
    warm-up + cosine lr.

    Logs every loss term as ``train/<term>`` and ``val/<term>`` (epoch means), the validation
    RMSE per state group ``val/rmse_<group>`` (unit quaternion, error q_hat (x) q^-1 - q_id) and
    their sum ``val/fit_rmse`` (the paper's "combined").
    """

    def __init__(
        self,
        net: SlungLoadNet,
        *,
        variant: str,
        params: VehicleParams,
        weights: LossWeights,
        window: WindowConfig,
        config: TrainConfig,
        meta: dict[str, Any],
        fit_scale: Tensor | None = None,
    ) -> None:
        super().__init__()
        self.net = net
        self.variant, self.params, self.weights = variant, params, weights
        self.history = window.history
        self.config = config
        self.meta = meta  # plain dicts, embedded in every checkpoint
        # L_fit's step factors (4, N) for the "physics-relative" weighting: a buffer, so it
        # follows the module to its device; not saved (train recomputes it from the data).
        self.register_buffer("fit_scale", fit_scale, persistent=False)
        self._sq_err = torch.zeros(len(GROUPS), dtype=torch.float64)
        self._count = torch.zeros((), dtype=torch.float64)
        self.skipped_steps = 0  # training steps with a non-finite loss, this call
        self._bad_in_a_row = 0

    def forward(self, states: Tensor, inputs: Tensor) -> Prediction:
        """Windows states (B, M+N, 13), inputs (B, M+N, 4) -> prediction of the last N steps."""
        m = self.history
        return self.net(states[:, :m], inputs[:, :m], inputs[:, m:])

    def _loss_terms(
        self, batch: tuple[Tensor, Tensor, Tensor]
    ) -> tuple[dict[str, Tensor], Prediction]:
        states, inputs, aux = batch
        pred = self(states, inputs)
        terms = compute_loss(
            pred,
            states,
            inputs,
            aux,
            history=self.history,
            params=self.params,
            weights=self.weights,
            variant=self.variant,
            fit_scale=self.fit_scale,
        )
        return _terms(terms), pred

    def _log_terms(self, terms: dict[str, Tensor], stage: str, batch_size: int) -> None:
        for name, value in terms.items():
            self.log(
                f"{stage}/{name}",
                value,
                on_step=False,
                on_epoch=True,
                batch_size=batch_size,
                sync_dist=True,
                prog_bar=name == "total",
            )

    def training_step(self, batch: tuple[Tensor, Tensor, Tensor], batch_idx: int) -> Tensor | None:
        if self.config.augment_yaw:
            batch = augment_yaw(batch)
        terms, _ = self._loss_terms(batch)
        loss = terms["total"]
        bad = ~torch.isfinite(loss.detach())
        if self.trainer.world_size > 1:  # every process must skip the same step
            bad = self.trainer.strategy.reduce(bad.float(), reduce_op="sum") > 0
        self.log("train/skipped_steps", bad.float(), on_step=False, on_epoch=True, reduce_fx="sum")
        if not bad:
            self._bad_in_a_row = 0
            self._log_terms(terms, "train", len(batch[0]))
            return loss
        self.skipped_steps += 1
        self._bad_in_a_row += 1
        where = f"epoch {self.current_epoch}, batch {batch_idx}"
        if self._bad_in_a_row >= self.config.max_bad_steps:
            raise TrainingDiverged(
                f"training loss not finite for {self._bad_in_a_row} steps in a row (last at "
                f"{where}); the weights were not updated by them. Try a lower learning rate, "
                "gradient clipping (TrainConfig.grad_clip), or check the data for outliers"
            )
        rank_zero_warn(f"non-finite training loss at {where}: step skipped", category=UserWarning)
        if self.trainer.world_size > 1:
            # DDP needs a backward on every process: zero gradients, so only momentum moves.
            return sum((p * 0.0).sum() for p in self.parameters())  # type: ignore[return-value]
        return None  # Lightning skips the backward pass and the weight update

    def on_before_optimizer_step(self, optimizer: Any) -> None:
        # A finite loss can still give non-finite gradients (an overflow in the backward pass);
        # clipping would spread them into every weight. Drop them: as for a non-finite loss, the
        # step then moves only the optimiser's momentum.
        grads = [p.grad for p in self.parameters() if p.grad is not None]
        if not grads:
            return
        bad = ~torch.stack([torch.isfinite(g).all() for g in grads]).all()
        if self.trainer.world_size > 1:  # every process must drop the same step
            bad = self.trainer.strategy.reduce(bad.float(), reduce_op="sum") > 0
        if not bad:
            return
        for g in grads:
            g.zero_()
        self.skipped_steps += 1
        where = f"epoch {self.current_epoch}, step {self.global_step}"
        rank_zero_warn(f"non-finite gradients at {where}: step skipped", category=UserWarning)

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> None:
        # Dropout draws from torch's global generator, which a checkpoint does not hold (and
        # which the data loader draws from too): reseed it for every batch, so a run resumed at
        # an epoch boundary draws the numbers the uninterrupted run drew.
        ids = [self.config.seed, self.current_epoch, batch_idx, self.global_rank]
        torch.manual_seed(int(np.random.SeedSequence(ids).generate_state(1)[0]))

    def on_validation_epoch_start(self) -> None:
        self._sq_err = torch.zeros(len(GROUPS), dtype=torch.float64, device=self.device)
        self._count = torch.zeros((), dtype=torch.float64, device=self.device)

    def validation_step(self, batch: tuple[Tensor, Tensor, Tensor], batch_idx: int) -> None:
        terms, pred = self._loss_terms(batch)
        self._log_terms(terms, "val", len(batch[0]))
        truth = batch[0][:, self.history :]  # (B, N, 13)
        errors = group_errors(with_unit_quaternion(pred.states), truth)  # group -> (B, N)
        for i, name in enumerate(GROUPS):
            self._sq_err[i] += errors[name].square().sum()
        self._count += truth.shape[0] * truth.shape[1]

    def on_validation_epoch_end(self) -> None:
        sq_err = self.trainer.strategy.reduce(self._sq_err, reduce_op="sum")
        count = self.trainer.strategy.reduce(self._count, reduce_op="sum")
        rmse = (sq_err / count.clamp_min(1)).sqrt().float()
        # Already summed over processes: sync_dist only averages equal values (and tells
        # Lightning so).
        for i, name in enumerate(GROUPS):
            self.log(f"val/rmse_{name}", rmse[i], sync_dist=True)
        self.log("val/fit_rmse", rmse.sum(), prog_bar=True, sync_dist=True)

    def configure_optimizers(self) -> Any:
        cfg = self.config
        # Adam's weight_decay adds wd * theta to the gradient: the L2 penalty the paper means;
        # AdamW decouples the decay from the adaptive step.
        optimizer = torch.optim.AdamW if cfg.optimizer == "adamw" else torch.optim.Adam
        opt = optimizer(self.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        if cfg.lr_schedule == "constant":
            return opt
        total = max(1, int(self.trainer.estimated_stepping_batches))
        per_epoch = max(1, total // max(1, self.trainer.max_epochs or 1))
        warmup = min(total - 1, cfg.warmup_epochs * per_epoch)
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, _warmup_cosine(warmup, total, cfg.min_lr_ratio)
        )
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint[CKPT_KEY] = self.meta


def _warmup_cosine(warmup: int, total: int, floor: float):
    """lr factor at optimiser step s: linear 0 -> 1 over ``warmup`` steps, then cosine to
    ``floor`` at ``total``. A plain function, so LambdaLR's state stays a plain dict."""

    def factor(s: int) -> float:
        if s < warmup:
            return (s + 1) / warmup
        t = min(1.0, (s - warmup) / max(1, total - warmup))
        return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * t))

    return factor
