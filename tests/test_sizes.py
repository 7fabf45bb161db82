"""Named network sizes (``config.MODEL_SIZES``): each builds its layers, a run records its size,
the checkpoint rebuilds from the file alone, and the command line lists what the registry
holds."""

from __future__ import annotations

import shutil
from itertools import pairwise

import pytest
import torch
from flights import SMALL, WINDOW_ARGS

from slungload.cli.common import choices
from slungload.config import (
    ARCHITECTURES,
    DEFAULT_SIZE,
    MODEL_SIZES,
    ModelConfig,
    size_tag,
)
from slungload.layout import INPUT_DIM, STATE_DIM
from slungload.models.base import count_parameters
from slungload.models.registry import build
from slungload.run_config import RunConfig


def expected_parameters(size: str, slack: bool) -> int:
    """The parameter count of the paper's layer plan at a size's widths, counted by hand."""
    s = MODEL_SIZES[size]
    h, e = s.hidden_size, s.embed_sizes[-1]

    def linears(widths) -> int:
        return sum(a * b + b for a, b in pairwise(widths))

    def lstm(inputs: int) -> int:  # 4 gates, input and hidden weights, two biases per layer
        first = 4 * h * (inputs + h) + 8 * h
        return first + (s.num_layers - 1) * (4 * h * 2 * h + 8 * h)

    embedding = linears((STATE_DIM + INPUT_DIM, *s.embed_sizes))
    attention = 2 * h * h + h  # W, U (H x H), v (H)
    head = linears((h, *s.head_sizes, STATE_DIM * (2 if slack else 1)))
    return embedding + lstm(e) + attention + lstm(h + e) + head


@pytest.mark.parametrize("architecture", sorted(ARCHITECTURES))
@pytest.mark.parametrize("size", list(MODEL_SIZES))
def test_a_named_size_builds_its_layers(size: str, architecture: str):
    config = ModelConfig.sized(size, architecture=architecture)
    net = build(config, None)
    chosen = MODEL_SIZES[size]
    assert [layer.out_features for layer in net.embed.layers] == list(chosen.embed_sizes)
    for lstm in (net.encoder, net.decoder):
        assert (lstm.hidden_size, lstm.num_layers) == (chosen.hidden_size, chosen.num_layers)
    widths = [layer.out_features for layer in net.head.layers]
    assert widths == [*chosen.head_sizes, 2 * STATE_DIM]  # slack outputs by default
    assert count_parameters(net) == expected_parameters(size, slack=True)
    assert config.size == size


def test_the_paper_size_is_the_default_and_the_papers_count():
    assert ModelConfig().size == DEFAULT_SIZE == "paper"
    assert ModelConfig.sized("paper") == ModelConfig()
    assert expected_parameters("paper", slack=True) == 238_906  # the paper's count
    counts = [expected_parameters(name, slack=False) for name in MODEL_SIZES]
    assert counts == sorted(counts, reverse=True)  # the registry lists the largest first
    assert counts[-1] < 5_000


def test_a_small_size_predicts_every_step():
    config = ModelConfig.sized("tiny", architecture="physics-step", slack=False)
    net = build(config, None).eval()
    m, n = 6, 4
    x = torch.zeros(3, m, STATE_DIM)
    x[..., 6], x[..., 12] = 1.0, -0.7  # unit quaternion, load below
    u = torch.zeros(3, m + n, INPUT_DIM)
    u[..., 0] = 14.0
    with torch.no_grad():
        states = net(x, u[:, :m], u[:, m:]).states
    assert states.shape == (3, n, STATE_DIM) and torch.isfinite(states).all()


def test_an_unknown_size_is_an_error_listing_the_known_ones():
    with pytest.raises(ValueError, match="unknown network size 'huge'") as info:
        ModelConfig.sized("huge")
    for name, size in MODEL_SIZES.items():
        assert name in str(info.value) and size.summary() in str(info.value)
    with pytest.raises(ValueError, match="hidden_size"):
        ModelConfig.sized("small", hidden_size=64)  # a size or widths, not both
    with pytest.raises(ValueError, match="positive integer"):
        ModelConfig(hidden_size=0)
    with pytest.raises(ValueError, match="at least one layer"):
        ModelConfig(embed_sizes=())


def test_folders_and_labels_name_a_size_other_than_the_papers():
    template = RunConfig(
        "no-physics", model=ModelConfig(architecture="physics-step", load_estimate="smoothed")
    )
    assert template.folder() == "physics-step-no-physics-smoothed-s0"  # as before sizes
    small = RunConfig(template.variant, model=template.model.resized("small"))
    assert small.folder() == "physics-step-small-no-physics-smoothed-s0"
    assert small.label() == "physics-step-small/no-physics+smoothed"
    paper_net = RunConfig(model=ModelConfig.sized("tiny"))
    assert paper_net.folder() == "tiny-proposed-s0"
    assert paper_net.label() == "lstm-attention-tiny/proposed"
    custom = ModelConfig(hidden_size=7)  # widths of no name: no tag, as before sizes had names
    assert custom.size is None and size_tag(custom) == ""
    assert RunConfig(model=custom).folder() == "proposed-s0"


def test_a_run_file_may_name_a_size():
    run = RunConfig.from_toml(
        'variant = "no-physics"\n[model]\narchitecture = "physics-step"\nsize = "small"\n'
    )
    assert run.model == ModelConfig.sized("small", architecture="physics-step", slack=False)
    assert RunConfig.from_toml(run.to_toml()) == run  # written with the widths themselves
    with pytest.raises(ValueError, match="unknown network size 'huge'"):
        RunConfig.from_toml('[model]\nsize = "huge"\n')
    with pytest.raises(ValueError, match="unknown keys"):
        RunConfig.from_toml('[model]\nsize = "small"\nwidth = 3\n')


def test_train_size_is_recorded_and_the_checkpoint_rebuilds_alone(run_cli, write_dataset, tmp_path):
    from slungload.models.checkpoints import load_checkpoint
    from slungload.run_config import read_toml

    data = write_dataset(tmp_path / "data", physics=True)
    out = tmp_path / "run"
    code, _, _ = run_cli(
        "train", "--data", data, "--out", out, "--preset", "quick", "--epochs", "1",
        "--model", "physics-step", "--size", "tiny", "--device", "cpu", "--threads", "1",
        "--quiet", *WINDOW_ARGS,
    )  # fmt: skip
    assert code == 0
    expected = ModelConfig.sized("tiny", architecture="physics-step")
    assert read_toml(out / "run.toml").model == expected
    alone = tmp_path / "elsewhere" / "model.ckpt"  # the file without its run folder
    alone.parent.mkdir()
    shutil.copyfile(out / "best.ckpt", alone)
    shutil.rmtree(out)
    loaded = load_checkpoint(alone)
    assert loaded.model_config == expected and loaded.model_config.size == "tiny"
    assert loaded.run.folder() == "physics-step-tiny-proposed-N4-s0"
    assert count_parameters(loaded.model) == expected_parameters("tiny", slack=True)
    m, n = SMALL.history, SMALL.horizon
    x = torch.zeros(2, m, STATE_DIM)
    x[..., 6], x[..., 12] = 1.0, -0.7
    u = torch.full((2, m + n, INPUT_DIM), 1.0)
    with torch.no_grad():
        assert torch.isfinite(loaded.model(x, u[:, :m], u[:, m:]).states).all()


def test_train_refuses_an_unknown_size_listing_the_known_ones(run_cli, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        run_cli("train", "--data", tmp_path, "--out", tmp_path / "r", "--size", "huge")
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "huge" in err and all(name in err for name in MODEL_SIZES)


@pytest.mark.parametrize("argv", [("train", "--help"), ("study", "size", "--help")])
def test_the_help_lists_the_registry(argv, capsys):
    from slungload.cli import build_parser

    assert choices("sizes") == list(MODEL_SIZES)
    with pytest.raises(SystemExit):
        build_parser().parse_args(list(argv))
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps the help
    for name, size in MODEL_SIZES.items():
        assert name in text and size.summary() in text
