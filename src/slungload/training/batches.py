"""Batches: the data side of training, from ``Windows`` tensors to the batches of each epoch.

``WindowTensors`` gathers a whole batch of windows at once, ``EpochBatches`` draws each
epoch's index batches from ``(seed, epoch)`` and shards them over DDP processes, and
``WindowData`` (a LightningDataModule) serves the training and validation loaders from them,
the training windows of a bootstrap resample of their flights with ``TrainConfig.bootstrap``.
``augment_yaw`` turns a training batch about the vertical (``TrainConfig.augment_yaw``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import lightning as L
import numpy as np
import torch
from torch import Tensor
from torch.utils.data import DataLoader, Sampler

from ..config import TrainConfig
from ..data.windows import Windows
from ..state import rotate_about_z


class WindowTensors(torch.utils.data.Dataset):
    """Windows as a map-style dataset indexed by a whole batch of indices at once.

    ``dataset[idx]`` with an index tensor (B,) -> states (B, M+N, 13), inputs (B, M+N, 4),
    aux (B, M+N, 6): one gather per tensor instead of B item lookups and a collate.
    """

    def __init__(self, windows: Windows) -> None:
        self.tensors = (windows.states, windows.inputs, windows.aux)

    def __len__(self) -> int:
        return len(self.tensors[0])

    def __getitem__(self, index: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        return tuple(t[index] for t in self.tensors)  # type: ignore[return-value]


class EpochBatches(Sampler[Tensor]):
    """Index batches of one epoch, drawn from ``(seed, epoch)`` and split over processes.

    shuffle=True: a random permutation (several back to back if ``num_samples`` > n), cut to
    ``num_samples``; shuffle=False: 0 .. n-1 in order. Process ``rank`` of ``world_size`` takes
    every world_size-th index of an equal-length prefix, so all processes run the same number
    of batches (DDP needs that). Lightning calls ``set_epoch`` before each epoch.
    """

    def __init__(
        self,
        n: int,
        batch_size: int,
        *,
        num_samples: int | None = None,
        shuffle: bool = True,
        seed: int = 0,
        rank: int = 0,
        world_size: int = 1,
    ) -> None:
        if n < 1:
            raise ValueError("EpochBatches: no windows to draw from")
        self.n, self.batch_size, self.shuffle, self.seed = n, batch_size, shuffle, seed
        self.num_samples = num_samples if num_samples is not None else n
        self.rank, self.world_size = rank, world_size
        self.epoch = 0
        if self.num_samples < world_size:
            raise ValueError(f"EpochBatches: {self.num_samples} windows for {world_size} processes")

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _indices(self) -> Tensor:
        if not self.shuffle:
            idx = torch.arange(self.n)[: self.num_samples]
        else:
            seed = int(np.random.SeedSequence([self.seed, self.epoch]).generate_state(1)[0])
            gen = torch.Generator().manual_seed(seed)
            reps = math.ceil(self.num_samples / self.n)
            idx = torch.cat([torch.randperm(self.n, generator=gen) for _ in range(reps)])
            idx = idx[: self.num_samples]
        share = len(idx) // self.world_size
        return idx[: share * self.world_size][self.rank :: self.world_size]

    def __iter__(self) -> Iterator[Tensor]:
        yield from self._indices().split(self.batch_size)

    def __len__(self) -> int:
        share = self.num_samples // self.world_size
        return math.ceil(share / self.batch_size)


def bootstrap_flights(windows: Windows, seed: int) -> Windows:
    """The windows of a bootstrap resample of their flights (``TrainConfig.bootstrap``): as
    many flights as ``windows`` comes from, drawn with replacement from ``seed``; a flight
    drawn k times gives its windows k times. ValueError for fewer than 2 flights."""
    flights = torch.unique(windows.flight)
    if len(flights) < 2:
        raise ValueError(
            f"a bootstrap of the training flights needs at least 2 of them; the training "
            f"windows come from {len(flights)}"
        )
    state = np.random.SeedSequence([seed, len(flights)]).generate_state(1)[0]
    gen = torch.Generator().manual_seed(int(state))
    drawn = flights[torch.randint(len(flights), (len(flights),), generator=gen)]
    return windows[torch.cat([torch.nonzero(windows.flight == f).flatten() for f in drawn])]


class WindowData(L.LightningDataModule):
    """Training and validation loaders over ``Windows`` tensors, in the main process.

    ``val_windows``: validate on a fixed subset of this many windows, drawn from ``config.seed``
    (None: all of them).
    """

    def __init__(
        self, train: Windows, val: Windows, config: TrainConfig, *, val_windows: int | None = None
    ):
        super().__init__()
        if len(train) == 0 or len(val) == 0:
            raise ValueError(
                f"training needs windows in both splits; got train {len(train)}, val {len(val)}: "
                "write the split lists with slungload split (by recording; --blocks cuts one "
                "or two recordings in time), or import with --split blocks"
            )
        if config.bootstrap:
            train = bootstrap_flights(train, config.seed)
        self.train_windows, self.config = train, config
        if val_windows is not None and val_windows < len(val):
            gen = torch.Generator().manual_seed(config.seed)
            pick = torch.randperm(len(val), generator=gen)[:val_windows]
            val = val[pick.sort().values]
        self.val_windows = val

    def _loader(self, windows: Windows, *, train: bool) -> DataLoader:
        trainer = self.trainer
        rank, world = (trainer.global_rank, trainer.world_size) if trainer else (0, 1)
        sampler = EpochBatches(
            len(windows),
            self.config.batch_size,
            num_samples=self.config.windows_per_epoch if train else None,
            shuffle=train,
            seed=self.config.seed,
            rank=rank,
            world_size=world,
        )
        return DataLoader(WindowTensors(windows), batch_size=None, sampler=sampler)

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train_windows, train=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.val_windows, train=False)


def augment_yaw(batch: tuple[Tensor, Tensor, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """The batch turned about z by a yaw per window, uniform in [-pi, pi) (so a level
    attitude keeps w >= 0, as in the data). Drawn from torch's generator, which
    ``SlungLoadModule.on_train_batch_start`` (training.py) reseeds per batch: resumed runs
    turn the same way."""
    states, inputs, aux = batch
    yaw = (2.0 * torch.rand(len(states), 1, device=states.device) - 1.0) * math.pi  # (B, 1)
    states, aux = rotate_about_z(states, aux, yaw.to(states.dtype))
    return states, inputs, aux
