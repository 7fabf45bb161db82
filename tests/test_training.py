"""Training: runs, logs, checkpoints, determinism, resume, variants, DDP on CPU.

Tiny flights come from the package's own physics model, written in the published file schema;
the network is shrunk (``TINY``) and the windows short (``SMALL``) so each run takes seconds.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import SMALL, TINY

from slungload.config import LossWeights, TrainConfig, to_dict
from slungload.data.dataset import load_dataset
from slungload.loss import LOSS_VARIANTS, compute_loss
from slungload.models.checkpoints import load_checkpoint
from slungload.run_config import PRESETS, Preset
from slungload.state import LOAD_POS, POS, VEL
from slungload.training.batches import EpochBatches, WindowData, bootstrap_flights
from slungload.training.module import _warmup_cosine

torch.set_num_threads(1)

LOSS_TERMS = ("total", "fit", "physics", "projection", "slack")


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory, write_dataset) -> Path:
    """Six physics-model flights of 60 steps around hover with a swinging load."""
    flights = {f"flight_{i:02d}": 60 for i in range(6)}
    return write_dataset(tmp_path_factory.mktemp("flights"), flights, physics=True)


@pytest.fixture(scope="module")
def dataset(data_dir: Path, tmp_path_factory: pytest.TempPathFactory):
    return load_dataset(data_dir, window=SMALL, cache_dir=tmp_path_factory.mktemp("cache"))


def read_metrics(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "csv" / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def epoch_values(rows: list[dict[str, str]], key: str) -> list[float]:
    return [float(r[key]) for r in rows if r.get(key)]


# --- the run folder ------------------------------------------------------------------------


def test_quick_run_writes_checkpoints_logs_and_summary(
    data_dir: Path, tmp_path: Path, train_tiny
) -> None:
    run = train_tiny(data_dir, tmp_path / "run", window=SMALL)  # from the folder itself
    assert run.epochs == PRESETS["quick"].config.max_epochs
    assert run.stop_reason == "max_epochs"
    assert run.best_checkpoint == tmp_path / "run" / "best.ckpt" and run.best_checkpoint.is_file()
    assert run.last_checkpoint.is_file()
    assert np.isfinite(run.best_val_loss)

    summary = json.loads((tmp_path / "run" / "run.json").read_text())
    assert summary["variant"] == "proposed" and summary["epochs"] == run.epochs
    assert summary["config"]["window"] == to_dict(SMALL)
    assert summary["config"]["model"]["hidden_size"] == TINY.hidden_size

    rows = read_metrics(tmp_path / "run")
    for stage in ("train", "val"):
        for term in LOSS_TERMS:
            assert len(epoch_values(rows, f"{stage}/{term}")) == run.epochs, f"{stage}/{term}"
    assert len(epoch_values(rows, "val/fit_rmse")) == run.epochs

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(tmp_path / "run" / "tensorboard"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert {f"{s}/{t}" for s in ("train", "val") for t in LOSS_TERMS} <= tags
    assert "val/fit_rmse" in tags


def test_fit_rmse_is_the_sum_of_group_rmses(dataset, tmp_path: Path, train_tiny) -> None:
    run = train_tiny(dataset, tmp_path / "run")
    groups = sum(run.metrics[f"val/rmse_{g}"] for g in ("position", "velocity", "quaternion"))
    groups += run.metrics["val/rmse_load_position"]
    assert run.metrics["val/fit_rmse"] == pytest.approx(groups, rel=1e-5)


def test_existing_run_is_not_overwritten_and_resume_needs_one(
    dataset, tmp_path: Path, train_tiny
) -> None:
    with pytest.raises(FileNotFoundError, match="last.ckpt"):
        train_tiny(dataset, tmp_path / "run", resume=True)
    train_tiny(dataset, tmp_path / "run", max_epochs=1)
    with pytest.raises(FileExistsError, match="resume"):
        train_tiny(dataset, tmp_path / "run")
    # a worker killed while writing last.ckpt left its temporary file: a resume removes it
    stale = tmp_path / "run" / ".last.ckpt.abc123.tmp"
    stale.write_bytes(b"half a checkpoint")
    train_tiny(dataset, tmp_path / "run", resume=True, max_epochs=2)
    assert not stale.exists() and (tmp_path / "run" / "last.ckpt").is_file()


def test_bad_options_are_refused(dataset, tmp_path: Path, train_tiny) -> None:
    with pytest.raises(ValueError, match="preset"):
        train_tiny(dataset, tmp_path / "a", preset="fastest")
    with pytest.raises(ValueError, match="device"):
        train_tiny(dataset, tmp_path / "b", device="tpu")
    with pytest.raises(ValueError, match="variant"):
        train_tiny(dataset, tmp_path / "c", variant="no-such-thing")


# --- optimisation --------------------------------------------------------------------------


def test_loss_decreases_when_overfitting_a_few_windows(dataset, tmp_path: Path, train_tiny) -> None:
    few = dataclasses.replace(
        dataset, splits={**dataset.splits, "train": dataset.splits["train"][torch.arange(8)]}
    )
    overfit = Preset(
        "overfit",
        TrainConfig(lr=3e-3, weight_decay=0.0, batch_size=8, max_epochs=60, patience=1000),
    )
    run = train_tiny(few, tmp_path / "run", preset=overfit)
    losses = epoch_values(read_metrics(tmp_path / "run"), "train/total")
    assert len(losses) == 60
    assert losses[-1] < 0.2 * losses[0], (losses[0], losses[-1])
    assert run.best_val_loss <= epoch_values(read_metrics(tmp_path / "run"), "val/total")[0]


def test_warmup_cosine_schedule_shape() -> None:
    factor = _warmup_cosine(warmup=10, total=110, floor=0.1)
    ramp = [factor(s) for s in range(10)]
    assert ramp == sorted(ramp) and ramp[0] > 0 and ramp[-1] == pytest.approx(1.0)
    decay = [factor(s) for s in range(10, 111)]
    assert all(a >= b for a, b in zip(decay[:-1], decay[1:], strict=True))
    assert decay[0] == pytest.approx(1.0) and decay[-1] == pytest.approx(0.1)
    assert factor(60) == pytest.approx(0.55)  # half way down the cosine


def test_cosine_preset_logs_warmup_then_decay(dataset, tmp_path: Path, train_tiny) -> None:
    cosine = Preset(
        "cosine",
        dataclasses.replace(
            PRESETS["quick"].config,
            max_epochs=5,
            patience=100,
            lr_schedule="cosine",
            warmup_epochs=2,
            min_lr_ratio=0.0,
            val_windows=16,
        ),
    )
    train_tiny(dataset, tmp_path / "run", preset=cosine)
    lrs = epoch_values(read_metrics(tmp_path / "run"), "lr-Adam")
    peak = lrs.index(max(lrs))
    assert 0 < peak <= 2 and lrs[0] < lrs[peak] and lrs[-1] < lrs[peak]


# --- batches -------------------------------------------------------------------------------


def test_epoch_batches_are_seeded_by_epoch_and_shard_evenly() -> None:
    def epoch(seed: int, e: int, rank: int = 0, world: int = 1) -> torch.Tensor:
        s = EpochBatches(50, 8, num_samples=30, seed=seed, rank=rank, world_size=world)
        s.set_epoch(e)
        batches = list(s)
        assert len(batches) == len(s)
        return torch.cat(batches)

    assert torch.equal(epoch(0, 3), epoch(0, 3))
    assert not torch.equal(epoch(0, 3), epoch(0, 4))
    assert not torch.equal(epoch(0, 3), epoch(1, 3))
    assert len(set(epoch(0, 3).tolist())) == 30  # without replacement
    shards = [epoch(0, 3, rank, 3) for rank in range(3)]
    assert all(len(s) == 10 for s in shards)
    assert torch.equal(torch.cat(shards).sort().values, epoch(0, 3).sort().values)
    ordered = EpochBatches(10, 4, shuffle=False)
    assert torch.equal(torch.cat(list(ordered)), torch.arange(10))
    more = EpochBatches(5, 4, num_samples=12)  # more windows per epoch than exist
    assert torch.bincount(torch.cat(list(more)), minlength=5).min() >= 2


def test_a_bootstrap_draws_whole_flights_with_replacement(dataset) -> None:
    train = dataset.splits["train"]
    flights = torch.unique(train.flight)
    per_flight = torch.bincount(train.flight, minlength=len(train.names))

    def times_drawn(w) -> torch.Tensor:
        counts = torch.bincount(w.flight, minlength=len(train.names))
        drawn = counts // per_flight.clamp(min=1)
        assert torch.equal(counts, drawn * per_flight)  # each flight's windows come whole
        return drawn

    draws = [times_drawn(bootstrap_flights(train, seed)) for seed in range(20)]
    assert all(int(d.sum()) == len(flights) for d in draws)  # as many flights as there are
    assert torch.equal(times_drawn(bootstrap_flights(train, 3)), draws[3])  # seeded
    assert any(not torch.equal(d, draws[0]) for d in draws[1:])
    assert any(int(d.max()) >= 2 for d in draws)  # with replacement
    config = dataclasses.replace(TrainConfig(), bootstrap=True, seed=3)
    data = WindowData(train, dataset.splits["val"], config)
    assert torch.equal(times_drawn(data.train_windows), draws[3])
    with pytest.raises(ValueError, match="at least 2"):
        bootstrap_flights(train[train.flight == flights[0]], 0)


# --- determinism and resume ----------------------------------------------------------------


def test_same_seed_gives_identical_weights(dataset, tmp_path: Path, train_tiny, weights_of) -> None:
    config = dataclasses.replace(TINY, dropout=0.2, num_layers=2)  # dropout draws numbers too
    a = train_tiny(dataset, tmp_path / "a", seed=3, model=config)
    b = train_tiny(dataset, tmp_path / "b", seed=3, model=config)
    c = train_tiny(dataset, tmp_path / "c", seed=4, model=config)
    wa, wb, wc = (weights_of(r.last_checkpoint) for r in (a, b, c))
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    assert not all(torch.equal(wa[k], wc[k]) for k in wa)


def test_resume_continues_the_epoch_count_and_matches_one_long_run(
    dataset, tmp_path: Path, train_tiny, weights_of
) -> None:
    config = dataclasses.replace(TINY, dropout=0.2, num_layers=2)  # dropout draws numbers too
    first = train_tiny(dataset, tmp_path / "split", max_epochs=1, model=config)
    assert first.epochs == 1
    one_epoch = torch.load(first.last_checkpoint, weights_only=True)["global_step"]
    resumed = train_tiny(dataset, tmp_path / "split", max_epochs=3, resume=True, model=config)
    assert resumed.epochs == 3
    rows = read_metrics(tmp_path / "split")
    assert epoch_values(rows, "epoch")[-1] == 2
    assert len(epoch_values(rows, "train/total")) == 3  # the first call's rows are kept
    straight = train_tiny(dataset, tmp_path / "straight", max_epochs=3, model=config)
    # last.ckpt is the last epoch's even when that epoch did not improve on the best one.
    last = torch.load(straight.last_checkpoint, weights_only=True)
    assert last["global_step"] == 3 * one_epoch
    # Windows and dropout are drawn from (seed, epoch, batch): the same weights.
    ws, wr = weights_of(straight.last_checkpoint), weights_of(resumed.last_checkpoint)
    assert all(torch.allclose(ws[k], wr[k], atol=1e-6) for k in ws)


def test_a_run_from_before_a_model_field_existed_resumes(dataset, tmp_path: Path, train_tiny):
    """A checkpoint whose model config lacks a field added since (here heading_frame) holds its
    default: resuming it is not refused as "other settings"."""
    from slungload.models.checkpoints import CKPT_KEY

    first = train_tiny(dataset, tmp_path / "old", max_epochs=1)
    ckpt = torch.load(first.last_checkpoint, weights_only=True)
    del ckpt[CKPT_KEY]["model"]["heading_frame"]
    torch.save(ckpt, first.last_checkpoint)
    resumed = train_tiny(dataset, tmp_path / "old", max_epochs=2, resume=True)
    assert resumed.epochs == 2


# --- checkpoints ---------------------------------------------------------------------------


def test_load_checkpoint_reproduces_the_logged_validation_loss(
    dataset, tmp_path: Path, train_tiny
) -> None:
    run = train_tiny(dataset, tmp_path / "run")
    assert len(dataset.splits["val"]) <= PRESETS["quick"].config.val_windows  # all are used
    loaded = load_checkpoint(tmp_path / "run")  # the folder means best.ckpt
    assert loaded.path == run.best_checkpoint
    assert not loaded.model.training
    assert loaded.variant == "proposed" and loaded.window == SMALL
    assert loaded.params == dataset.params and loaded.model_config == TINY

    val = dataset.splits["val"]
    m = SMALL.history
    with torch.no_grad():
        pred = loaded.model(val.states[:, :m], val.inputs[:, :m], val.inputs[:, m:])
        terms = compute_loss(
            pred,
            val.states,
            val.inputs,
            val.aux,
            history=m,
            params=loaded.params,
            weights=loaded.weights,
            variant=loaded.variant,
        )
    assert float(terms.total) == pytest.approx(run.best_val_loss, rel=1e-4)

    again = load_checkpoint(run.best_checkpoint).model
    x = val.states[:3, :m], val.inputs[:3, :m], val.inputs[:3, m:]
    assert torch.equal(loaded.model(*x).states, again(*x).states)


def test_non_slungload_files_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.ckpt"):
        load_checkpoint(tmp_path / "missing.ckpt")
    garbage = tmp_path / "garbage.ckpt"
    garbage.write_bytes(b"not a checkpoint at all")
    with pytest.raises(ValueError, match="garbage.ckpt.*not a readable checkpoint"):
        load_checkpoint(garbage)
    other = tmp_path / "other.ckpt"
    torch.save({"state_dict": {"w": torch.zeros(2)}, "epoch": 3}, other)
    with pytest.raises(ValueError, match="other.ckpt.*not a slungload checkpoint"):
        load_checkpoint(other)


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


def test_checkpoints_with_pickled_objects_are_refused(tmp_path: Path) -> None:
    evil = tmp_path / "evil.ckpt"
    torch.save({"state_dict": {}, "slungload": _Evil()}, evil)
    with pytest.raises(ValueError, match="evil.ckpt"):
        load_checkpoint(evil)


# --- variants ------------------------------------------------------------------------------


@pytest.mark.parametrize("variant", sorted(LOSS_VARIANTS))
def test_each_variant_trains_and_reloads(variant: str, dataset, tmp_path: Path, train_tiny) -> None:
    one_step = Preset("one", dataclasses.replace(PRESETS["quick"].config, max_epochs=1))
    run = train_tiny(dataset, tmp_path / variant, variant=variant, preset=one_step)
    assert run.epochs == 1 and run.variant == variant
    loaded = load_checkpoint(run.out)
    assert loaded.variant == variant
    assert loaded.model_config.slack == LOSS_VARIANTS[variant].slack
    val = dataset.splits["val"]
    pred = loaded.model(val.states[:2, :6], val.inputs[:2, :6], val.inputs[:2, 6:])
    assert (pred.slack is not None) == LOSS_VARIANTS[variant].slack
    if not LOSS_VARIANTS[variant].physics:
        assert run.metrics["val/physics"] == 0.0


# --- several processes ---------------------------------------------------------------------


@pytest.mark.slow
def test_ddp_with_two_cpu_processes(
    data_dir: Path, tmp_path: Path, train_command, subprocess_env
) -> None:
    """Lightning's "ddp" re-launches the command line, so run it as ``python -m``."""
    out = tmp_path / "ddp"
    cmd = train_command(data_dir, out, "--devices", "2")
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env=subprocess_env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    summary = json.loads((out / "run.json").read_text())
    assert summary["epochs"] == PRESETS["quick"].config.max_epochs
    assert (out / "best.ckpt").is_file() and (out / "last.ckpt").is_file()
    assert len(epoch_values(read_metrics(out), "train/total")) == summary["epochs"]
    assert load_checkpoint(out).variant == "proposed"
    assert done.stdout.count("epochs in") == 1  # only rank 0 reports


def test_yaw_augmentation_is_a_symmetry_of_the_loss(dataset) -> None:
    from slungload.models.base import Prediction
    from slungload.training.batches import augment_yaw

    w = dataset.splits["train"][torch.arange(4)]
    m = dataset.window.history
    batch = (w.states.double(), w.inputs.double(), w.aux.double())
    torch.manual_seed(3)
    turned = augment_yaw(batch)
    assert not torch.allclose(turned[0][..., POS], batch[0][..., POS])
    assert torch.equal(turned[1], batch[1])  # thrust and body rates are body-frame quantities
    for part in (VEL, LOAD_POS):
        torch.testing.assert_close(
            turned[0][..., part].norm(dim=-1), batch[0][..., part].norm(dim=-1)
        )

    def physics_term(states, inputs, aux):
        # The truth as the "prediction": what is left is the paper's model's own error.
        pred = Prediction(states[:, m:], torch.zeros_like(states[:, m:]))
        return compute_loss(
            pred,
            states,
            inputs,
            aux,
            history=m,
            params=dataset.params,
            weights=LossWeights(),
            variant="proposed",
        ).physics

    original = physics_term(*batch)
    assert original > 0
    torch.testing.assert_close(physics_term(*turned), original, rtol=1e-9, atol=1e-12)


# --- the "physics-relative" step weighting --------------------------------------------------


def test_physics_step_mse_is_the_physics_models_error(dataset) -> None:
    from slungload.models.prediction import PhysicsModel
    from slungload.state import GROUPS, group_errors
    from slungload.training.trainer import physics_step_mse

    windows = dataset.splits["train"]
    mse, diverged = physics_step_mse(windows, dataset.params, batch_size=7)  # several batches
    predicted = PhysicsModel(dataset.params).predict_windows(windows)
    errors = group_errors(predicted, windows.future.states)
    expected = torch.stack([errors[g].square().mean(0) for g in GROUPS])
    torch.testing.assert_close(mse, expected)
    assert mse.shape == (len(GROUPS), dataset.window.horizon) and diverged == 0


def test_windows_whose_physics_rollout_diverged_set_no_step_weight(dataset) -> None:
    from slungload.training.trainer import physics_step_mse

    windows = dataset.splits["train"]
    mse, _ = physics_step_mse(windows, dataset.params)
    far, lost = windows.states.clone(), windows.states.clone()
    far[0, -2:, POS] += 1e4  # the truth 10 km away at the last steps: physics "misses" by 1e4 m
    lost[1, -1, VEL] = float("nan")
    for states, which in ((far, 0), (lost, 1)):
        stray = dataclasses.replace(windows, states=states)
        got, diverged = physics_step_mse(stray, dataset.params)
        kept = torch.arange(len(windows)) != which
        alone, _ = physics_step_mse(windows[kept], dataset.params)
        assert diverged == 1 and torch.isfinite(got).all()
        torch.testing.assert_close(got, alone)
        assert (got[0, -1] - mse[0, -1]).abs() < 0.5 * mse[0, -1]  # not 1e8 times larger


def test_physics_relative_run_records_its_scale_and_resumes(dataset, tmp_path: Path, train_tiny):
    weights = LossWeights(steps="physics-relative")
    run = train_tiny(dataset, tmp_path / "rel", loss=weights, max_epochs=1)
    summary = json.loads((run.out / "run.json").read_text())
    rms = summary["config"]["physics_rms"]
    assert set(rms) == {"position", "velocity", "quaternion", "load_position"}
    assert all(len(v) == dataset.window.horizon for v in rms.values())
    assert "physics_diverged" not in summary["config"]  # none diverged: recorded only when any
    assert load_checkpoint(run.out).weights.steps == "physics-relative"
    again = train_tiny(dataset, tmp_path / "rel", loss=weights, max_epochs=2, resume=True)
    assert again.epochs == 2
    with pytest.raises(ValueError, match="weights.steps"):  # not with the paper's weighting
        train_tiny(dataset, tmp_path / "rel", max_epochs=3, resume=True)


def test_a_run_whose_step_weights_changed_is_not_resumed(
    dataset, tmp_path, train_tiny, monkeypatch
):
    from slungload.training import trainer

    weights = LossWeights(steps="mixed")
    train_tiny(dataset, tmp_path / "mixed", loss=weights, max_epochs=1)
    computed = trainer.physics_step_mse
    monkeypatch.setattr(  # as if a window of its flights now diverged
        trainer, "physics_step_mse", lambda w, p: (computed(w, p)[0] * 0.5, 1)
    )
    with pytest.raises(ValueError, match="step weights came out otherwise"):
        train_tiny(dataset, tmp_path / "mixed", loss=weights, max_epochs=2, resume=True)
