"""Training: the network and its loss in a Lightning module, presets, resume, signals.

One entry function, ``train(data, out=...) -> Run``; its inverse for the trained file is
``checkpoints.load_checkpoint(path) -> LoadedModel``, and the batches it trains on come from
``batches.py``. Read top to bottom: presets, the Lightning module, checkpoint writing and
signals, ``train``. Its command line is ``slungload train`` (cli.py).

A run folder holds::

    best.ckpt, last.ckpt    Lightning checkpoints; each embeds every config (plain dicts under
                            the key "slungload"), so ``load_checkpoint`` rebuilds the model from
                            the file alone, with ``torch.load(weights_only=True)``
    run.json                summary (``Run``), written atomically by rank 0
    csv/metrics.csv         every loss term per epoch, train and val, and the val RMSEs
    tensorboard/            the same for TensorBoard

Faults: every checkpoint is written under a temporary name and renamed into place, so a killed
run never leaves a truncated ``.ckpt``. SIGINT (Ctrl-C) or SIGTERM stops after the current
batch, saves ``last.ckpt`` and raises ``TrainingInterrupted``; ``resume=True`` continues from
it (a second Ctrl-C stops at once, without saving). A training step whose loss is not finite is
skipped (no weight update) and counted (``train/skipped_steps``, ``Run.skipped_steps``);
``TrainExtras.max_bad_steps`` of them in a row stop the run with ``TrainingDiverged``.

Reproducibility: ``seed`` seeds the weights; each epoch's subsample of training windows and each
batch's dropout are drawn from ``(seed, epoch, batch)``, so a run resumed at an epoch boundary
draws what the uninterrupted run would have (a resume mid-epoch, after a signal, cannot). Two
CPU runs with the same seed and no wall-clock budget give identical weights. A preset with
``max_time`` stops on the clock, so its epoch count depends on the machine.

Several processes (``devices > 1``): Lightning's "ddp" strategy (gloo on CPU, NCCL on GPU)
re-launches the running command once per extra process, so call ``train`` from a script or
the command line (``slungload train`` or ``python -m slungload.cli train``), not from a notebook.
Each process takes an equal share of every epoch's windows.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import logging
import math
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from datetime import timedelta
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import (
    Callback,
    EarlyStopping,
    LearningRateMonitor,
    ModelCheckpoint,
)
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger
from lightning.pytorch.loggers.csv_logs import ExperimentWriter
from lightning.pytorch.loggers.logger import rank_zero_experiment
from lightning.pytorch.plugins.io import TorchCheckpointIO
from lightning.pytorch.utilities import rank_zero_warn
from lightning.pytorch.utilities.exceptions import SIGTERMException
from torch import Tensor

from .batches import WindowData, augment_yaw
from .checkpoints import BEST, CKPT_FORMAT, CKPT_KEY, LAST, check_resumable
from .config import LossWeights, ModelConfig, TrainConfig, VehicleParams, WindowConfig, to_dict
from .data import Dataset, load_dataset
from .fileio import atomic_path, write_json
from .loss import compute_loss, model_config_for
from .model import Prediction, SlungLoadNet, with_unit_quaternion
from .presets import Preset, TrainExtras, get_preset
from .state import GROUPS, QUAT, quat_error

RUN_JSON = "run.json"
MONITOR = "val/total"  # drives early stopping and the best checkpoint


class TrainingInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped a run; ``last.ckpt`` holds it (``resume=True`` continues)."""

    def __init__(self, message: str, signum: int = signal.SIGINT) -> None:
        super().__init__(message)
        self.signum = signum


class TrainingDiverged(ValueError):
    """The training loss stayed non-finite for ``TrainExtras.max_bad_steps`` steps in a row."""


# --- presets -----------------------------------------------------------------------------


def _terms(loss_terms: Any) -> dict[str, Tensor]:
    """LossTerms (NamedTuple or dataclass) -> {name: scalar tensor}, Nones dropped."""
    if dataclasses.is_dataclass(loss_terms):
        items = {f.name: getattr(loss_terms, f.name) for f in dataclasses.fields(loss_terms)}
    else:
        items = loss_terms._asdict()
    return {k: v for k, v in items.items() if isinstance(v, Tensor)}


class SlungLoadModule(L.LightningModule):
    """The network and its loss: Adam with L2 decay, optional warm-up + cosine lr.

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
        extras: TrainExtras,
        meta: dict[str, Any],
    ) -> None:
        super().__init__()
        self.net = net
        self.variant, self.params, self.weights = variant, params, weights
        self.history = window.history
        self.config, self.extras = config, extras
        self.meta = meta  # plain dicts, embedded in every checkpoint
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
        if self.extras.augment_yaw:
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
        if self._bad_in_a_row >= self.extras.max_bad_steps:
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
        x_hat = with_unit_quaternion(pred.states)
        for i, cols in enumerate(GROUPS.values()):
            if cols == QUAT:
                err = quat_error(x_hat[..., cols], truth[..., cols])
            else:
                err = x_hat[..., cols] - truth[..., cols]
            self._sq_err[i] += err.double().square().sum()
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
        cfg, extras = self.config, self.extras
        # Adam's weight_decay adds wd * theta to the gradient: the L2 penalty the paper means.
        optimizer = torch.optim.AdamW if cfg.optimizer == "adamw" else torch.optim.Adam
        opt = optimizer(self.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        if cfg.lr_schedule == "constant":
            return opt
        total = max(1, int(self.trainer.estimated_stepping_batches))
        per_epoch = max(1, total // max(1, self.trainer.max_epochs or 1))
        warmup = min(total - 1, extras.warmup_epochs * per_epoch)
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, _warmup_cosine(warmup, total, extras.min_lr_ratio)
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


# --- checkpoint writing and signals ------------------------------------------------------


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint writer, through a temporary file beside the target.

    Lightning 2.6 stages a local checkpoint in the system temporary folder and moves it into
    place; across file systems that move is a copy, which a crash can leave truncated.
    """

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: str | Path, storage_options: Any | None = None
    ) -> None:
        if storage_options is not None:
            raise TypeError("AtomicCheckpointIO.save_checkpoint takes no storage_options")
        with atomic_path(path) as tmp:
            torch.save(checkpoint, tmp)


class SaveOnInterrupt(Callback):
    """On SIGTERM (or SIGINT, see ``_sigint_as_sigterm``) save ``last.ckpt`` before stopping.

    Lightning 2.6 turns SIGTERM into a ``SIGTERMException`` at the end of the current batch
    (every DDP process at the same batch) but saves nothing; this adds the save.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.saved = False

    def on_exception(
        self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException
    ) -> None:
        if isinstance(exception, SIGTERMException) and not trainer.sanity_checking:
            trainer.save_checkpoint(self.path)
            self.saved = True


@contextlib.contextmanager
def _sigint_as_sigterm() -> Iterator[list[int]]:
    """While fitting, a first Ctrl-C asks for the graceful stop Lightning gives SIGTERM;
    a second one (or one before Lightning's handler is in place) interrupts at once.

    Yields a list that receives the number of every signal that asked to stop.
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received  # signal handlers can only be set from the main thread
        return

    def on_sigint(signum: int, frame: Any) -> None:
        lightning = signal.getsignal(signal.SIGTERM)
        if received or not callable(lightning):
            raise KeyboardInterrupt
        received.append(signum)
        print(
            "\nstopping after this batch to save last.ckpt (Ctrl-C again: stop now)",
            file=sys.stderr,
        )
        lightning(signal.SIGTERM, frame)

    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield received
    finally:
        signal.signal(signal.SIGINT, previous)


# --- train -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
    """What a ``train`` call produced."""

    out: Path
    best_checkpoint: Path
    last_checkpoint: Path
    variant: str
    preset: str
    epochs: int  # epochs completed in total (a resumed run counts the earlier ones)
    seconds: float  # wall-clock time of this call's fit
    stop_reason: str  # "max_epochs" | "early_stopping" | "max_time"
    best_val_loss: float
    metrics: dict[str, float] = field(default_factory=dict)  # last epoch's val metrics
    skipped_steps: int = 0  # training steps skipped for a non-finite loss, this call

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        return {k: str(v) if isinstance(v, Path) else v for k, v in d.items()}

    def summary(self) -> str:
        skipped = f"{self.skipped_steps} steps skipped (loss or gradients not finite); " * bool(
            self.skipped_steps
        )
        return (
            f"{self.variant} ({self.preset}): {self.epochs} epochs in {self.seconds:.0f} s, "
            f"stopped by {self.stop_reason}; best val loss {self.best_val_loss:.4g}, "
            f"val fit RMSE {self.metrics.get('val/fit_rmse', float('nan')):.4g}; "
            f"{skipped}{self.best_checkpoint}"
        )


def _accelerator(device: str) -> str:
    if device not in ("auto", "cpu", "cuda"):
        raise ValueError(f"device must be 'auto', 'cpu' or 'cuda', got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but torch sees no CUDA GPU")
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return device


def train(
    data: str | Path | Dataset,
    *,
    out: str | Path,
    variant: str = "proposed",
    preset: str | Preset = "default",
    device: str = "auto",
    devices: int = 1,
    seed: int = 0,
    max_epochs: int | None = None,
    resume: bool = False,
    model_config: ModelConfig = ModelConfig(),  # noqa: B008 (frozen)
    weights: LossWeights = LossWeights(),  # noqa: B008 (frozen)
    window: WindowConfig = WindowConfig(),  # noqa: B008 (frozen)
    params: VehicleParams | None = None,
    progress: bool = True,
    num_threads: int | None = None,
) -> Run:
    """Train one model variant on a dataset folder (or a loaded ``Dataset``) into ``out``.

    ``preset`` names a schedule in ``PRESETS``; ``seed`` and ``max_epochs`` override its own.
    ``variant`` names a loss variant of ``loss.py`` (it may change the network, e.g. no slack
    outputs). ``window``/``params`` are used only when ``data`` is a folder. ``resume=True``
    continues from ``out/last.ckpt`` (epochs, optimiser, schedule and early-stopping state);
    without it, an ``out`` that already holds a run is refused. ``num_threads`` sets torch's
    CPU threads for this process.

    Raises ``TrainingInterrupted`` after SIGINT/SIGTERM (``last.ckpt`` saved) and
    ``TrainingDiverged`` if the loss stays non-finite (see the module docstring).
    """
    out = Path(out).expanduser()
    last = out / LAST
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"run folder {out} is a file, expected a folder")
    if resume and not last.is_file():
        raise FileNotFoundError(f"cannot resume: {last} does not exist")
    if not resume and last.is_file():
        raise FileExistsError(f"{out} already holds a run ({LAST}); pass resume=True or a new out")
    if devices < 1:
        raise ValueError(f"devices must be >= 1, got {devices}")
    if max_epochs is not None and max_epochs < 1:
        raise ValueError(f"max_epochs must be >= 1, got {max_epochs}")
    if num_threads is not None and num_threads < 1:
        raise ValueError(f"num_threads (torch CPU threads) must be >= 1, got {num_threads}")
    accelerator = _accelerator(device)
    if num_threads is not None:
        torch.set_num_threads(num_threads)

    chosen = get_preset(preset)
    config = replace(chosen.config, seed=seed)
    if max_epochs is not None:
        config = replace(config, max_epochs=max_epochs)
    extras = chosen.extras

    dataset = (
        data if isinstance(data, Dataset) else load_dataset(data, window=window, params=params)
    )
    window = dataset.window
    model_config = model_config_for(variant, model_config)

    L.seed_everything(seed, workers=False, verbose=False)
    net = SlungLoadNet(model_config)
    train_windows = dataset.splits["train"]
    if model_config.normalize and len(train_windows):
        net.fit_normalization(
            train_windows.states, train_windows.inputs, origin_step=window.history - 1
        )

    from . import __version__

    meta = {
        "format": CKPT_FORMAT,
        "package_version": __version__,
        "variant": variant,
        "preset": chosen.name,
        "model": to_dict(model_config),
        "weights": to_dict(weights),
        "train": to_dict(config),
        "extras": to_dict(extras),
        "window": to_dict(window),
        "params": to_dict(dataset.params),
        "params_source": dataset.params_source,
        "data": str(dataset.folder),
    }
    if resume:
        check_resumable(last, meta)
    module = SlungLoadModule(
        net,
        variant=variant,
        params=dataset.params,
        weights=weights,
        window=window,
        config=config,
        extras=extras,
        meta=meta,
    )
    datamodule = WindowData(
        train_windows, dataset.splits["val"], config, val_windows=extras.val_windows
    )

    best_cb = ModelCheckpoint(
        dirpath=out,
        filename=BEST.removesuffix(".ckpt"),
        monitor=MONITOR,
        mode="min",
        save_top_k=1,
        auto_insert_metric_name=False,
        enable_version_counter=False,
    )
    # Lightning 2.6's save_last=True refreshes last.ckpt only in epochs that improve the best
    # one; a second callback without a monitor writes it after every epoch. Listed after
    # best_cb, so last.ckpt holds best_cb's state of the same epoch.
    last_cb = ModelCheckpoint(
        dirpath=out, filename=LAST.removesuffix(".ckpt"), save_top_k=1, enable_version_counter=False
    )
    # strict=False: a run stopped by a signal in the middle of validation resumes past that
    # epoch's validation (Lightning does not rerun it), so that one epoch has no val/total;
    # the check skips it instead of failing the resumed run.
    stop_cb = EarlyStopping(monitor=MONITOR, mode="min", patience=config.patience, strict=False)
    interrupt_cb = SaveOnInterrupt(last)
    callbacks = [best_cb, last_cb, stop_cb, interrupt_cb]
    start = time.perf_counter()
    with _quiet_lightning(not progress), _sigint_as_sigterm() as sigints:
        trainer = _make_trainer(out, accelerator, devices, config, extras, callbacks, progress)
        try:
            trainer.fit(
                module,
                datamodule=datamodule,
                ckpt_path=last if resume else None,
                weights_only=True,
            )
        except SIGTERMException:
            signum = signal.SIGINT if sigints else signal.SIGTERM
            saved = f"saved {last}" if interrupt_cb.saved else f"{last} is the last epoch's"
            raise TrainingInterrupted(
                f"training stopped by {signal.Signals(signum).name} at epoch "
                f"{trainer.current_epoch}, step {trainer.global_step}; {saved}; continue with "
                "resume=True (slungload train --resume)",
                signum,
            ) from None
    seconds = time.perf_counter() - start

    run = _run_result(trainer, best_cb, stop_cb, out, variant, chosen.name, config, seconds)
    run = replace(run, skipped_steps=module.skipped_steps)
    if trainer.is_global_zero:
        write_json(out / RUN_JSON, {**run.to_dict(), "config": meta})
    return run


def _make_trainer(
    out: Path,
    accelerator: str,
    devices: int,
    config: TrainConfig,
    extras: TrainExtras,
    callbacks: list[Any],
    progress: bool,
) -> L.Trainer:
    strategy: Any = "auto"
    if devices > 1:
        from lightning.pytorch.strategies import DDPStrategy

        strategy = DDPStrategy(process_group_backend="gloo" if accelerator == "cpu" else "nccl")
    return L.Trainer(
        accelerator=accelerator,
        devices=devices,
        strategy=strategy,
        max_epochs=config.max_epochs,
        max_time=timedelta(seconds=extras.max_time) if extras.max_time else None,
        gradient_clip_val=config.grad_clip or None,
        callbacks=[*callbacks, LearningRateMonitor(logging_interval="epoch")],
        plugins=[AtomicCheckpointIO()],
        logger=[
            _ResumableCSVLogger(out, name="csv", version=""),
            TensorBoardLogger(out, name="tensorboard", version="", default_hp_metric=False),
        ],
        default_root_dir=out,
        enable_progress_bar=progress,
        enable_model_summary=progress,
        use_distributed_sampler=False,  # EpochBatches shards the windows itself
        log_every_n_steps=1,
        num_sanity_val_steps=1,
    )


def _run_result(
    trainer: L.Trainer,
    best_cb: ModelCheckpoint,
    stop_cb: EarlyStopping,
    out: Path,
    variant: str,
    preset: str,
    config: TrainConfig,
    seconds: float,
) -> Run:
    epochs = trainer.current_epoch
    if stop_cb.stopped_epoch > 0:
        reason = "early_stopping"
    elif epochs >= config.max_epochs:
        reason = "max_epochs"
    else:
        reason = "max_time"
    metrics = {
        k: float(v) for k, v in sorted(trainer.callback_metrics.items()) if k.startswith("val/")
    }
    best_score = best_cb.best_model_score
    return Run(
        out=out,
        best_checkpoint=Path(best_cb.best_model_path) if best_cb.best_model_path else out / BEST,
        last_checkpoint=out / LAST,
        variant=variant,
        preset=preset,
        epochs=epochs,
        seconds=seconds,
        stop_reason=reason,
        best_val_loss=float(best_score) if best_score is not None else float("nan"),
        metrics=metrics,
    )


class _AppendingWriter(ExperimentWriter):
    """Lightning's CSV writer deletes an existing metrics.csv; a resumed run appends to it."""

    def _check_log_dir_exists(self) -> None:
        if self._fs.isfile(self.metrics_file_path):
            with self._fs.open(self.metrics_file_path, "r", newline="") as f:
                self.metrics_keys = list(csv.DictReader(f).fieldnames or [])


class _ResumableCSVLogger(CSVLogger):
    """``CSVLogger`` that keeps the rows of the epochs before a resume."""

    @property
    @rank_zero_experiment
    def experiment(self) -> ExperimentWriter:
        if self._experiment is None:
            self._fs.makedirs(self.root_dir, exist_ok=True)
            self._experiment = _AppendingWriter(log_dir=self.log_dir)
        return self._experiment


@contextlib.contextmanager
def _quiet_lightning(quiet: bool) -> Iterator[None]:
    """Silence Lightning's warnings about our deliberate choices, and its info lines if quiet."""
    levels: dict[str, int] = {}
    with warnings.catch_warnings():
        # Windows are tensors in memory (no workers needed); resuming into the run folder is
        # the point of resume.
        # Lightning 2.6 on torch 2.13 warns about its own use of torch's pytree.
        for pattern in (
            r".*does not have many workers.*",
            r".*exists and is not empty.*",
            r".*treespec, LeafSpec.*",
            r".*`training_step` returned `None`.*",  # a skipped non-finite step, on purpose
        ):
            warnings.filterwarnings("ignore", message=pattern)
        if quiet:
            for name in ("lightning.pytorch", "lightning.fabric"):
                levels[name] = logging.getLogger(name).level
                logging.getLogger(name).setLevel(logging.WARNING)
        try:
            yield
        finally:
            for name, level in levels.items():
                logging.getLogger(name).setLevel(level)
