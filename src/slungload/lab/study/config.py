"""What each study runs, without importing torch, MuJoCo or Ray (the command line's help reads
these, and every option's default comes from here): ``DataStudyConfig`` (``study data``),
``SizeStudyConfig`` (``study size``), ``LoadsStudyConfig`` and its rows (``study loads``),
``SearchSpace`` and ``TuneSettings`` (``slungload tune``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ...config import DEFAULT_ARCHITECTURE, LOSS_VARIANTS, MODEL_SIZES


@dataclass(frozen=True)
class DataStudyConfig:
    """What ``study data`` trains and evaluates: every architecture x loss variant x seed on
    the first k training flights, for each k of ``flights``."""

    flights: tuple[int, ...] = (6, 12, 24, 48)  # training-flight counts; a simulated dataset
    # is sized for the largest
    variants: tuple[str, ...] = tuple(LOSS_VARIANTS)  # the paper's three
    architectures: tuple[str, ...] = (DEFAULT_ARCHITECTURE,)
    seeds: tuple[int, ...] = (0,)  # training seeds
    preset: str = "default"  # the training schedule (``run_config.PRESETS``)
    horizon: int = 50  # N evaluated, steps
    sim_seed: int = 0  # the simulated dataset's seed, and the draw of the nested subsets

    def __post_init__(self) -> None:
        if not self.flights or min(self.flights) < 1:
            raise ValueError(f"--flights must be positive counts, got {list(self.flights)}")


@dataclass(frozen=True)
class SizeStudyConfig:
    """What ``study size`` trains and times: each named network size (``config.MODEL_SIZES``)
    for every seed, validation RMSE at ``horizon``, one batched rollout of ``samples`` plans of
    ``steps`` steps on ``backend``; the sizes on the Pareto front get ``front_seeds`` too."""

    sizes: tuple[str, ...] = tuple(MODEL_SIZES)
    seeds: tuple[int, ...] = (0,)
    front_seeds: tuple[int, ...] = (1, 2)
    preset: str = "default"  # the training schedule (``run_config.PRESETS``) ...
    epochs: int | None = None  # ... cut to this many epochs (its schedule fitted to them)
    horizon: int = 50  # N of the validation RMSE, steps
    samples: int = 256  # K of the timed rollout, the MPC's
    steps: int = 15  # N of the timed rollout, steps
    repeats: int = 200  # timed rollouts
    backend: str = "compiled"  # what the rollouts are timed on (``config.PREDICTION_BACKENDS``)

    def __post_init__(self) -> None:
        unknown = [s for s in self.sizes if s not in MODEL_SIZES]
        if unknown or not self.sizes:
            raise ValueError(f"unknown network sizes {unknown}; known: {', '.join(MODEL_SIZES)}")


def _range(default: tuple[float, float], text: str, unit: str):
    """A (low, high) field with its description and unit as metadata (the CLI's help)."""
    return field(default=default, metadata={"text": text, "unit": unit})


RANGES = ("train_mass", "train_length", "beyond_mass", "beyond_length")  # the ranged fields


@dataclass(frozen=True)
class LoadsStudyConfig:
    """What the loads study flies and trains; masses in kg, lengths in m."""

    train_mass: tuple[float, float] = _range(
        (0.10, 0.25), "load masses of the training flights", "kg"
    )
    train_length: tuple[float, float] = _range((0.6, 0.9), "their cable lengths", "m")
    beyond_mass: tuple[float, float] = _range((0.28, 0.36), "load masses beyond the range", "kg")
    beyond_length: tuple[float, float] = _range((0.95, 1.05), "their cable lengths", "m")
    flights: int = 48  # flights of ``one`` and ``many`` (split as the simulator splits)
    beyond_flights: int = 12  # flights of ``beyond``, all tested
    size: str = "small"  # the network's named size (``config.MODEL_SIZES``)
    horizons: tuple[int, ...] = (25, 50)  # evaluated horizons N, steps
    # The in-flight estimate's mass priors, (m/s^2)^2 per equation
    # (``constants_estimate.estimate_constants``), that the physics row with the estimate
    # chooses from on the validation flights of ``many`` (combined RMSE at the longest horizon).
    estimate_priors: tuple[float, ...] = (0.2, 0.5, 1.0, 2.0, 5.0)
    seeds: tuple[int, ...] = (0,)  # training seeds
    preset: str = "default"  # the training schedule (``run_config.PRESETS``) ...
    epochs: int | None = None  # ... cut to this many epochs (its schedule fitted to them)
    sim_seed: int = 0  # the simulated datasets' seed

    def __post_init__(self) -> None:
        if not self.estimate_priors or min(self.estimate_priors) < 0:
            raise ValueError(
                f"LoadsStudyConfig.estimate_priors: at least one prior, each >= 0; got "
                f"{self.estimate_priors}"
            )

    @property
    def nominal(self) -> tuple[float, float]:
        """The nominal load mass and cable length: the training range's midpoints."""
        return sum(self.train_mass) / 2, sum(self.train_length) / 2


# The rows of the study, by label (no commas: they are CSV cells): which constants the physics
# model runs with.
TRUTH = "physics (true constants)"  # the reference row
ESTIMATE_ROW = "physics (in-flight estimate)"  # its mass prior chosen on validation
NOMINAL_ROW = "physics (nominal)"
PHYSICS_ROWS = {NOMINAL_ROW: "dataset", ESTIMATE_ROW: "window", TRUTH: "flight"}
ONE_LOAD_ROW = "one load"  # the network the adaptive ones are compared with per test flight
# The networks: the dataset each trains on, the constants its f runs with and whether its
# correction sees them (``ModelConfig.constants_input``).
NETWORK_ROWS = {
    ONE_LOAD_ROW: ("one", "dataset", False),
    "many loads": ("many", "dataset", False),
    "many loads (adaptive)": ("many", "window", False),
    "many loads (adaptive sees constants)": ("many", "window", True),
}
# The test sets, unseen loads inside and beyond the range: the dataset whose flights each tests
# (inside: the test flights of "many"; beyond: every flight of "beyond").
SETS = {"inside": "many", "beyond": "beyond"}


@dataclass(frozen=True)
class SearchSpace:
    """What a trial may choose (each tuple: the choices; ``lr``: a log-uniform range)."""

    architecture: tuple[str, ...] = ("lstm-attention", "physics-step")
    variant: tuple[str, ...] = ("proposed", "no-slack", "no-physics")
    steps: tuple[str, ...] = ("paper", "physics-relative", "mixed")
    horizon: tuple[int, ...] = (25, 50)  # training horizon N
    load_estimate: tuple[str, ...] = ("difference", "smoothed")
    size: tuple[str, ...] = ("paper", "medium", "small", "tiny")
    batch_size: tuple[int, ...] = (32, 64, 128)
    lr: tuple[float, float] = (2e-4, 3e-3)  # 1/step, log-uniform


@dataclass(frozen=True)
class TuneSettings:
    """The search: how many trials, on what budget, with which seeds."""

    trials: int = 24
    preset: str = "default"  # the search budget's schedule ...
    epochs: int | None = 10  # ... cut to this many epochs (its cosine fitted to them)
    final_preset: str = "default"  # best.toml's schedule: what the chosen run retrains with
    seeds: tuple[int, int] = (0, 1)  # the objective is their mean
    horizon: int = 50  # N of the objective
    concurrent: int = 2  # trials at a time (one CPU each)
    grace_epochs: int = 2  # ASHA: epochs every trial gets before it may be stopped
    search_seed: int = 0  # TPE's random seed
    history: int = 50  # M of every trial

    def __post_init__(self) -> None:
        # ASHA may stop a trial only after its grace period: a budget no longer than that
        # leaves it nothing to decide, and its report would call finished trials stopped.
        if self.epochs is not None and self.epochs <= self.grace_epochs:
            raise ValueError(
                f"--epochs {self.epochs}: a trial's budget must exceed ASHA's grace period of "
                f"{self.grace_epochs} epochs (give --epochs {self.grace_epochs + 1} or more)"
            )
