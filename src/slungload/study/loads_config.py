"""What the loads study flies, trains and compares (``study.loads``): light, so that the
command line's help derives its defaults from here without loading torch."""

from __future__ import annotations

from dataclasses import dataclass, field


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
