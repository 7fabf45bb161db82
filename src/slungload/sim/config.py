"""Simulator settings: which unmodelled effects are on, and every physical constant, in SI units.

The paper's discrete model (``physics.py``) leaves out drag, rotor downwash on the load, actuator
lags, thrust errors, cable stretch and slack, wind and sensor noise. The simulator puts them back,
each behind a switch in ``Effects``, so that a learned model has something to learn and a test can
turn one effect off at a time. Where each magnitude comes from is written in ``docs/simulator.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING

from ..config import VehicleParams

if TYPE_CHECKING:  # numpy is not imported by the command line's help
    import numpy as np


@dataclass(frozen=True)
class Effects:
    """Switches for the effects the paper's model leaves out (all on by default)."""

    drag: bool = True  # rotor (linear) + body (quadratic) drag on the vehicle, drag on the cube
    downwash: bool = True  # rotor wake pushing the load down when it is under the rotors
    thrust_lag: bool = True  # first-order lag of the achieved thrust behind the command
    rate_loop: bool = True  # finite-bandwidth inner body-rate loop (off: rates follow instantly)
    thrust_error: bool = True  # per-flight thrust scale and battery-sag drift
    thrust_offset: bool = True  # thrust centre off the centre of mass -> disturbance torque
    cable_stretch: bool = True  # elastic cable (off: a near-rigid one; slack is always possible)
    wind: bool = True  # Ornstein-Uhlenbeck gusts (indoor, modest)
    mocap_noise: bool = True  # noise on recorded positions and attitude
    velocity_filter: bool = True  # recorded velocity = low-passed difference (off: true velocity)
    latency: bool = True  # delay between a measurement and its command reaching the motors

    @classmethod
    def none(cls) -> Effects:
        """Every effect off: the ideal system (rigid body, taut-or-slack cable, exact sensing)."""
        return cls(**{f.name: False for f in fields(cls)})

    @classmethod
    def only(cls, *names: str) -> Effects:
        """Only the named effects on (tests isolate one effect this way)."""
        return replace(cls.none(), **{n: True for n in cls._checked(names)})

    @classmethod
    def _checked(cls, names) -> tuple[str, ...]:
        unknown = set(names) - set(cls.names())
        if unknown:
            raise ValueError(f"unknown effects {sorted(unknown)}; known: {list(cls.names())}")
        return tuple(names)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Names of the switches, for the CLI's ``--no-EFFECT`` flags."""
        return tuple(f.name for f in fields(cls))

    def without(self, *names: str) -> Effects:
        """A copy with the named effects switched off; unknown names are an error."""
        return replace(self, **{n: False for n in self._checked(names)})


@dataclass(frozen=True)
class Excitation:
    """Random perturbations added to the controller's commands (off by default).

    A model trained on closed-loop flights only sees the inputs its controller chose, which are
    a function of the state; it can then predict well from the history alone and ignore the
    inputs, which is useless to a model-predictive controller that has to compare inputs
    (docs/control.md). A smooth random signal added to the commands, independent of the state,
    shows the model how the vehicle answers inputs the controller would not have chosen.

    Each channel is an Ornstein-Uhlenbeck process with stationary standard deviation
    ``thrust_std`` (N) or ``rate_std`` (rad/s, body x, y, z) and correlation time ``tau`` (s).
    The recorded commands ``T_ref``/``w_ref`` include it (they are what the vehicle was told).
    """

    thrust_std: float = 0.0  # N
    rate_std: tuple[float, float, float] = (0.0, 0.0, 0.0)  # rad/s, body x, y, z
    tau: float = 0.15  # s, correlation time

    def __post_init__(self) -> None:
        if self.thrust_std < 0 or min(self.rate_std) < 0 or len(self.rate_std) != 3:
            raise ValueError(
                f"Excitation: need thrust_std >= 0 and three rate_std >= 0, got "
                f"{self.thrust_std} and {self.rate_std}"
            )
        if not self.tau > 0:
            raise ValueError(f"Excitation.tau must be > 0, got {self.tau}")

    @property
    def active(self) -> bool:
        return self.thrust_std > 0 or max(self.rate_std) > 0


def _ranged(unit: str, text: str):
    """A field of ``LoadRanges``: no range by default; its unit and description as metadata (the
    command line's help is made from them)."""
    return field(default=None, metadata={"unit": unit, "text": text})


@dataclass(frozen=True)
class LoadRanges:
    """Ranges (low, high) of the vehicle and load constants, drawn per flight (none by default).

    A quantity without a range keeps ``SimConfig``'s single value in every flight (the flights
    are then those of a config without ``LoadRanges``, byte for byte). With a range, each flight
    draws its value uniformly from its own random stream and records it in its file
    (``fileio.CONSTANT_KEYS``); the nominal value, which ``vehicle.json`` holds and the PID
    controller is built for, is the range's midpoint (``SimConfig.nominal``). The names are the
    ``SimConfig`` quantities they vary; ``cable_length`` is the effective length, vehicle centre
    of mass -> load centre (the string is that less the attachment and half the cube).
    """

    mass_quad: tuple[float, float] | None = _ranged("kg", "vehicle mass")
    load_mass: tuple[float, float] | None = _ranged("kg", "load mass")
    cable_length: tuple[float, float] | None = _ranged(
        "m", "effective cable length, vehicle centre of mass to load centre"
    )

    def __post_init__(self) -> None:
        for name in self.names():
            bounds = getattr(self, name)
            if bounds is not None and not (len(bounds) == 2 and 0 < bounds[0] <= bounds[1]):
                raise ValueError(
                    f"LoadRanges.{name} must be (low, high) with 0 < low <= high, got {bounds}"
                )

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @property
    def active(self) -> bool:
        """Whether any quantity varies from flight to flight."""
        return any(getattr(self, name) is not None for name in self.names())


# The plant families (``sim.families``): structurally different simulators of one vehicle.
# ``tendon``: the thrust and an inner body-rate loop as MuJoCo actuators with first-order lags,
# the cable one elastic tendon, rotor drag and downwash (``plant.Plant``). ``chain``: four
# rotors with speed lags and saturation behind an explicit body-rate PI loop and a mixer, the
# cable a chain of links with its own mass, quadratic drag only (``chain.ChainPlant``).
FAMILIES = ("tendon", "chain")


@dataclass(frozen=True)
class Chain:
    """Constants only the ``chain`` family uses (``sim/chain.py``); SI units."""

    links: int = 5  # -, straight links of the cable; a point-mass bead joins each two
    cable_density: float = 0.02  # kg/m, the cable's own mass per metre, carried by its beads
    bead_damping: float = 0.003  # N s/m, air drag of each bead (damps the chain's fast modes)
    arm: float = 0.16  # m, centre of mass to each of the four rotors (X configuration)
    rotor_tau: float = 0.035  # s, lag of each rotor's speed behind its command (thrust ~ speed^2)
    yaw_moment: float = 0.016  # m, rotor drag torque per newton of that rotor's thrust
    # the rate loop: angular acceleration per rad/s of error (P) and per rad of its integral
    # (I), body x, y, z; about 30 % overshoot on a step, a 5 mm thrust offset taken out in 1 s
    rate_kp: tuple[float, float, float] = (25.0, 25.0, 8.0)  # 1/s
    rate_ki: tuple[float, float, float] = (120.0, 120.0, 20.0)  # 1/s^2
    rate_integral: float = 0.3  # rad, bound of each axis's integrated rate error (anti-windup)
    load_drag_coef: float = 0.47  # -, drag coefficient of the spherical load

    def __post_init__(self) -> None:
        if self.links < 2:
            raise ValueError(f"Chain.links must be >= 2, got {self.links}")
        for name in ("arm", "rotor_tau", "rate_integral"):
            if not getattr(self, name) > 0:
                raise ValueError(f"Chain.{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class SimConfig:
    """Constants of the simulated quadrotor, cable, load, air, actuators, sensors and controller.

    Sources for every magnitude are in ``docs/simulator.md``.
    """

    family: str = "tendon"  # which simulator flies it (``FAMILIES``)
    chain: Chain = field(default_factory=Chain)  # the ``chain`` family's own constants
    effects: Effects = field(default_factory=Effects)
    excitation: Excitation = field(default_factory=Excitation)  # of the commands; off
    loads: LoadRanges = field(default_factory=LoadRanges)  # per-flight vehicle and load; none
    # --- timing
    control_dt: float = 0.03  # s, h: control and recording period (the paper's sampling time)
    substeps: int = 15  # MuJoCo steps per control period (timestep 2 ms)
    warmup: float = 1.0  # s, hover simulated before recording starts (not written)
    # --- vehicle (Intel Aero RTF)
    mass_quad: float = 1.35  # kg
    inertia_quad: tuple[float, float, float] = (0.0115, 0.0115, 0.021)  # kg m^2, body x, y, z
    attach_below: float = 0.05  # m, cable attachment below the vehicle's centre of mass
    rotor_area: float = 0.166  # m^2, total disc area of the four 9-inch rotors
    max_thrust: float = 30.0  # N, saturation of the achieved thrust
    hover_z: float = 1.5  # m, hover height of the vehicle (load 0.8 m above the floor)
    # --- cable and load (100 g cube, 10 cm edges, 60 cm string)
    string_length: float = 0.6  # m, string between attachment and the cube's top face
    load_mass: float = 0.1  # kg
    load_size: float = 0.1  # m, cube edge
    cable_stiffness: float = 1500.0  # N/m, elastic stretch of the string when taut
    cable_damping: float = 5.0  # N s/m, internal damping of the string (about 0.2 critical)
    # --- air
    air_density: float = 1.2  # kg/m^3
    rotor_drag: float = 0.35  # N/(m/s), linear rotor drag on in-plane air-relative velocity
    body_drag_area: tuple[float, float, float] = (0.025, 0.025, 0.05)  # m^2, Cd*A body x, y, z
    load_drag_area: float = 0.0105  # m^2, Cd*A of the cube (Cd 1.05 x 0.01 m^2)
    downwash_gain: float = 1.0  # -, wake speed at the load / induced velocity at the disc
    downwash_radius: float = 0.2  # m, 1/e lateral radius of the wake around the rotor axis
    wind_std: float = 0.15  # m/s, horizontal gust standard deviation (vertical: a third)
    wind_tau: float = 2.0  # s, gust correlation time
    # --- actuators
    thrust_tau: float = 0.04  # s, first-order lag of thrust behind its command
    rate_bandwidth: tuple[float, float, float] = (18.0, 18.0, 6.0)  # rad/s, inner rate loop x y z
    motor_tau: float = 0.02  # s, lag of the rate loop's torque command (motor spin-up)
    thrust_scale_spread: float = 0.06  # -, achieved/commanded thrust drawn in 1 +- spread
    battery_sag: float = 0.003  # 1/s, largest loss of thrust per second of flight
    thrust_offset_std: float = 0.002  # m, thrust centre offset from the centre of mass (x, y)
    latency: float = 0.012  # s, measurement-to-motor delay (rounded to substeps)
    # --- motion capture
    pos_noise: float = 0.001  # m, vehicle position noise (1 sigma)
    load_pos_noise: float = 0.003  # m, load position noise (1 sigma)
    att_noise: float = 0.008  # rad, attitude noise per axis (1 sigma)
    velocity_tau: float = 0.04  # s, low-pass time constant of the velocity estimate
    # --- offboard controller (acts on the noisy measurements)
    kp: tuple[float, float, float] = (3.5, 3.5, 5.0)  # 1/s^2, position gain
    kd: tuple[float, float, float] = (3.0, 3.0, 3.5)  # 1/s, velocity gain
    ki: tuple[float, float, float] = (1.0, 1.0, 1.5)  # 1/s^3, integral gain
    k_att: tuple[float, float, float] = (7.0, 7.0, 3.0)  # 1/s, attitude error -> rate command
    max_tilt: float = 0.75  # rad, tilt limit of the desired attitude (43 deg)
    max_rate: float = 4.0  # rad/s, body-rate command limit
    max_position_error: float = 1.0  # m, position error saturation (steps)
    gravity: float = 9.81  # m/s^2

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"SimConfig.family: one of {list(FAMILIES)}, got {self.family!r}")
        positive = (
            "control_dt", "mass_quad", "string_length", "load_mass", "load_size", "rotor_area",
            "max_thrust", "air_density", "thrust_tau", "motor_tau", "wind_tau", "velocity_tau",
            "gravity", "cable_stiffness",
        )  # fmt: skip
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"SimConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.substeps < 1:
            raise ValueError(f"SimConfig.substeps must be >= 1, got {self.substeps}")
        if self.latency < 0 or self.latency >= self.control_dt:
            raise ValueError(f"SimConfig.latency must be in [0, control_dt), got {self.latency}")
        shortest = self.attach_below + 0.5 * self.load_size
        if self.loads.cable_length is not None and self.loads.cable_length[0] <= shortest:
            raise ValueError(
                f"SimConfig.loads.cable_length must start above the attachment and half the "
                f"load, {shortest:g} m, got {self.loads.cable_length}"
            )

    @property
    def timestep(self) -> float:
        """MuJoCo timestep, s."""
        return self.control_dt / self.substeps

    @property
    def cable_length(self) -> float:
        """Effective length, m, vehicle centre of mass -> cube centre (the paper's l)."""
        return self.attach_below + self.string_length + 0.5 * self.load_size

    @property
    def total_mass(self) -> float:
        """mQ + mL, kg."""
        return self.mass_quad + self.load_mass

    def value(self, name: str) -> float:
        """The single value of a ``LoadRanges`` quantity (its field, or the ``cable_length``
        property), the one every flight flies without a range."""
        if name not in LoadRanges.names():
            raise ValueError(f"unknown load quantity {name!r}; known: {list(LoadRanges.names())}")
        return float(getattr(self, name))

    def with_load(self, **values: float) -> SimConfig:
        """A copy flying these single values (``LoadRanges`` names; the cable length through the
        string length) with no ranges left: one flight's plant, or the nominal vehicle."""
        unknown = set(values) - set(LoadRanges.names())
        if unknown:
            raise ValueError(f"unknown load quantities {sorted(unknown)}")
        fixed = {k: float(v) for k, v in values.items() if k != "cable_length"}
        if "cable_length" in values:
            ends = self.attach_below + 0.5 * self.load_size  # attachment and half the cube
            fixed["string_length"] = values["cable_length"] - ends
        return replace(self, loads=LoadRanges(), **fixed)

    def with_loads(self, **values: float | tuple[float, float] | None) -> SimConfig:
        """A copy with ``LoadRanges`` quantities set: a number (or a range of zero width) is a
        single value for every flight, (low, high) a range drawn per flight, None unchanged."""
        fixed, ranges = {}, {}
        for name, value in values.items():
            if value is None:
                continue
            if isinstance(value, tuple) and value[0] != value[1]:
                ranges[name] = (float(value[0]), float(value[1]))
            else:
                fixed[name] = float(value[0] if isinstance(value, tuple) else value)
        kept = {n: getattr(self.loads, n) for n in LoadRanges.names() if n not in fixed}
        return replace(self.with_load(**fixed), loads=LoadRanges(**{**kept, **ranges}))

    @property
    def nominal(self) -> SimConfig:
        """The config with each ranged quantity at its range's midpoint and no ranges: the
        vehicle ``vehicle.json`` describes and the default controller is built for (``self``
        when nothing varies)."""
        if not self.loads.active:
            return self
        mids = {n: 0.5 * sum(r) for n in LoadRanges.names() if (r := getattr(self.loads, n))}
        return self.with_load(**mids)

    def drawn(self, rng: np.random.Generator) -> SimConfig:
        """One flight's config: each ranged quantity drawn uniformly, rounded to 1e-9 (the
        precision of the MuJoCo model's text). Three uniforms are always drawn, in
        ``LoadRanges`` order, so one range does not change another's draw; ``self`` (and
        ``rng`` untouched) when nothing varies."""
        if not self.loads.active:
            return self
        u = rng.uniform(0.0, 1.0, size=len(LoadRanges.names()))
        draws = {}
        for name, ui in zip(LoadRanges.names(), u, strict=True):
            bounds = getattr(self.loads, name)
            if bounds is not None:
                draws[name] = round(bounds[0] + float(ui) * (bounds[1] - bounds[0]), 9)
        return self.with_load(**draws)

    @classmethod
    def from_dict(cls, data: dict) -> SimConfig:
        """Rebuild from ``config.to_dict`` output (e.g. ``vehicle.json["sim"]``)."""
        data = dict(data)
        effects = Effects(**data.pop("effects", {}))
        chain = Chain(**tuples_from_json(data.pop("chain", {})))
        excitation = Excitation(**tuples_from_json(data.pop("excitation", {})))
        loads = LoadRanges(**tuples_from_json(data.pop("loads", None) or {}))
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"SimConfig: unknown keys {sorted(unknown)}")
        return cls(effects=effects, chain=chain, excitation=excitation, loads=loads,
                   **tuples_from_json(data))  # fmt: skip

    def with_effects(self, effects: Effects) -> SimConfig:
        """A copy with other effect switches."""
        return replace(self, effects=effects)


def vehicle_params(cfg: SimConfig) -> VehicleParams:
    """The paper-model constants matching the simulated geometry (of one flight, or of the
    nominal vehicle: ``vehicle_params(cfg.nominal)``)."""
    return VehicleParams(
        mass_quad=cfg.mass_quad,
        mass_load=cfg.load_mass,
        cable_length=round(cfg.cable_length, 9),  # 0.05 + 0.6 + 0.05 without float dust
        dt=cfg.control_dt,
        gravity=cfg.gravity,
    )


def tuples_from_json(data: dict) -> dict:
    """JSON lists back to the tuples the frozen configs hold (``SimConfig.from_dict``, the
    control study's saved MPC settings)."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
