"""The run description: one ``RunConfig`` names its folder and label, round-trips through TOML
and a checkpoint, and is what ``train`` records."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from flights import SMALL, TINY

from slungload.config import LossWeights, ModelConfig, TrainConfig, WindowConfig
from slungload.run_config import PRESETS, RunConfig, read_toml

STEP = ModelConfig(architecture="physics-step", load_estimate="smoothed")
BEYOND = RunConfig.from_preset(
    "quick",
    variant="no-physics",
    seed=2,
    fit_constants=True,
    model=STEP,
    loss=LossWeights(steps="mixed"),
    window=WindowConfig(horizon=50),
)


@pytest.mark.parametrize(
    "run",
    [RunConfig(), BEYOND, RunConfig("no-slack").scheduled("paper", seed=7), BEYOND.uncapped()],
)
def test_toml_round_trip(run: RunConfig, tmp_path: Path):
    assert RunConfig.from_toml(run.to_toml()) == run
    assert read_toml(run.write_toml(tmp_path / "run.toml")) == run
    assert RunConfig.from_dict(run.to_dict()) == run


def test_a_short_file_names_a_preset_and_overrides_what_it_changes():
    run = RunConfig.from_toml(
        'variant = "no-physics"\npreset = "quick"\n[model]\narchitecture = "physics-step"\n'
        '[train]\nseed = 3\nmax_time = "none"\n'
    )
    assert run.train == replace(PRESETS["quick"].config, seed=3, max_time=None)
    assert run.model == ModelConfig(architecture="physics-step", slack=False)
    assert RunConfig.from_toml("") == RunConfig()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("variant = 'nope'", "unknown loss variant 'nope'"),
        ("[model]\nwidth = 3", r"unknown keys \['width'\]"),
        ("colour = 'red'", r"unknown keys \['colour'\]"),
        ("[train]\nmax_epochs = 0", "max_epochs must be >= 1"),
        ("model = 3", r"\[model\] must be a table"),
        ("[train\n", "not valid TOML"),
    ],
)
def test_a_bad_file_is_an_error_naming_it(tmp_path: Path, text: str, match: str):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        read_toml(path)
    assert str(path) in str(info.value)


def test_the_variant_decides_the_slack_outputs():
    assert RunConfig("proposed").model.slack and not RunConfig("no-physics").model.slack
    assert RunConfig("no-slack", model=ModelConfig(slack=True)) == RunConfig("no-slack")


def test_folder_and_label_name_what_differs_from_the_paper():
    assert RunConfig().folder() == "proposed-s0" and RunConfig().label() == "proposed"
    assert BEYOND.folder() == "physics-step-no-physics-fitted-mixed-N50-smoothed-s2"
    assert BEYOND.label() == "physics-step/no-physics+fit+mixed+smoothed"
    assert BEYOND.label(with_horizon=True) == "physics-step/no-physics+fit+mixed+N50+smoothed"
    # Seeds share a label and a schedule's name is not part of the identity.
    assert BEYOND.scheduled("default", seed=0).label() == BEYOND.label()
    heading = replace(BEYOND, model=replace(BEYOND.model, heading_frame=True))
    assert heading.folder() == "physics-step-no-physics-fitted-mixed-N50-smoothed-heading-s2"
    assert heading.label() == BEYOND.label() + "+heading"
    assert RunConfig.from_toml(heading.to_toml()) == heading


def test_from_preset_applies_the_overrides_to_the_preset():
    run = RunConfig.from_preset("default", seed=4, max_epochs=9, fit_constants=True)
    assert run.train == replace(PRESETS["default"].config, seed=4, max_epochs=9,
                                fit_constants=True)  # fmt: skip
    assert run.preset == "default" and RunConfig() == RunConfig.from_preset()
    with pytest.raises(ValueError, match="preset"):
        RunConfig.from_preset("fastest")
    custom = RunConfig(preset="mine", train=TrainConfig(max_epochs=2))
    assert RunConfig.from_toml(custom.to_toml()) == custom


def test_a_trained_run_records_its_description(tiny_run, tmp_path):
    from slungload.models.checkpoints import load_checkpoint
    from slungload.training.trainer import train

    loaded = load_checkpoint(tiny_run.out)
    written = read_toml(tiny_run.out / "run.toml")
    assert loaded.run == written
    assert written == RunConfig.from_preset("quick", model=TINY, window=SMALL, max_epochs=1)
    # and a run trained from that file is the same run again
    again = train(tiny_run.data, written, out=tmp_path / "again", progress=False, num_threads=1)
    assert load_checkpoint(again.out).run == written


def test_train_takes_the_heading_frame_option_and_a_config_file_describes_it(tmp_path):
    from slungload.cli import build_parser
    from slungload.cli.train import run_from_args

    base = ["train", "--data", "d", "--out", "o"]
    run = run_from_args(build_parser().parse_args([*base, "--heading-frame"]))
    assert run.model.heading_frame and run.folder().endswith("-heading-s0")
    assert not run_from_args(build_parser().parse_args(base)).model.heading_frame
    path = tmp_path / "run.toml"
    path.write_text(run.to_toml())
    with pytest.raises(ValueError, match="--heading-frame"):
        run_from_args(build_parser().parse_args([*base, "--config", str(path), "--heading-frame"]))
    assert run_from_args(build_parser().parse_args([*base, "--config", str(path)])) == run
