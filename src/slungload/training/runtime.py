"""Workarounds around Lightning for robust runs: checkpoints written through a temporary file
(``AtomicCheckpointIO``), ``last.ckpt`` saved on SIGTERM/SIGINT (``SaveOnInterrupt``,
``_sigint_as_sigterm``), a CSV log that a resumed run appends to, and quiet output.
"""

from __future__ import annotations

import contextlib
import csv
import logging
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import (
    Callback,
)
from lightning.pytorch.loggers import CSVLogger
from lightning.pytorch.loggers.csv_logs import ExperimentWriter
from lightning.pytorch.loggers.logger import rank_zero_experiment
from lightning.pytorch.plugins.io import TorchCheckpointIO
from lightning.pytorch.utilities.exceptions import SIGTERMException

from ..fileio import atomic_path


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


class EpochReport(Callback):
    """Hands ``report(epoch, metrics, net)`` each finished validation epoch's ``val/...``
    metrics (floats) and the network being trained (on the global-zero process, not during
    the sanity check): how a configuration search (``slungload tune``) follows a trial and
    stops the poor ones early."""

    def __init__(self, report: Callable[[int, dict[str, float], Any], None]) -> None:
        self.report = report

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero:
            return
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val/")}
        self.report(trainer.current_epoch, metrics, pl_module.net)


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
def _quiet_lightning() -> Iterator[None]:
    """Keep Lightning's output to what a user needs (the progress bar, warnings that matter):
    silence its info lines (accelerator and TPU lines, tips, the SIGTERM notice, checkpoint
    restoring) and its warnings about our deliberate choices."""
    levels: dict[str, int] = {}
    with warnings.catch_warnings():
        # Windows are tensors in memory (no workers needed); resuming into the run folder is
        # the point of resume; checkpoints are read with weights_only=True on purpose.
        # Lightning 2.6 on torch 2.13 warns about its own use of torch's pytree.
        for pattern in (
            r".*does not have many workers.*",
            r".*exists and is not empty.*",
            r".*treespec, LeafSpec.*",
            r".*`training_step` returned `None`.*",  # a skipped non-finite step, on purpose
            r".*weights_only.*",
            r".*callbacks used to create the checkpoint.*",  # the time cap's Timer, on resume
        ):
            warnings.filterwarnings("ignore", message=pattern)
        for name in ("lightning.pytorch", "lightning.fabric", "lightning"):
            levels[name] = logging.getLogger(name).level
            logging.getLogger(name).setLevel(logging.WARNING)
        try:
            yield
        finally:
            for name, level in levels.items():
                logging.getLogger(name).setLevel(level)
