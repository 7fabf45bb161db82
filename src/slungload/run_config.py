"""One run description: what a training run trains, and under which schedule.

A ``RunConfig`` holds every config of one run (the loss variant, the network, the loss
weights, the windows and the optimisation schedule with its seed). It is what
``training.train`` takes, what ``reproduce`` and ``study`` queue, what a checkpoint embeds
(``from_meta`` reads it back), and it names its run folder (``folder``) and its label in the
tables (``label``). It reads and writes itself as TOML (``read_toml``, ``write_toml``)::

    variant = "no-physics"
    preset = "default"

    [model]
    architecture = "physics-step"

    [train]
    seed = 1

A table or key left out takes its default; in ``[train]`` that is the named preset's value,
so a file names a preset and overrides what it changes. ``[model]`` may name a network size
(``size = "small"``, a name of ``config.MODEL_SIZES``) in place of the widths; the file
``train`` writes holds the widths themselves. TOML has no null: an option that is
off (``max_time``, ``windows_per_epoch``, ``val_windows``) is written as ``"none"``.

The named schedules (``PRESETS``) live here too: ``paper`` is the paper's schedule,
``default`` the budget tuned for a 2-core CPU (measured in docs/training.md), ``quick`` a
smoke test. Nothing here imports torch, so the command line's help reads it fast.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from .config import (
    DEFAULT_ARCHITECTURE,
    LOSS_VARIANTS,
    LossWeights,
    ModelConfig,
    TrainConfig,
    WindowConfig,
    from_dict,
    size_tag,
    step_tag,
    to_dict,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


ADAPTIVE = "adaptive"  # the tag of a network whose f runs with constants estimated in flight
SEEING = "sees-constants"  # ... and of one whose correction sees them too (constants_input)
HEADING = "heading"  # ... and of one that sees each window in its heading frame (heading_frame)


@dataclass(frozen=True)
class Preset:
    """A named optimisation schedule: one ``TrainConfig`` and what it is for."""

    name: str
    config: TrainConfig
    description: str = ""


PRESETS: dict[str, Preset] = {
    "paper": Preset(
        "paper",
        TrainConfig(
            lr=1e-4, weight_decay=0.05, batch_size=256, max_epochs=3000, patience=50, grad_clip=0.0
        ),
        description="the paper: Adam 1e-4, L2 0.05, batch 256, <= 3000 epochs, patience 50",
    ),
    # For a 2-core CPU, one thread per run, two runs side by side (measured, docs/training.md):
    # the paper-size model costs ~2.8 ms per window and training step at batch 64, so an epoch
    # of 2,048 windows plus 1,024 validation windows takes ~7 s alone and ~10 s with a second
    # run beside it; 45 epochs fit in ~5-8 min. The budget is the 45 epochs, whatever the
    # machine's load, so the variants of an ablation are trained alike; max_time is only a
    # safety net against a stuck run (when it fires, the report and reproduce say so loudly,
    # and reproduce resumes the run to its 45 epochs).
    "default": Preset(
        "default",
        TrainConfig(
            lr=1e-3,
            weight_decay=0.05,
            optimizer="adamw",
            batch_size=64,
            max_epochs=45,
            patience=12,
            windows_per_epoch=2048,
            lr_schedule="cosine",
            warmup_epochs=3,
            min_lr_ratio=0.05,
            max_time=3600.0,
            val_windows=1024,
        ),
        description="CPU budget: AdamW 1e-3, warm-up + cosine, 45 epochs of 2048 windows",
    ),
    "quick": Preset(
        "quick",
        TrainConfig(
            lr=1e-3,
            weight_decay=0.0,
            batch_size=32,
            max_epochs=2,
            patience=2,
            windows_per_epoch=128,
            val_windows=64,
        ),
        description="smoke test: 2 epochs of 128 windows, seconds",
    ),
}
DEFAULT_PRESET = "default"
SMOKE_PRESET = "quick"  # a run trained with it is a smoke test: every report says so at the top


def get_preset(preset: str | Preset) -> Preset:
    """A preset by name (``PRESETS``), or the given ``Preset`` itself."""
    if isinstance(preset, Preset):
        return preset
    if preset not in PRESETS:
        raise ValueError(f"unknown training preset {preset!r}; choose from {sorted(PRESETS)}")
    return PRESETS[preset]


NONE = "none"  # how TOML files spell an option that is off (TOML has no null)


@dataclass(frozen=True)
class RunConfig:
    """Everything one training run trains with (see the module).

    ``model.slack`` follows the variant (a variant without slack trains a network without
    slack outputs), so two descriptions of the same run compare equal. ``preset`` names the
    schedule ``train`` came from (a custom schedule may carry any name).
    """

    variant: str = "proposed"  # a name of config.LOSS_VARIANTS
    preset: str = DEFAULT_PRESET
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossWeights = field(default_factory=LossWeights)
    window: WindowConfig = field(default_factory=WindowConfig)
    train: TrainConfig = field(default_factory=lambda: PRESETS[DEFAULT_PRESET].config)

    def __post_init__(self) -> None:
        if self.variant not in LOSS_VARIANTS:
            raise ValueError(
                f"unknown loss variant {self.variant!r}; known: {', '.join(LOSS_VARIANTS)}"
            )
        slack = LOSS_VARIANTS[self.variant].slack
        if self.model.slack != slack:
            object.__setattr__(self, "model", replace(self.model, slack=slack))

    @classmethod
    def from_preset(
        cls,
        preset: str | Preset = DEFAULT_PRESET,
        *,
        variant: str = "proposed",
        seed: int = 0,
        max_epochs: int | None = None,
        fit_constants: bool = False,
        model: ModelConfig = ModelConfig(),  # noqa: B008 (frozen)
        loss: LossWeights = LossWeights(),  # noqa: B008 (frozen)
        window: WindowConfig = WindowConfig(),  # noqa: B008 (frozen)
    ) -> RunConfig:
        """A run on a named schedule (``PRESETS``, or a ``Preset``) with its seed, an epoch
        budget other than the preset's, and constants fitted before training."""
        chosen = get_preset(preset)
        train = replace(chosen.config, seed=seed)
        if max_epochs is not None:
            train = replace(train, max_epochs=max_epochs)
        if fit_constants:
            train = replace(train, fit_constants=True)
        return cls(variant, chosen.name, model, loss, window, train)

    def scheduled(self, preset: str | Preset, *, seed: int) -> RunConfig:
        """The same model, loss and windows on another schedule and seed (constants fitted as
        before): how ``reproduce`` and ``study`` turn a template into runs."""
        return RunConfig.from_preset(
            preset,
            variant=self.variant,
            seed=seed,
            fit_constants=self.train.fit_constants,
            model=self.model,
            loss=self.loss,
            window=self.window,
        )

    def uncapped(self) -> RunConfig:
        """Without the wall-clock cap (``TrainConfig.max_time``, a safety net): how a run the
        cap stopped short resumes to its full budget."""
        return replace(self, train=replace(self.train, max_time=None))

    @property
    def seed(self) -> int:
        return self.train.seed

    # --- identity -------------------------------------------------------------------------

    def tags(self) -> list[str]:
        """What sets this run apart from the paper's setup, in folder-name form: the
        architecture (unless the paper's), the network's named size (unless the paper's:
        ``config.size_tag``), the variant, "fitted" constants, the step weighting, "N<steps>"
        (a training horizon other than the default), the load estimate (unless the backward
        difference), "adaptive" (f runs with each window's constants estimated in flight) and
        "sees-constants" (the correction network takes them as inputs too), "heading" (the
        network sees each window in its heading frame)."""
        tags = [] if self.model.architecture == DEFAULT_ARCHITECTURE else [self.model.architecture]
        tags += [size_tag(self.model)] if size_tag(self.model) else []
        tags.append(self.variant)
        tags += ["fitted"] if self.train.fit_constants else []
        tags += [step_tag(self.loss.steps)] if self.loss.steps != "paper" else []
        default_horizon = WindowConfig().horizon
        tags += [f"N{self.window.horizon}"] if self.window.horizon != default_horizon else []
        estimate = self.model.load_estimate
        tags += [estimate] if estimate != ModelConfig().load_estimate else []
        tags += [ADAPTIVE] if self.model.adapts_constants else []
        tags += [SEEING] if self.model.constants_input else []
        tags += [HEADING] if self.model.heading_frame else []
        return tags

    def folder(self) -> str:
        """Its run folder's name: the tags and the seed, e.g. "proposed-s0",
        "physics-step-no-physics-mixed-N50-smoothed-s1", "physics-step-small-no-physics-s0"."""
        return "-".join(self.tags()) + f"-s{self.seed}"

    def label(self, *, with_horizon: bool = False) -> str:
        """Its label in the tables (seeds share one): the variant, prefixed by the
        architecture unless that is the paper's network, suffixed by "+fit" (fitted
        constants), "+relative" or "+mixed" (the step weighting), "+N<steps>" with
        ``with_horizon`` (when runs of a report differ in training horizon), "+smoothed" and
        "+adaptive", "+sees-constants" and "+heading";
        a named network size other than the paper's joins the architecture; e.g. "proposed",
        "physics-step/no-physics+relative+N50", "physics-step-small/no-physics"."""
        architecture, size = self.model.architecture, size_tag(self.model)
        network = [] if architecture == DEFAULT_ARCHITECTURE and not size else [architecture]
        network += [size] if size else []
        label = f"{'-'.join(network)}/{self.variant}" if network else self.variant
        label += "+fit" if self.train.fit_constants else ""
        tag = step_tag(self.loss.steps)
        label += f"+{tag}" if tag else ""
        label += f"+N{self.window.horizon}" if with_horizon else ""
        label += "+smoothed" if self.model.load_estimate == "smoothed" else ""
        label += f"+{ADAPTIVE}" if self.model.adapts_constants else ""
        label += f"+{SEEING}" if self.model.constants_input else ""
        return label + (f"+{HEADING}" if self.model.heading_frame else "")

    # --- files ----------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Plain dicts (JSON-friendly; ``None`` where an option is off)."""
        return to_dict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        """Inverse of ``to_dict``; missing keys take their defaults, ``[train]``'s the named
        preset's; unknown keys are an error naming them."""
        data = dict(data)
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"RunConfig: unknown keys {sorted(unknown)}")
        preset = str(data.get("preset", DEFAULT_PRESET))
        base = PRESETS[preset].config if preset in PRESETS else TrainConfig()
        kwargs: dict[str, Any] = {"variant": data.get("variant", "proposed"), "preset": preset}
        for name, cls_ in {"loss": LossWeights, "window": WindowConfig}.items():
            kwargs[name] = from_dict(cls_, _table(data, name))
        kwargs["model"] = _model(_table(data, "model"))
        train = _table(data, "train")
        kwargs["train"] = from_dict(TrainConfig, {**to_dict(base), **train})
        return cls(**kwargs)

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> RunConfig:
        """The run a checkpoint's embedded configs describe (its "weights" are the loss)."""
        keys = {"variant": "variant", "preset": "preset", "model": "model", "loss": "weights",
                "window": "window", "train": "train"}  # fmt: skip
        return cls.from_dict({k: meta[m] for k, m in keys.items() if m in meta})

    def to_toml(self) -> str:
        """The TOML text of every field (``from_toml`` inverts it)."""
        import tomli_w

        def plain(value: Any) -> Any:
            if isinstance(value, dict):
                return {k: plain(v) for k, v in value.items()}
            if isinstance(value, tuple):
                return list(value)
            return NONE if value is None else value

        return tomli_w.dumps(plain(self.to_dict()))

    @classmethod
    def from_toml(cls, text: str, source: str = "run configuration") -> RunConfig:
        """A ``RunConfig`` from TOML text; errors name ``source``."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{source}: not valid TOML ({exc})") from None
        try:
            return cls.from_dict(_nones(data))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from None

    def write_toml(self, path: str | Path) -> Path:
        """Write ``to_toml`` atomically to ``path``."""
        from .fileio import write_text

        path = Path(path)
        write_text(path, self.to_toml())
        return path


def read_toml(path: str | Path) -> RunConfig:
    """A ``RunConfig`` from a TOML file; errors name the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the run configuration ({exc})") from None
    return RunConfig.from_toml(text, str(path))


def _table(data: dict[str, Any], name: str) -> dict[str, Any]:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise ValueError(f"[{name}] must be a table of options, got {table!r}")
    return table


def _model(table: dict[str, Any]) -> ModelConfig:
    """``[model]``: the fields, or ``size = "small"`` (a name of ``config.MODEL_SIZES``) in
    place of the widths."""
    if "size" not in table:
        return from_dict(ModelConfig, table)
    rest = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items() if k != "size"}
    unknown = set(rest) - {f.name for f in fields(ModelConfig)}
    if unknown:
        raise ValueError(f"ModelConfig: unknown keys {sorted(unknown)}")
    return ModelConfig.sized(str(table["size"]), **rest)


def _nones(data: dict[str, Any]) -> dict[str, Any]:
    """``"none"`` values of the tables back to ``None`` (no config field takes "none" as a
    string)."""
    return {
        k: _nones(v) if isinstance(v, dict) else (None if v == NONE else v) for k, v in data.items()
    }


__all__ = [
    "DEFAULT_PRESET",
    "PRESETS",
    "Preset",
    "RunConfig",
    "get_preset",
    "read_toml",
]
