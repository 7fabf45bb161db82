"""What the closed-loop experiments fly, without importing torch or MuJoCo (the command line's
help reads them): ``ComparisonConfig`` (``slungload control``), ``StudyConfig`` (``study
control``), ``UnseenLoadsConfig`` (``study control-loads``), ``RecordConfig`` (``record``), the
shifted plants, the maneuvers, the tuning grid. Every option's default on the command line is
read from these."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace
from typing import Any

from ...control import paired
from ...control.controllers import REFERENCE
from ...control.mppi import COSTS, MPCConfig, knots_for
from ...control.paired import trust_steps
from ...sim.config import SimConfig
from ...sim.maneuvers import MANEUVERS
from ...sim.plants import DEFAULT_PLANT, PLANTS

# The simulator's three fastest maneuvers, what ``slungload control`` flies by default: back and
# forth along a line at 2.8-3.6 s a cycle, roll doublets of 25-35 degrees, and figure eights
# that climb and sink.
DEFAULT_MANEUVERS = ("baf_very_fast", "roll_35", "fast_8_lap_xyz")
# The study: those and two gentler ones.
STUDY_MANEUVERS = (*DEFAULT_MANEUVERS, "slow_ellipses_xy", "xy_step")
NOMINAL = "nominal"
# Each shifted plant from the nominal config: what the models were not trained on.
SHIFTS: dict[str, Callable[[SimConfig], SimConfig]] = {
    "load +50%": lambda c: c.with_load(load_mass=1.5 * c.load_mass),
    "cable +20%": lambda c: c.with_load(cable_length=1.2 * c.cable_length),
    "wind x2": lambda c: replace(c, wind_std=2.0 * c.wind_std),
    "thrust lag x2": lambda c: replace(c, thrust_tau=2.0 * c.thrust_tau),
}
# The kinds ``run_study`` may fly: the reference controllers (``control.controllers``), the MPC
# over the physics model, over the learned model and over the ``oracle`` (the registered
# controllers themselves: ``control.controllers.CONTROLLERS``).
LEARNED = "learned"
ORACLE = "oracle"
STUDY_KINDS = (*REFERENCE, "physics", LEARNED, ORACLE)
PHYSICS_SAMPLES = (256, 512, 1024, 2048, 4096, 8192)  # K the physics MPC may use
# (temperature, noise scale) pairs ``tune_settings`` tries, first with the default cost
TUNING_GRID = ((0.1, 1.0), (0.3, 1.0), (1.0, 1.0), (0.1, 0.5), (0.3, 0.5), (0.3, 2.0))
# and the cost changes it tries at the chosen pair against the default cost (``mppi.MPCConfig``
# fields): the swing bound, position errors beyond 0.5 m or 0.3 m pulling linearly, the floor
SWING_BOUND = 0.7  # rad (40 deg): the swing angle beyond it costs (``MPCConfig.max_swing``)
# deg: a swing past it counts against a tuning choice, after a lost flight (``tune_settings``),
# and the report lists the MPC flights past it where the geometric controller stayed below
UNSAFE_SWING = 60.0
FLOOR = 1.0  # m, 0.5 m below the hover height: lower costs (``MPCConfig.min_height``)
# The defaults the study, the unseen loads and the recorded flights share (the comparison
# keeps MPCConfig's)
SAMPLES = 256  # K of a real-time MPC
STEPS = 300  # recorded steps per flight (9 s; None in a config: the maneuver's whole length)
BACKEND = "compiled"  # what the real models predict on (``config.PREDICTION_BACKENDS``)
# the temperature the control study's tuning chose for the learned model's MPC at N = 15
# (docs/BENCHMARKS.md, 2026-11-25), fixed here for the flights that are not tuned
LEARNED_TEMPERATURE = 0.1
COST_GRID: tuple[dict[str, float], ...] = (
    {"max_swing": SWING_BOUND},
    {"position_huber": 0.5},
    {"position_huber": 0.3},
    {"max_swing": SWING_BOUND, "position_huber": 0.5},
    {"min_height": FLOOR},
)
# at most this many alternating rounds (noise, cost, noise, ...) of ``tune_settings``
TUNING_ROUNDS = 4
# the payload cost's lean (``MPCConfig.lean``) tuning also tries with each cost change: it
# helped the default plant at N = 15 and hurt the chain plant (docs/BENCHMARKS.md)
LEAN_CHOICE = 1.0


def cost_changes(cost: str, lean: float) -> list[dict[str, float]]:
    """The cost changes ``tune_settings`` tries (``MPCConfig`` fields) for a study of ``cost``
    at ``lean``: none, then each of ``COST_GRID``; for the "payload" cost each of those also
    with the lean ``LEAN_CHOICE`` (unless it is the study's own)."""
    changes: list[dict[str, float]] = [{}, *COST_GRID]
    if cost != "payload" or lean == LEAN_CHOICE:
        return changes
    return [*changes, *({**c, "lean": LEAN_CHOICE} for c in changes)]


# The ``StudyConfig`` fields that settle what a study folder's flights are: the MPC settings and
# Ks (the tuning flights, the equal-compute timing), the recorded steps, the oracle's K. A
# folder's settings.json and flights serve any config that agrees on these, so evaluation
# seeds, shifted plants, their horizons and the oracle's horizons can be added later.
SETTINGS_FIELDS = (
    "plant", "maneuvers", "tuning_seeds", "horizons", "samples", "oracle_samples", "steps",
    "tune", "backend", "cost", "lean", "shape", "risk", "with_physics", "trust_window",
    "input_lag",
)  # fmt: skip


@dataclass(frozen=True)
class ComparisonConfig:
    """What ``slungload control`` flies (``comparison.compare``): the PID, then the MPC over
    each prediction model once per K in ``samples``, on every maneuver x seed (defaults: the
    README's nine flights)."""

    maneuvers: tuple[str, ...] = DEFAULT_MANEUVERS
    seeds: tuple[int, ...] = (100, 101, 102)  # the default dataset is simulated from seed 0
    samples: tuple[int, ...] = (MPCConfig.samples,)  # K, one flight per model and K
    horizon: int = MPCConfig.horizon  # N, steps of 0.03 s
    steps: int | None = None  # recorded steps per flight (None: the maneuver's whole length)
    backend: str = "eager"  # what the prediction models run on (``config.PREDICTION_BACKENDS``)
    plant: str = DEFAULT_PLANT  # the simulated vehicle (``sim.plants.PLANTS``)
    cost: str = MPCConfig.cost  # the MPC's cost (``control.mppi.COSTS``)
    lean: float = MPCConfig.lean  # the "payload" cost's lean (``MPCConfig.lean``)
    shape: float = MPCConfig.shape  # the "payload" cost's jumps shaped (``MPCConfig.shape``)
    risk: float | None = MPCConfig.risk  # an ensemble's pricing (``MPCConfig.risk``)
    members: str = MPCConfig.members  # how an ensemble's members share the candidates
    input_lag: tuple[float, float, float] = MPCConfig.input_lag  # s, physics's (``MPCConfig``)
    with_physics: bool = False  # each network priced with physics by ``risk`` (control.paired)
    # with ``with_physics``: steps of the flown path on which the network must predict at least
    # as well as physics to take part (``control.paired.trust_steps``: None, its default; 0:
    # always)
    trust_window: int | None = None

    def __post_init__(self) -> None:
        _check_steps("ComparisonConfig", self.steps)
        trust_steps(self.trust_window, self.with_physics)  # refuses a window without physics
        _check_cost(self.cost, self.lean, self.shape, self.input_lag)
        _check_plant(self.plant)
        _check_maneuvers(self.maneuvers)
        if not self.samples or min(self.samples) < 2:
            raise ValueError(f"ComparisonConfig.samples: K >= 2 each, got {list(self.samples)}")

    @property
    def pair_window(self) -> int:
        """The pair's trust window in steps (``control.paired.trust_steps``; 0 without physics)."""
        return trust_steps(self.trust_window, self.with_physics)

    @property
    def mpc(self) -> MPCConfig:
        """The MPC's settings but K (``MPCConfig`` with this horizon and its knots); ``risk``
        and ``members`` are an ensemble's only (``comparison``)."""
        return MPCConfig(horizon=self.horizon, knots=knots_for(self.horizon), cost=self.cost,
                         lean=self.lean, shape=self.shape, risk=self.risk,
                         members=self.members, input_lag=self.input_lag)  # fmt: skip


@dataclass(frozen=True)
class StudyConfig:
    """What the study flies (defaults: the benchmark's; docs/control.md)."""

    maneuvers: tuple[str, ...] = STUDY_MANEUVERS
    seeds: tuple[int, ...] = (100, 101, 102, 103, 104)  # evaluation
    # MPC settings are chosen on these only: as many as evaluation seeds, so that a rare lost
    # flight or large swing shows up in the tuning too
    tuning_seeds: tuple[int, ...] = (200, 201, 202, 203, 204)
    horizons: tuple[int, ...] = (15, 25, 50)  # N, steps of 0.03 s
    samples: int = SAMPLES  # K of the learned model's MPC
    oracle_samples: int = 32  # K of the oracle's MPC (it is not real time)
    oracle_horizons: tuple[int, ...] = (15,)
    shifts: tuple[str, ...] = tuple(SHIFTS)
    # N of the real MPCs on the shifted plants, among ``horizons`` (empty: the first of them)
    shift_horizons: tuple[int, ...] = ()
    steps: int | None = STEPS
    tune: bool = True  # choose each MPC's noise and temperature on the tuning seeds
    backend: str = BACKEND
    # the simulated vehicle (``sim.plants.PLANTS``): its nominal constants are the physics
    # model's, the shifts are of it
    plant: str = DEFAULT_PLANT
    cost: str = MPCConfig.cost  # every MPC's cost (``control.mppi.COSTS``)
    lean: float = MPCConfig.lean  # the "payload" cost's lean (``MPCConfig.lean``)
    shape: float = MPCConfig.shape  # the "payload" cost's jumps shaped (``MPCConfig.shape``)
    # the learned MPC's plans priced under the network and the physics model by ``risk``
    # (``control.paired``): tuned, timed and matched at equal compute as that pair
    risk: float | None = MPCConfig.risk
    with_physics: bool = False
    trust_window: int | None = None  # with ``with_physics``: ``ComparisonConfig``'s
    input_lag: tuple[float, float, float] = MPCConfig.input_lag  # s, physics's (``MPCConfig``)

    @property
    def pair_window(self) -> int:
        """The pair's trust window in steps (``control.paired.trust_steps``; 0 without physics)."""
        return trust_steps(self.trust_window, self.with_physics)

    def mpc(self, *, members: bool = False, **fields: Any) -> MPCConfig:
        """An MPC of this study: ``fields`` (horizon, knots, K, tuned settings) with its cost;
        ``members``: over a model of members (the paired learned one), priced by ``risk``."""
        # a tuned choice may carry its own lean (``cost_changes``)
        return MPCConfig(**{"cost": self.cost, "lean": self.lean, "shape": self.shape, **fields},
                         risk=self.risk if members else None,
                         input_lag=self.input_lag)  # fmt: skip

    @property
    def shifted_horizons(self) -> tuple[int, ...]:
        """The horizons flown on the shifted plants."""
        return self.shift_horizons or self.horizons[:1]

    def __post_init__(self) -> None:
        _check_steps("StudyConfig", self.steps)
        _check_cost(self.cost, self.lean, self.shape, self.input_lag)
        _check_plant(self.plant)
        unknown = set(self.shifts) - set(SHIFTS)
        if unknown:
            raise ValueError(f"unknown plant shifts {sorted(unknown)}; known: {list(SHIFTS)}")
        if set(self.oracle_horizons) - set(self.horizons):
            raise ValueError(f"oracle horizons {list(self.oracle_horizons)} must be among the "
                             f"horizons {list(self.horizons)} (the oracle flies the learned "
                             "MPC's settings at its horizon)")  # fmt: skip
        if set(self.shift_horizons) - set(self.horizons):
            raise ValueError(f"shift horizons {list(self.shift_horizons)} must be among the "
                             f"horizons {list(self.horizons)}")  # fmt: skip
        trust_steps(self.trust_window, self.with_physics)
        if self.with_physics != (self.risk is not None):
            raise ValueError("the study prices the learned MPC's plans with the physics model "
                             "by a risk (--with-physics --risk BETA): give both or neither "
                             "(it flies no ensemble)")  # fmt: skip


@dataclass(frozen=True)
class UnseenLoadsConfig:
    """What ``study control-loads`` flies (``loads.fly_loads``; defaults: the benchmark's,
    docs/control.md). Every MPC flies K = ``samples``, N = ``horizon`` at ``temperature`` with
    the swing bound ``max_swing`` and the floor ``min_height`` (``MPCConfig``)."""

    # (load mass kg, cable length m) of each plant: two inside the loads study's training
    # range (0.10-0.25 kg, 0.6-0.9 m), one beyond it
    loads: tuple[tuple[float, float], ...] = ((0.13, 0.65), (0.22, 0.85), (0.32, 1.0))
    maneuvers: tuple[str, ...] = STUDY_MANEUVERS
    seeds: tuple[int, ...] = (100, 101, 102)
    samples: int = SAMPLES  # K
    # N, steps of 0.03 s: at 15 (0.45 s) the adaptive MPC lost 4 of 45 flights on position
    # steps, at 25 (0.75 s) 2, where the control study's learned MPC also loses none
    horizon: int = 25
    temperature: float = LEARNED_TEMPERATURE
    # the swing bound, likewise: at N = 25 it keeps those 2 in the arena
    max_swing: float = SWING_BOUND
    # the floor under the vehicle: it keeps in the arena the one flight the adaptive MPC still
    # lost in flight with the bound alone (xy_step, seed 100, 0.13 kg)
    min_height: float = FLOOR
    steps: int | None = STEPS
    backend: str = BACKEND
    # an ensemble's pricing in the network's MPCs (``MPCConfig.risk``): None, its members' mean
    risk: float | None = None

    def __post_init__(self) -> None:
        _check_steps("UnseenLoadsConfig", self.steps)


def _check_maneuvers(names: Iterable[str]) -> None:
    """Every name one of the simulator's maneuvers (``sim.maneuvers.MANEUVERS``)."""
    unknown = sorted(set(names) - set(MANEUVERS))
    if unknown:
        raise ValueError(f"unknown maneuvers {unknown}; known: {sorted(MANEUVERS)}")


def _check_plant(name: str) -> None:
    """One of the simulator's named plants (``sim.plants.PLANTS``)."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant {name!r}; known: {list(PLANTS)}")


def _check_steps(owner: str, steps: int | None) -> None:
    """Recorded steps per flight: None (the whole maneuver) or at least one."""
    if steps is not None and steps < 1:
        raise ValueError(f"{owner}.steps: None (the whole maneuver) or >= 1, got {steps}")


@dataclass(frozen=True)
class PlanErrorConfig:
    """What ``study plan-errors`` flies and probes (``plan_errors.plan_errors``; defaults: the
    study's maneuvers, three of its evaluation seeds, the real-time MPC's K at N = 15, the
    default MPC settings)."""

    maneuvers: tuple[str, ...] = STUDY_MANEUVERS
    seeds: tuple[int, ...] = (100, 101, 102)
    horizon: int = 15  # N, steps of 0.03 s
    samples: int = SAMPLES  # K of the flying MPC
    candidates: int = 32  # plans probed per probed step (the first of the K; the plan first)
    every: int = 10  # control steps between probes
    steps: int | None = STEPS  # recorded steps per flight
    flying: tuple[str, ...] = ("physics", LEARNED)  # whose MPC's plans are probed
    backend: str = BACKEND
    plant: str = DEFAULT_PLANT  # the simulated vehicle (``sim.plants.PLANTS``)

    def __post_init__(self) -> None:
        _check_steps("PlanErrorConfig", self.steps)
        _check_maneuvers(self.maneuvers)
        _check_plant(self.plant)
        if not 2 <= self.candidates <= self.samples:
            raise ValueError(f"PlanErrorConfig.candidates: 2..samples, got {self.candidates}")
        if self.every < 1:
            raise ValueError(f"PlanErrorConfig.every: >= 1, got {self.every}")
        if not self.flying or set(self.flying) - {"physics", LEARNED}:
            raise ValueError(f"PlanErrorConfig.flying: physics and/or {LEARNED}, got "
                             f"{list(self.flying)}")  # fmt: skip


# Sim seeds the closed-loop benchmarks fly: recorded training flights must not use them (the
# cost changes of docs/BENCHMARKS.md were also flown by hand on tuning seeds 200-209).
BENCHMARK_SEEDS = frozenset(
    {*StudyConfig.seeds, *StudyConfig.tuning_seeds, *UnseenLoadsConfig.seeds, *range(200, 210)}
)


@dataclass(frozen=True)
class RecordConfig:
    """What ``record`` flies (``record.record_flights``): the MPC over a trained model
    on ``flights`` (maneuver, count) with sim seeds ``first_seed``, ``first_seed`` + 1, ...,
    each flight recorded until it ends or the arena stops it, as training data on the states
    that MPC visits (docs/control.md). Defaults: the control study's learned MPC at N = 15 (its
    K, temperature and swing bound), most flights position steps, where that MPC lost flights."""

    flights: tuple[tuple[str, int], ...] = (
        ("xy_step", 30),
        ("xyz_step", 10),
        *((maneuver, 5) for maneuver in STUDY_MANEUVERS if maneuver != "xy_step"),
    )
    first_seed: int = 1000  # none of the benchmarks' seeds (``BENCHMARK_SEEDS``)
    samples: int = SAMPLES  # K
    horizon: int = 15  # N, steps of 0.03 s
    temperature: float = LEARNED_TEMPERATURE
    max_swing: float = SWING_BOUND  # rad
    steps: int | None = STEPS
    backend: str = BACKEND
    plant: str = DEFAULT_PLANT  # the simulated vehicle (``sim.plants.PLANTS``)

    def __post_init__(self) -> None:
        _check_steps("RecordConfig", self.steps)
        _check_plant(self.plant)
        names = [m for m, _ in self.flights]
        if not names or min(n for _, n in self.flights) < 1 or len(set(names)) < len(names):
            raise ValueError(f"RecordConfig.flights: each maneuver once, with >= 1 flight; got "
                             f"{list(self.flights)}")  # fmt: skip
        _check_maneuvers(names)
        taken = sorted(BENCHMARK_SEEDS.intersection(self.seeds))
        if taken:
            raise ValueError(
                f"recorded flights would fly the benchmarks' sim seeds {taken} (evaluation and "
                f"tuning); start them elsewhere (first seed now {self.first_seed})"
            )

    @property
    def seeds(self) -> range:
        """The sim seeds flown (each maneuver from ``first_seed`` on)."""
        return range(self.first_seed, self.first_seed + max(n for _, n in self.flights))


def _check_cost(cost: str, lean: float, shape: float, input_lag=MPCConfig.input_lag) -> None:
    if cost not in COSTS:
        raise ValueError(f"unknown MPC cost {cost!r}; known: {list(COSTS)}")
    # its rules for the lean, the shape and the lag
    MPCConfig(cost=cost, lean=lean, shape=shape, input_lag=input_lag)


# --- what a study folder's settings.json records of its configuration -----------------------

# What a settings file's null window (the default, as given) meant when it was written.
_EARLIER_WINDOW = 10


def settings_record(cfg: StudyConfig) -> dict[str, Any]:
    """The study's configuration as ``settings.json`` records it, the pair's window resolved
    (``pair_window``), whether the pair weighs its members by their record
    (``paired.WEIGH_BY_RECORD``): a file must say what its flights had, whatever the default
    becomes."""
    record = _jsonable(asdict(cfg))
    record["trust_window"] = cfg.pair_window
    record["pair_weighs"] = bool(cfg.pair_window) and paired.WEIGH_BY_RECORD
    return record


def recorded_settings(config: dict[str, Any]) -> dict[str, Any]:
    """A settings file's ``config`` as ``settings_record`` would write it today: a field the
    file lacks was added since, with the value its flights had (no window, equal weights, no
    lean, no shape, no input lag); a null window meant the default then, ``_EARLIER_WINDOW``."""
    was = _jsonable(asdict(StudyConfig()))
    was.update(trust_window=0, pair_weighs=False, lean=0.0, shape=0.0, input_lag=[0.0] * 3)
    theirs = {k: config.get(k, was[k]) for k in (*SETTINGS_FIELDS, "pair_weighs")}
    if theirs["trust_window"] is None:
        theirs["trust_window"] = _EARLIER_WINDOW if theirs["with_physics"] else 0
    return theirs


def _jsonable(value: Any) -> Any:
    """``value`` as JSON gives it back (tuples -> lists), to compare with a file's."""
    return json.loads(json.dumps(value))
