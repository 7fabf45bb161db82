"""Training: one entry function, ``train(data, run, out=...) -> Run``.

What a run trains is one ``run_config.RunConfig`` (configs, schedule, seed). Its inverse for
the trained file is ``models.checkpoints.load_checkpoint(path) -> LoadedModel``; the Lightning
module is ``module.py``, the batches come from ``batches.py``, and ``runtime.py`` holds the
Lightning workarounds. Its command line is ``slungload train`` (cli/train.py).

A run folder holds::

    best.ckpt, last.ckpt    Lightning checkpoints; each embeds every config (plain dicts under
                            the key "slungload"), so ``load_checkpoint`` rebuilds the model from
                            the file alone, with ``torch.load(weights_only=True)``
    run.toml                the run's description (``RunConfig``; ``run_config.read_toml``)
    run.json                summary (``Run``), written atomically by rank 0
    csv/metrics.csv         every loss term per epoch, train and val, and the val RMSEs
    tensorboard/            the same for TensorBoard

Faults: every checkpoint is written under a temporary name and renamed into place, so a killed
run never leaves a truncated ``.ckpt``. SIGINT (Ctrl-C) or SIGTERM stops after the current
batch, saves ``last.ckpt`` and raises ``TrainingInterrupted``; ``resume=True`` continues from
it (a second Ctrl-C stops at once, without saving). A training step whose loss is not finite is
skipped (no weight update) and counted (``train/skipped_steps``, ``Run.skipped_steps``);
``TrainConfig.max_bad_steps`` of them in a row stop the run with ``TrainingDiverged``.

Reproducibility: ``seed`` seeds the weights; each epoch's subsample of training windows and each
batch's dropout are drawn from ``(seed, epoch, batch)``, so a run resumed at an epoch boundary
draws what the uninterrupted run would have (a resume mid-epoch, after a signal, cannot). Two
CPU runs with the same seed give identical weights, unless the wall-clock cap
(``TrainConfig.max_time``, a safety net) stops one: its epoch count then depends on the machine,
``Run.stop_reason`` is "max_time", and ``train(data, run.uncapped(), resume=True, ...)``
continues it.

Several processes (``devices > 1``): Lightning's "ddp" strategy (gloo on CPU, NCCL on GPU)
re-launches the running command once per extra process, so call ``train`` from a script or
the command line (``slungload train`` or ``python -m slungload.cli train``), not from a notebook.
Each process takes an equal share of every epoch's windows.
"""

from __future__ import annotations

import dataclasses
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import timedelta
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import (
    EarlyStopping,
    LearningRateMonitor,
    ModelCheckpoint,
)
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities.exceptions import SIGTERMException
from torch import Tensor, nn

from .._version import __version__
from ..config import ModelConfig, TrainConfig, VehicleParams, to_dict
from ..data.dataset import Dataset, load_dataset
from ..data.windows import physics_rollout
from ..fileio import write_json
from ..loss import step_scale
from ..models.checkpoints import BEST, CKPT_FORMAT, LAST, check_resumable
from ..models.registry import build
from ..run_config import RunConfig
from ..state import GROUPS, group_errors
from .batches import WindowData
from .identify import identify
from .module import MONITOR, SlungLoadModule
from .runtime import (
    AtomicCheckpointIO,
    EpochReport,
    SaveOnInterrupt,
    _quiet_lightning,
    _ResumableCSVLogger,
    _sigint_as_sigterm,
)

RUN_JSON = "run.json"
RUN_TOML = "run.toml"  # the run's description (``RunConfig``), readable by ``read_toml``


class TrainingInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped a run; ``last.ckpt`` holds it (``resume=True`` continues)."""

    def __init__(self, message: str, signum: int = signal.SIGINT) -> None:
        super().__init__(message)
        self.signum = signum


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
    run: RunConfig | None = None,
    *,
    out: str | Path,
    device: str = "auto",
    devices: int = 1,
    resume: bool = False,
    params: VehicleParams | None = None,
    progress: bool = True,
    num_threads: int | None = None,
    on_epoch: Callable[[int, dict[str, float], nn.Module], None] | None = None,
) -> Run:
    """Train the run ``run`` describes (default ``RunConfig()``: the paper's network, the
    proposed loss, the default preset, seed 0) on a dataset folder (or a loaded ``Dataset``)
    into ``out``; ``RunConfig.from_preset`` builds one from a preset's name.

    ``run.window`` and ``params`` (vehicle constants overriding the folder's vehicle.json) are
    used only when ``data`` is a folder. ``resume=True`` continues from ``out/last.ckpt``
    (epochs, optimiser, schedule and early-stopping state); without it, an ``out`` that already
    holds a run is refused. ``num_threads`` sets torch's CPU threads for this process. A run
    whose ``TrainConfig.fit_constants`` is set fits the physics model's constants to the
    training flights first (``identify``) and trains with them. The run folder gets the
    description as ``run.toml``. ``on_epoch(epoch, metrics, net)`` receives each validation
    epoch's ``val/...`` metrics and the network (``runtime.EpochReport``; a configuration
    search's progress).

    Raises ``TrainingInterrupted`` after SIGINT/SIGTERM (``last.ckpt`` saved) and
    ``TrainingDiverged`` if the loss stays non-finite (see the module docstring).
    """
    run = run if run is not None else RunConfig()
    out = Path(out).expanduser()
    last = _check_run_folder(out, resume)
    _check_counts(devices=devices, num_threads=num_threads)
    accelerator = _accelerator(device)
    if num_threads is not None:
        torch.set_num_threads(num_threads)
    config, variant, weights = run.train, run.variant, run.loss
    dataset = (
        data if isinstance(data, Dataset) else load_dataset(data, window=run.window, params=params)
    )
    model_config = run.model
    meta = _checkpoint_meta(run, dataset)
    model_params, fit_scale = _constants_and_step_scale(run, dataset, meta)
    if resume:
        check_resumable(last, meta)

    L.seed_everything(config.seed, workers=False, verbose=False)  # the network's initial weights
    module = SlungLoadModule(
        _new_network(model_config, dataset, model_params),
        variant=variant,
        params=model_params,
        weights=weights,
        window=dataset.window,
        config=config,
        meta=meta,
        fit_scale=fit_scale,
    )
    datamodule = WindowData(
        dataset.splits["train"], dataset.splits["val"], config, val_windows=config.val_windows
    )
    callbacks = _callbacks(out, config)
    if _is_global_zero():
        RunConfig.from_meta(meta).write_toml(out / RUN_TOML)
    start = time.perf_counter()
    extra = (EpochReport(on_epoch),) if on_epoch is not None else ()
    trainer = _fit(
        module, datamodule, callbacks, out, accelerator, devices, config, progress, resume, extra
    )
    seconds = time.perf_counter() - start

    best_cb, _, stop_cb, _ = callbacks
    result = _run_result(trainer, best_cb, stop_cb, out, variant, run.preset, config, seconds)
    result = replace(result, skipped_steps=module.skipped_steps)
    if trainer.is_global_zero:
        write_json(out / RUN_JSON, {**result.to_dict(), "config": meta})
    return result


def _constants_and_step_scale(
    run: RunConfig, dataset: Dataset, meta: dict[str, Any]
) -> tuple[VehicleParams, Tensor | None]:
    """The constants of the physics loss and of the network's f (the dataset's, or fitted to
    the training flights with ``identify``) and the per-step weights of the fit term (None for
    the paper's weighting); what they were goes into ``meta``, the run's record (a resume
    recomputes them: the same data give the same values)."""
    params = dataset.params
    if run.train.fit_constants:
        fitted = identify(dataset)
        params = fitted.params
        meta.update(constants=fitted.table, model_params=to_dict(params))
    if run.loss.steps == "paper":
        return params, None
    physics_mse, diverged = physics_step_mse(dataset.splits["train"], params)
    meta["physics_rms"] = {g: physics_mse[i].sqrt().tolist() for i, g in enumerate(GROUPS)}
    if diverged:  # recorded only when any: runs on clean data resume as they were started
        meta["physics_diverged"] = diverged
    return params, step_scale(run.loss.steps, physics_mse, run.loss.alpha).float()


# A window whose physics rollout strays further than this many times the typical window's
# worst error (or goes non-finite) diverged: a flight the arena stopped, a cable state the
# discrete model cannot step through. Its squared errors would dwarf every other window's and
# set the step weights alone, making the early steps weigh orders of magnitude too much.
DIVERGED_FACTOR = 100.0
_ERROR_FLOOR = 1e-3  # group units: below it an error is the same as none (data from f itself)


def physics_step_mse(
    windows: Any, params: VehicleParams, batch_size: int = 8192
) -> tuple[torch.Tensor, int]:
    """The physics model's mean-square error per group and horizon step, (4, N) float64, over
    ``windows`` (a ``data.windows.Windows``): the squared error norms (``state.group_errors``,
    ``GROUPS`` order) of its open-loop prediction (``data.windows.physics_rollout``), averaged
    over the windows whose rollout did not diverge (``DIVERGED_FACTOR``); and how many did."""
    if len(windows) == 0:
        raise ValueError("physics_step_mse: no training window")
    pred = physics_rollout(windows, params, batch_size)
    errors = group_errors(pred, windows.states[:, windows.window.history :])
    worst = torch.stack([errors[g].amax(1) for g in GROUPS])  # (4, W), NaN where non-finite
    typical = worst.nan_to_num(nan=torch.inf).median(1, keepdim=True).values
    bound = DIVERGED_FACTOR * typical.clamp_min(_ERROR_FLOOR)
    diverged = (~torch.isfinite(worst) | (worst > bound)).any(0)
    if bool(diverged.all()):
        raise ValueError("physics_step_mse: the physics rollout diverged on every window")
    kept = ~diverged
    return torch.stack([errors[g][kept].square().mean(0) for g in GROUPS]), int(diverged.sum())


def _is_global_zero() -> bool:
    """Whether this is the first process of a run (DDP starts one per device)."""
    from lightning.pytorch.utilities import rank_zero_only

    return rank_zero_only.rank == 0


def _check_run_folder(out: Path, resume: bool) -> Path:
    """The run folder's ``last.ckpt``, after checking that ``out`` can take or continue a run."""
    last = out / LAST
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"run folder {out} is a file, expected a folder")
    if resume and not last.is_file():
        raise FileNotFoundError(f"cannot resume: {last} does not exist")
    if not resume and last.is_file():
        raise FileExistsError(
            f"{out} already holds a run ({LAST}): continue it with --resume (resume=True) or "
            "choose another --out (out=)"
        )
    if resume:  # a process killed while writing a checkpoint leaves its temporary file
        for stale in out.glob(".*.ckpt.*.tmp"):
            stale.unlink(missing_ok=True)
    return last


def _check_counts(*, devices: int, num_threads: int | None) -> None:
    if devices < 1:
        raise ValueError(f"devices must be >= 1, got {devices}")
    if num_threads is not None and num_threads < 1:
        raise ValueError(f"num_threads (torch CPU threads) must be >= 1, got {num_threads}")


def _new_network(model_config: ModelConfig, dataset: Dataset, params: VehicleParams) -> nn.Module:
    """A fresh network of the configured architecture with the model constants ``params``,
    normalised on the training windows (draws its weights from torch's generator: seed it
    first)."""
    net = build(model_config, params)
    train_windows = dataset.splits["train"]
    if model_config.normalize and len(train_windows):
        origin = dataset.window.history - 1  # the step ``forward`` measures positions from
        net.fit_normalization(train_windows.states, train_windows.inputs, origin_step=origin)
    return net


def _checkpoint_meta(run: RunConfig, dataset: Dataset) -> dict[str, Any]:
    """Every config of the run as plain dicts: embedded in each checkpoint (``CKPT_KEY``), so
    ``load_checkpoint`` rebuilds the network from the file alone (``RunConfig.from_meta``
    reads the run back; its loss weights are under "weights"). The windows are the dataset's
    (a loaded ``Dataset`` brings its own)."""
    return {
        "format": CKPT_FORMAT,
        "package_version": __version__,
        "variant": run.variant,
        "preset": run.preset,
        "model": to_dict(run.model),
        "weights": to_dict(run.loss),
        "train": to_dict(run.train),
        "window": to_dict(dataset.window),
        "params": to_dict(dataset.params),
        "params_source": dataset.params_source,
        "data": str(dataset.folder),
    }


def _callbacks(
    out: Path, config: TrainConfig
) -> tuple[ModelCheckpoint, ModelCheckpoint, EarlyStopping, SaveOnInterrupt]:
    """best.ckpt, last.ckpt, early stopping, and the save on a signal, in that order."""
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
    return best_cb, last_cb, stop_cb, SaveOnInterrupt(out / LAST)


def _fit(
    module: SlungLoadModule,
    datamodule: WindowData,
    callbacks: tuple[Any, ...],
    out: Path,
    accelerator: str,
    devices: int,
    config: TrainConfig,
    progress: bool,
    resume: bool,
    extra: tuple[Any, ...] = (),
) -> L.Trainer:
    """Fit (from ``last.ckpt`` when resuming) with ``callbacks`` and the ``extra`` ones; a
    signal becomes ``TrainingInterrupted``."""
    last, interrupt_cb = out / LAST, callbacks[-1]
    with _quiet_lightning(), _sigint_as_sigterm() as sigints:
        every = [*callbacks, *extra]
        trainer = _make_trainer(out, accelerator, devices, config, every, progress)
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
                "the same command and --resume (resume=True)",
                signum,
            ) from None
    return trainer


def _make_trainer(
    out: Path,
    accelerator: str,
    devices: int,
    config: TrainConfig,
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
        max_time=timedelta(seconds=config.max_time) if config.max_time else None,
        gradient_clip_val=config.grad_clip or None,
        callbacks=[*callbacks, LearningRateMonitor(logging_interval="epoch")],
        plugins=[AtomicCheckpointIO()],
        logger=[
            _ResumableCSVLogger(out, name="csv", version=""),
            TensorBoardLogger(out, name="tensorboard", version="", default_hp_metric=False),
        ],
        default_root_dir=out,
        enable_progress_bar=progress,
        enable_model_summary=False,  # its table ends in '0 Total Flops'; run.json says enough
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
