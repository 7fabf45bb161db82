"""Frozen configuration dataclasses, in SI units.

Every stage takes one of these; every checkpoint and report stores them (``to_dict``) so a
result can be rebuilt from its file alone (``from_dict``).

Frame convention (used everywhere in the package and in the data files): the world frame is
z **up**, gravity is ``-g e3``. The paper writes gravity as ``+g e3``; see ``physics.py``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any, TypeVar

T = TypeVar("T")


def constant(default: float, unit: str, symbol: str, text: str) -> Any:
    """A field of ``VehicleParams``: its default, SI unit ("-": unitless), the paper's symbol and
    a one-line description, kept as the field's metadata (the command line's options, their help
    and ``VehicleParams.summary`` are made from them)."""
    return dataclasses.field(
        default=default, metadata={"unit": unit, "symbol": symbol, "text": text}
    )


@dataclass(frozen=True)
class VehicleParams:
    """Constants of the quadrotor + slung-load model (the paper's Section III-A).

    Defaults are the authors' values for an Intel Aero RTF carrying a 100 g cube on a 60 cm
    string; ``cable_length`` is the effective length (string + attachment + half cube).
    ``thrust_gain`` is not in the paper (its value there is 1): the discrete model applies
    thrust_gain * T, so a vehicle whose thrust commands are off by a factor (a mapping from
    normalised throttle, battery sag) is fitted by ``slungload identify``.

    This class is the one home of the vehicle's constants: ``physics.VehicleConstants`` is
    their tensor view, and the ``--mass-quad`` ... options of every command are made from
    these fields (``cli.common.add_vehicle_options``).
    """

    mass_quad: float = constant(1.35, "kg", "mQ", "vehicle mass")
    mass_load: float = constant(0.100, "kg", "mL", "load mass")
    cable_length: float = constant(
        0.7, "m", "l", "effective cable length (string, attachment and half the load)"
    )
    load_damping: float = constant(
        0.025, "-", "d", "per-step damping of the load angular velocity, in [0, 1]"
    )
    dt: float = constant(0.03, "s", "h", "sampling time")
    # The paper prints 9.8; the authors' code uses 9.81.
    gravity: float = constant(9.81, "m/s^2", "g", "gravity")
    thrust_gain: float = constant(1.0, "-", "kT", "achieved / commanded thrust (the paper: 1)")

    def __post_init__(self) -> None:
        for name in ("mass_quad", "mass_load", "cable_length", "dt", "gravity", "thrust_gain"):
            if not getattr(self, name) > 0:
                raise ValueError(f"VehicleParams.{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.load_damping <= 1.0:
            raise ValueError(
                f"VehicleParams.load_damping must be in [0, 1], got {self.load_damping}"
            )

    def summary(self) -> str:
        """The constants with their symbols and units: "mQ 1.35 kg, mL 0.1 kg, ..., kT 1"."""
        return ", ".join(
            f"{f.metadata['symbol']} {getattr(self, f.name):g}"
            + ("" if f.metadata["unit"] == "-" else f" {f.metadata['unit']}")
            for f in fields(self)
        )


@dataclass(frozen=True)
class WindowConfig:
    """Sliding windows cut from each flight: M past steps, N future steps."""

    history: int = 50  # steps, M
    horizon: int = 25  # steps, N
    stride: int = 1  # steps between consecutive window starts

    def __post_init__(self) -> None:
        for name in ("history", "horizon", "stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"WindowConfig.{name} must be >= 1, got {getattr(self, name)}")

    @property
    def length(self) -> int:
        """Steps one window spans (M + N)."""
        return self.history + self.horizon

    def count(self, steps: int) -> int:
        """Windows of ``length`` steps at ``stride`` in a flight of ``steps`` steps."""
        return 0 if steps < self.length else (steps - self.length) // self.stride + 1


@dataclass(frozen=True)
class Architecture:
    """A network architecture: its class in ``slungload.models`` as ``"module:Class"``
    (``models.MODELS`` imports it on first use) and what it is."""

    target: str
    description: str


DEFAULT_ARCHITECTURE = "lstm-attention"  # the paper's network (models.lstm_attention)
# Every network architecture by name: the one table (``models.MODELS`` reads its classes from
# it), beside the config that selects one, so the command line lists them without loading torch.
# A new architecture is a module in ``models/`` and one line here.
ARCHITECTURES: dict[str, Architecture] = {
    DEFAULT_ARCHITECTURE: Architecture(
        "lstm_attention:SlungLoadNet", "the paper's LSTM encoder-decoder with Bahdanau attention"
    ),
    "physics-step": Architecture(
        "physics_step:PhysicsStepNet",
        "the paper's network correcting one step of the discrete model per step",
    ),
}


# What a prediction model runs on in the MPC (``deploy.compiled.batched``, ``control --backend``),
# first the default; the names live here so the command line lists them without loading torch.
PREDICTION_BACKENDS: dict[str, str] = {
    "eager": "torch operators (models.prediction)",
    "compiled": "compiled kernels: the physics in one float64 loop, a network in float32",
    "cuda": "torch operators on the GPU, replayed from CUDA graphs: the physics in float64, a "
    "network in float32",
}

# An ensemble's interval: its default coverage, and the level ``calibrate`` fits at.
ENSEMBLE_LEVEL = 0.9


# The physics-step network's estimate of the load state at the last history step.
LOAD_ESTIMATES: dict[str, str] = {
    "difference": "backward differences of the last two positions (the data's estimate)",
    "smoothed": "slopes of least-squares quadratics through the last 9 positions",
}
# Which constants the discrete model f runs with, by name (``ModelConfig.constants`` for the
# physics-step network: "dataset" or "window"; ``models.PhysicsModel`` takes all three).
CONSTANTS_SOURCES: dict[str, str] = {
    "dataset": "the dataset's (vehicle.json, or fitted by identify), one set for every window",
    "window": "each window's cable length and load mass, estimated in flight from its history",
    "flight": "each window's flight's recorded constants (simulated varied loads: the truth)",
}
NETWORK_CONSTANTS = ("dataset", "window")  # what a network can run f with (it sees no truth)
# The constants a network with ``ModelConfig.constants_input`` sees, as ratios to its own.
CONDITIONED = ("cable_length", "mass_load")
# H: half-width of the triangular smoothing of the in-flight estimate's force balance, steps
# (``constants_estimate``), and the shortest window that estimate takes
ESTIMATE_SMOOTHING_STEPS = 7
ESTIMATE_MIN_STEPS = 2 * ESTIMATE_SMOOTHING_STEPS + 3
# What a model that adapts to its load runs f with (``constants_estimate.adapted``): the mass
# pulled towards the constants' by this prior, (m/s^2)^2 per equation (one window's median
# error 13 % against 26 % without, every effect on: docs/data.md), then both kept within these
# factors of the constants' (a window without swing can read as a negative load, and f divides
# by mL).
ADAPT_PRIOR_WEIGHT = 0.2
ADAPT_RANGE = {"mass_load": (0.25, 4.0), "cable_length": (0.5, 2.0)}


@dataclass(frozen=True)
class ModelSize:
    """The widths of one named network size (``MODEL_SIZES``): what ``ModelConfig.sized`` sets."""

    embed_sizes: tuple[int, ...]  # input embedding Linear widths
    hidden_size: int  # LSTM hidden units
    num_layers: int  # LSTM layers (encoder and decoder)
    head_sizes: tuple[int, ...]  # decoder output head widths
    description: str = ""

    def summary(self) -> str:
        """One line, e.g. "embedding 100-200-300, 3 x 20 LSTM, head 300-200-100" (a head without
        hidden layers: "linear head")."""
        head = "-".join(map(str, self.head_sizes))
        return (
            f"embedding {'-'.join(map(str, self.embed_sizes))}, "
            f"{self.num_layers} x {self.hidden_size} LSTM, "
            + (f"head {head}" if head else "linear head")
        )


# Named network sizes, torch-free so the command line lists them fast (``train --size``;
# ``ModelConfig.sized``). "paper" is the paper's network (238,906 parameters with slack
# outputs). The smaller ones come from the size study of the physics-step network
# (``slungload study size``, docs/BENCHMARKS.md): that network does most of its work
# through the discrete model f, so it needs far fewer weights; what each costs in the MPC's
# batched rollout is measured there.
DEFAULT_SIZE = "paper"
MODEL_SIZES: dict[str, ModelSize] = {
    "paper": ModelSize((100, 200, 300), 20, 3, (300, 200, 100), "the paper's network"),
    "medium": ModelSize((64, 64), 32, 2, (64, 64), "the most accurate in the size study"),
    "small": ModelSize((32, 32), 16, 2, (32,), "the paper's accuracy, 1.7x faster MPC rollouts"),
    "tiny": ModelSize((16,), 8, 1, (), "2.6x faster MPC rollouts, 1.23x the error"),
}


def size_tag(config: ModelConfig) -> str:
    """A network size's short name in run labels and folders: the name of ``MODEL_SIZES`` that
    the widths match, "" for the paper's and for widths that match no name (so the folders
    and labels of such runs are what they were before sizes had names)."""
    name = config.size
    return "" if name in (None, DEFAULT_SIZE) else name


_PAPER = MODEL_SIZES[DEFAULT_SIZE]


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of the LSTM encoder-decoder with Bahdanau attention.

    The defaults give the paper's 238,906 parameters; ``ModelConfig.sized(name)`` a named size
    of ``MODEL_SIZES`` (``size`` names the one a config has). ``architecture`` names the network
    in ``models.MODELS``; a checkpoint written before it existed is the paper's network.
    """

    architecture: str = DEFAULT_ARCHITECTURE  # a name in models.MODELS
    # The widths default to the paper's (MODEL_SIZES["paper"]); ``sized`` picks another size.
    embed_sizes: tuple[int, ...] = _PAPER.embed_sizes  # input embedding Linear widths
    hidden_size: int = _PAPER.hidden_size  # LSTM hidden units
    num_layers: int = _PAPER.num_layers  # LSTM layers (encoder and decoder)
    head_sizes: tuple[int, ...] = _PAPER.head_sizes  # decoder output head widths
    dropout: float = 0.1  # between embedding layers and LSTM layers
    slack: bool = True  # emit 13 slack variables per step besides the 13 states
    normalize: bool = True  # standardise inputs/outputs with training-split statistics
    # The head predicts x_k - x_{k-1} (True) or x_k itself (False, the paper). The residual form
    # starts from "hold the last state" and learns far faster on a CPU budget (docs/training.md).
    residual: bool = True
    # Positions (vehicle and load) enter and leave the network relative to the last measured
    # vehicle position: the dynamics do not depend on where the arena's origin is, and a network
    # that sees absolute positions can tell training flights apart and memorise them.
    relative_positions: bool = True
    # The network sees each window turned about the world's vertical so that its last measured
    # heading points along x, and its prediction is turned back (``state.to_heading_frame``):
    # the dynamics do not depend on the heading (gravity is the only direction they single
    # out), and a network that sees the heading must learn every heading from data.
    heading_frame: bool = False
    # How the physics-step network estimates the load state (vL, Omega_L) it starts f from
    # (a name of LOAD_ESTIMATES); the paper's network has no such estimate.
    load_estimate: str = "difference"
    # The constants the physics-step network's f runs with (a name of NETWORK_CONSTANTS):
    # "window" adapts f to each window's load, estimated from the history in flight.
    constants: str = "dataset"
    # The physics-step network's correction also sees f's constants (``CONDITIONED``, each as
    # a ratio to the network's own minus one) as more embedding inputs at every step: it can
    # then learn how the unmodelled effects change with the load, not only f.
    constants_input: bool = False

    def __post_init__(self) -> None:
        widths = (*self.embed_sizes, self.hidden_size, self.num_layers, *self.head_sizes)
        bad = [w for w in widths if isinstance(w, bool) or not isinstance(w, int) or w < 1]
        if not self.embed_sizes or bad:
            raise ValueError(
                "ModelConfig: the embedding needs at least one layer and every width and layer "
                f"count must be a positive integer; got embed_sizes={self.embed_sizes}, "
                f"hidden_size={self.hidden_size}, num_layers={self.num_layers}, "
                f"head_sizes={self.head_sizes}"
            )
        if self.load_estimate not in LOAD_ESTIMATES:
            raise ValueError(
                f"unknown load estimate {self.load_estimate!r}; known: {sorted(LOAD_ESTIMATES)}"
            )
        if self.load_estimate != "difference" and self.architecture != "physics-step":
            raise ValueError(
                f"load_estimate={self.load_estimate!r} is for the physics-step network; the "
                f"{self.architecture!r} architecture starts no physics step"
            )
        if self.constants not in NETWORK_CONSTANTS:
            raise ValueError(
                f"unknown constants source {self.constants!r} for a network; known: "
                f"{list(NETWORK_CONSTANTS)}"
            )
        if self.constants != "dataset" and self.architecture != "physics-step":
            raise ValueError(
                f"constants={self.constants!r} is for the physics-step network; the "
                f"{self.architecture!r} architecture runs no physics step"
            )
        if self.constants_input and self.architecture != "physics-step":
            raise ValueError(
                f"constants_input is for the physics-step network; the {self.architecture!r} "
                "architecture runs no physics step whose constants it could see"
            )
        if self.architecture not in ARCHITECTURES:
            raise ValueError(
                f"unknown model architecture {self.architecture!r}; known: {sorted(ARCHITECTURES)}"
            )

    @classmethod
    def sized(cls, size: str, **options: Any) -> ModelConfig:
        """The network of a named size (``MODEL_SIZES``) with any other field given:
        ``ModelConfig.sized("small", architecture="physics-step")``. A checkpoint records the
        widths themselves, so it rebuilds even if the registry changes."""
        clash = sorted(set(_WIDTHS) & set(options))
        if clash:
            raise ValueError(f"ModelConfig.sized({size!r}) sets {clash}; give a size or widths")
        return cls(**options).resized(size)

    def resized(self, size: str) -> ModelConfig:
        """The same config with the widths of a named size (``MODEL_SIZES``)."""
        if size not in MODEL_SIZES:
            known = "; ".join(f"{n} ({s.summary()})" for n, s in MODEL_SIZES.items())
            raise ValueError(f"unknown network size {size!r}; known: {known}")
        return dataclasses.replace(
            self, **{name: getattr(MODEL_SIZES[size], name) for name in _WIDTHS}
        )

    @property
    def adapts_constants(self) -> bool:
        """Whether f runs with each window's cable length and load mass, estimated in flight."""
        return self.constants == "window"

    @property
    def size(self) -> str | None:
        """The name of ``MODEL_SIZES`` whose widths these are, or None (custom widths)."""
        mine = tuple(getattr(self, name) for name in _WIDTHS)
        for name, size in MODEL_SIZES.items():
            if tuple(getattr(size, w) for w in _WIDTHS) == mine:
                return name
        return None


_WIDTHS = ("embed_sizes", "hidden_size", "num_layers", "head_sizes")  # what a size sets


# How L_fit weighs the horizon steps (``LossWeights.steps``; ``loss.fit_loss``).
STEP_WEIGHTINGS: dict[str, str] = {
    "paper": "e^{-alpha n}, the paper's: late steps, with their larger errors, dominate",
    "physics-relative": "e^{-alpha n} / (the physics model's mean-square error at step n, per "
    "group), scaled so that physics-level errors give the paper's loss: every step counts by "
    "how much it improves on the physics model",
    "mixed": "the mean of the two: the paper's weight on the late steps, half the "
    "physics-relative weight on the early ones",
}


def step_tag(steps: str) -> str:
    """A step weighting's short name in run labels and folders: "" for the paper's,
    "relative" for "physics-relative", "mixed"."""
    return "" if steps == "paper" else steps.removeprefix("physics-")


@dataclass(frozen=True)
class LossWeights:
    """Weights of the four-term loss (the paper's values) and how L_fit weighs the steps."""

    position: float = 20.0  # lambda_1
    velocity: float = 20.0  # lambda_2
    quaternion: float = 20.0  # lambda_3
    load_position: float = 20.0  # lambda_4
    physics: float = 5.0  # phi
    projection: float = 10.0  # psi
    slack: float = 0.1  # rho
    alpha: float = 0.1  # 1/step, decay of the fit weights e^{-alpha (n - M)}
    beta: float = 0.6  # 1/step, decay of the physics and slack weights e^{-beta (n - M)}
    steps: str = "paper"  # a name of STEP_WEIGHTINGS

    def __post_init__(self) -> None:
        if self.steps not in STEP_WEIGHTINGS:
            raise ValueError(
                f"unknown step weighting {self.steps!r}; known: {', '.join(STEP_WEIGHTINGS)}"
            )


@dataclass(frozen=True)
class LossVariant:
    """Which terms a training run uses (the paper's ablations; ``loss.compute_loss``)."""

    name: str
    physics: bool  # include L_physics
    slack: bool  # the model emits slack variables and L_slack is included
    description: str


LOSS_VARIANTS: dict[str, LossVariant] = {
    v.name: v
    for v in (
        LossVariant("proposed", True, True, "fit + physics with slack + projection + slack"),
        LossVariant("no-slack", True, False, "fit + physics (slack fixed at 0) + projection"),
        LossVariant("no-physics", False, False, "fit + projection (plain encoder-decoder)"),
    )
}


@dataclass(frozen=True)
class TrainConfig:
    """One training run's optimisation schedule and safeguards (a preset names one)."""

    lr: float = 1e-4  # Adam learning rate
    weight_decay: float = 0.05  # weight decay (an L2 term for "adam", decoupled for "adamw")
    # "adam": Adam with weight decay added to the gradient (the paper's L2). "adamw": decoupled
    # decay. Coupled L2 of 0.05 outweighs the clipped gradients of this loss and stalls short
    # CPU runs (measured in docs/training.md); the paper's 117,000 steps ride it out.
    optimizer: str = "adam"
    batch_size: int = 256  # windows per batch
    max_epochs: int = 3000
    patience: int = 50  # epochs without validation improvement before stopping
    windows_per_epoch: int | None = None  # subsample training windows each epoch (None: all)
    lr_schedule: str = "constant"  # "constant" or "cosine"
    grad_clip: float = 1.0  # max gradient norm (0 disables)
    seed: int = 0
    warmup_epochs: int = 0  # epochs of linear lr warm-up before the cosine decay
    min_lr_ratio: float = 0.0  # lr at the end of the cosine decay, as a fraction of lr
    max_time: float | None = None  # s, wall-clock budget of the run, resumed parts included
    val_windows: int | None = None  # validate on a fixed seeded subset of this size (None: all)
    max_bad_steps: int = 10  # consecutive non-finite training losses before giving up
    # Turn every training window about the vertical by a random yaw (a symmetry of the physics:
    # ``state.rotate_about_z``): the network meets each maneuver at every heading.
    augment_yaw: bool = False
    # Fit the discrete model's constants (load mass, cable length, load damping, thrust gain)
    # to the training flights before training (``slungload identify``): the physics loss and a
    # physics-step network's f then use the fitted model instead of the nominal one.
    fit_constants: bool = False
    # Train on a bootstrap resample of the training flights: as many flights as the split
    # holds, drawn with replacement from ``seed`` (a flight drawn twice weighs twice), so that
    # an ensemble's members differ by their data as well as by their initialisation.
    bootstrap: bool = False

    def __post_init__(self) -> None:
        for name in ("max_epochs", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"TrainConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.warmup_epochs < 0:
            raise ValueError(f"warmup_epochs must be >= 0, got {self.warmup_epochs}")
        if not 0.0 <= self.min_lr_ratio <= 1.0:
            raise ValueError(f"min_lr_ratio must be in [0, 1], got {self.min_lr_ratio}")
        if self.max_time is not None and self.max_time <= 0:
            raise ValueError(f"max_time must be > 0 s, got {self.max_time}")
        if self.val_windows is not None and self.val_windows < 1:
            raise ValueError(f"val_windows must be >= 1, got {self.val_windows}")
        if self.max_bad_steps < 1:
            raise ValueError(f"max_bad_steps must be >= 1, got {self.max_bad_steps}")
        if self.optimizer not in ("adam", "adamw"):
            raise ValueError(
                f"TrainConfig.optimizer must be 'adam' or 'adamw', got {self.optimizer!r}"
            )
        if self.lr_schedule not in ("constant", "cosine"):
            raise ValueError(
                f"TrainConfig.lr_schedule must be 'constant' or 'cosine', got {self.lr_schedule!r}"
            )


@dataclass(frozen=True)
class PreflightConfig:
    """The check before flying (``evaluation.preflight``): does a network beat the physics
    model in an MPC, judged on held-out flights.

    horizon: the MPC's N, steps (the MPC's own default, ``control.mppi.MPCConfig``).
    split: the flights judged on: "held-out" (val and test together), "test" or "val".
    pays_below: the network may pay when the upper end of the interval of its load response
    score relative to physics's (the share of the commands' effect it leaves unexplained) lies
    below this (a 10 % lead, with confidence). vehicle_below: and its vehicle score's upper end
    below this: a network that learned this vehicle explains its response to commands far
    better than the physics model, which leaves out its inner loops (docs/control.md).
    level, resamples: the interval's coverage and its flight-bootstrap resamplings. knots:
    values per command channel a window's future commands are summarised by (hat functions,
    as the MPC draws its noise). ridge: the response fit's regularisation, per window
    (standardised features)."""

    horizon: int = 15
    split: str = "held-out"
    pays_below: float = 0.9
    vehicle_below: float = 0.5
    level: float = 0.95
    resamples: int = 2000
    knots: int = 5
    ridge: float = 1e-3

    def __post_init__(self) -> None:
        if (
            self.horizon < 1
            or min(self.pays_below, self.vehicle_below) <= 0
            or not (0 < self.level < 1)
        ):
            raise ValueError(f"PreflightConfig: bad values {self}")
        if self.resamples < 100:
            raise ValueError(f"PreflightConfig.resamples: at least 100, got {self.resamples}")


def to_dict(cfg: Any) -> dict[str, Any]:
    """A JSON-friendly dict of a config dataclass (nested ones included)."""
    return dataclasses.asdict(cfg)


def from_dict(cls: type[T], data: dict[str, Any]) -> T:
    """Rebuild a config dataclass from ``to_dict`` output; unknown keys are an error."""
    known = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
    unknown = set(data) - set(known)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown keys {sorted(unknown)}")
    kwargs = {}
    for name, value in data.items():
        if isinstance(value, list):  # JSON turns tuples into lists
            value = tuple(value)
        kwargs[name] = value
    return cls(**kwargs)
