"""The architecture registry and checkpoints that name their architecture (old ones included)."""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from torch import nn

from slungload.config import (
    ARCHITECTURES,
    DEFAULT_ARCHITECTURE,
    ModelConfig,
    TrainConfig,
    VehicleParams,
    WindowConfig,
    to_dict,
)
from slungload.deploy.compiled import CompiledPredictor, unsupported
from slungload.deploy.predictor import Predictor
from slungload.models import MODELS, architecture_of, build, load_checkpoint, require_architecture
from slungload.models.checkpoints import CKPT_FORMAT, CKPT_KEY, checkpoint_path
from slungload.models.lstm_attention import SlungLoadNet

TINY = ModelConfig(embed_sizes=(8, 8, 8), hidden_size=4, num_layers=2, head_sizes=(8, 8, 8))


def test_the_registry_reads_the_one_table_of_architectures():
    # The CLI lists ARCHITECTURES without loading torch; MODELS imports the classes it names.
    assert MODELS[DEFAULT_ARCHITECTURE] is SlungLoadNet
    for name, cls in MODELS.items():
        assert cls.architecture == name


def test_one_line_in_the_table_adds_an_architecture(monkeypatch):
    from slungload.config import Architecture

    class Renamed(SlungLoadNet):
        architecture = "renamed"

    import slungload.models.lstm_attention as module

    monkeypatch.setattr(module, "Renamed", Renamed, raising=False)
    monkeypatch.setitem(ARCHITECTURES, "renamed", Architecture("lstm_attention:Renamed", "test"))
    assert "renamed" in MODELS and MODELS["renamed"] is Renamed
    net = build(replace(TINY, architecture="renamed"), VehicleParams())
    assert isinstance(net, Renamed) and architecture_of(net) == "renamed"
    # a class registered under another name than its own is refused, naming both
    monkeypatch.setitem(ARCHITECTURES, "other", Architecture("lstm_attention:Renamed", "test"))
    with pytest.raises(TypeError, match="'other'"):
        MODELS["other"]


def test_the_controllers_are_registered_once_by_name():
    from slungload.control.controllers import (
        CONTROLLERS,
        REFERENCE,
        controller_class,
        reference_maker,
    )
    from slungload.control.geometric import GeometricLoadController
    from slungload.control.mpc import SamplingMPC
    from slungload.sim.config import SimConfig
    from slungload.sim.controller import PIDController

    classes = {name: controller_class(name) for name in CONTROLLERS}
    assert classes == {"pid": PIDController, "geometric": GeometricLoadController,
                       "mpc": SamplingMPC}  # fmt: skip
    make = reference_maker("geometric", SimConfig())
    first, second = make(0), make(1)
    assert isinstance(first, GeometricLoadController) and first is not second  # one per flight
    assert set(REFERENCE) < set(CONTROLLERS)
    with pytest.raises(ValueError, match="unknown controller 'lqr'; known: "):
        controller_class("lqr")
    with pytest.raises(ValueError, match="not built from the simulator's config alone"):
        reference_maker("mpc", SimConfig())


def test_build_makes_the_named_architecture():
    torch.manual_seed(0)
    net = build(TINY, VehicleParams())
    assert isinstance(net, SlungLoadNet) and architecture_of(net) == DEFAULT_ARCHITECTURE
    # The same seed builds the same weights as the class itself (training's reproducibility).
    torch.manual_seed(0)
    direct = SlungLoadNet(TINY)
    for a, b in zip(net.state_dict().values(), direct.state_dict().values(), strict=True):
        assert torch.equal(a, b)


def test_unknown_architectures_are_refused_by_name():
    with pytest.raises(ValueError, match="unknown model architecture 'no-such-net'"):
        ModelConfig(architecture="no-such-net")
    with pytest.raises(ValueError, match="not a registered architecture"):
        architecture_of(nn.Linear(2, 2))
    with pytest.raises(ValueError, match="does not support the 'lstm-attention' architecture"):
        require_architecture(SlungLoadNet(TINY), ("other",), "the exporter")


def save_checkpoint(path: Path, meta: dict, net: nn.Module) -> Path:
    """A checkpoint as training writes it: Lightning's state dict and our configs."""
    state = {f"net.{k}": v for k, v in net.state_dict().items()}
    torch.save({"state_dict": state, CKPT_KEY: meta}, path)
    return path


def current_meta(config: ModelConfig = TINY) -> dict:
    return {
        "format": CKPT_FORMAT,
        "package_version": "test",
        "variant": "proposed",
        "preset": "quick",
        "model": to_dict(config),
        "weights": {},
        "train": to_dict(TrainConfig()),
        "window": to_dict(WindowConfig(history=4, horizon=3)),
        "params": to_dict(VehicleParams()),
    }


def test_a_checkpoint_rebuilds_its_architecture_from_the_file(tmp_path):
    net = SlungLoadNet(TINY)
    loaded = load_checkpoint(save_checkpoint(tmp_path / "a.ckpt", current_meta(), net))
    assert isinstance(loaded.model, SlungLoadNet)
    assert loaded.model_config.architecture == DEFAULT_ARCHITECTURE
    for a, b in zip(net.state_dict().values(), loaded.model.state_dict().values(), strict=True):
        assert torch.equal(a, b)


def test_a_checkpoint_naming_an_unknown_architecture_is_refused_by_name(tmp_path):
    meta = current_meta()
    meta["model"] = {**meta["model"], "architecture": "from-the-future"}
    path = save_checkpoint(tmp_path / "future.ckpt", meta, SlungLoadNet(TINY))
    with pytest.raises(ValueError, match="from-the-future") as err:
        load_checkpoint(path)
    assert str(path) in str(err.value)


def test_an_old_checkpoint_loads_as_the_papers_network(tmp_path):
    # Written before architectures had names, with the schedule split in "train" + "extras".
    meta = current_meta()
    model = {k: v for k, v in meta["model"].items() if k != "architecture"}
    extras = {"warmup_epochs": 3, "min_lr_ratio": 0.05, "max_time": 600.0, "val_windows": 1024,
              "max_bad_steps": 10, "augment_yaw": False}  # fmt: skip
    train = {k: v for k, v in meta["train"].items() if k not in extras}
    meta.update(model=model, train=train, extras=extras)
    net = SlungLoadNet(TINY)
    loaded = load_checkpoint(save_checkpoint(tmp_path / "old.ckpt", meta, net))
    assert isinstance(loaded.model, SlungLoadNet)
    assert loaded.train_config.warmup_epochs == 3 and loaded.train_config.max_time == 600.0
    assert "extras" not in loaded.meta


def test_the_compiled_predictor_refuses_what_it_cannot_compile():
    class Other(SlungLoadNet):
        architecture = "other"

    other = Other.__new__(Other)
    nn.Module.__init__(other)
    other.config = TINY
    assert "does not support the 'other' architecture" in unsupported(other)
    assert unsupported(SlungLoadNet(TINY)) is None
    window = WindowConfig(history=4, horizon=3)
    with pytest.raises(ValueError, match="'other' architecture"):
        CompiledPredictor(Predictor(other, window, VehicleParams(), "x"), warm_up=False)


def test_a_run_folder_without_best_points_to_last(tmp_path):
    (tmp_path / "last.ckpt").write_bytes(b"")
    with pytest.raises(FileNotFoundError, match="last.ckpt"):
        checkpoint_path(tmp_path)


def test_train_config_holds_the_whole_schedule():
    # One object describes a run: the former "extras" are TrainConfig fields, checked alike.
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    assert {"warmup_epochs", "min_lr_ratio", "max_time", "val_windows", "augment_yaw"} <= names
    with pytest.raises(ValueError, match="max_time"):
        TrainConfig(max_time=0.0)


def test_mpc_maker_refuses_no_model_when_built():
    from slungload.control.mpc import InputLimits, MPCConfig, mpc_maker

    with pytest.raises(ValueError, match="needs a prediction model or a factory"):
        mpc_maker(None, InputLimits(4.0, 30.0, 4.0), MPCConfig(), VehicleParams())
