"""Fly one maneuver: controller + plant + mocap, recorded as the published flight schema."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..fileio import CONSTANT_KEYS
from ..frames import rotation_matrix
from .aero import ou_wind
from .config import SimConfig, vehicle_params
from .controller import Controller, Measurement, PIDController, excitation_signal
from .families import make_plant
from .maneuvers import Maneuver, Reference, make_maneuver, sample_reference
from .plant import Plant, PlantParams
from .sensors import Mocap
from .streams import seed_streams


@dataclass(frozen=True)
class Flight:
    """One simulated flight.

    ``arrays`` holds the published schema (``fileio.FLIGHT_KEYS``: time, p, v, attitude x-y-z-w,
    p_load, w_ref, T_ref) as recorded, i.e. noisy measurements and the *commands*.
    ``truth`` holds what really happened at the same instants: p, v, q (w-x-y-z), p_load,
    v_load, thrust (achieved, N), rates (achieved, rad/s), cable (attachment -> cube top, m),
    wind (m/s). ``config`` is the flight's own config: the simulator's, with the vehicle and
    load drawn for this flight in place when ``SimConfig.loads`` gives ranges (the file then
    records them, ``fileio.CONSTANT_KEYS``).
    """

    maneuver: str
    arrays: dict[str, np.ndarray]
    truth: dict[str, np.ndarray]
    params: PlantParams = field(default_factory=PlantParams)
    config: SimConfig = field(default_factory=SimConfig)

    @property
    def steps(self) -> int:
        return int(self.arrays["time"].shape[0])


@dataclass(frozen=True)
class FlightSetup:
    """What a flight is before its first step: its seed's streams (maneuver, plant, wind,
    sensors, excitation, load; the later ones do not change the earlier), the maneuver, the
    recorded steps, the times (T,) s of every control step (warm-up negative), the vehicle and
    load flown, the plant in its start state, the reference at ``times``, the wind (T, 3) m/s
    of every step and the motion capture (its noise stream unused yet). The simulated PX4
    (``autopilot.sil``) starts a flight of a maneuver and seed from the same draws."""

    streams: tuple[np.random.Generator, ...]
    maneuver: Maneuver
    steps: int
    times: np.ndarray
    flown: SimConfig
    plant: Plant
    reference: Reference
    wind: np.ndarray
    mocap: Mocap


def flight_setup(
    maneuver: str | Maneuver,
    seed: int | np.random.SeedSequence = 0,
    config: SimConfig | None = None,
    steps: int | None = None,
) -> FlightSetup:
    """The flight ``simulate_flight`` flies for the same arguments, before its first step."""
    cfg = config or SimConfig()
    streams = seed_streams(seed)
    man = make_maneuver(maneuver, streams[0]) if isinstance(maneuver, str) else maneuver
    n = int(steps if steps is not None else man.steps)
    if n < 1:
        raise ValueError(f"a flight needs at least one step, got {n}")
    warm = round(cfg.warmup / cfg.control_dt)
    times = (np.arange(warm + n) - warm) * cfg.control_dt  # recording starts at t = 0
    flown, plant, wind, mocap = vehicle_draws(streams, cfg, warm + n)
    ref = sample_reference(man, times, plant.p)  # from the start point, where it hovers
    for a in (ref.position, ref.velocity, ref.acceleration, ref.yaw):
        a.flags.writeable = False  # every step sees the same reference: no controller edits it
    return FlightSetup(streams, man, n, times, flown, plant, ref, wind, mocap)


def vehicle_draws(
    streams: tuple[np.random.Generator, ...], config: SimConfig, wind_steps: int
) -> tuple[SimConfig, Plant, np.ndarray, Mocap]:
    """What a flight draws besides its maneuver, from its streams (``seed_streams``): the
    vehicle and load flown (``config`` when none vary), the plant in its start state, the
    wind (``wind_steps``, 3) m/s and the motion capture."""
    _, s_plant, s_wind, s_sens, _, s_load = streams  # sim.streams.FLIGHT_STREAMS
    flown = config.drawn(s_load)
    plant = make_plant(flown, PlantParams.draw(flown, s_plant))
    return flown, plant, ou_wind(config, wind_steps, s_wind), Mocap(config, s_sens)


def flight_reference(
    maneuver: str | Maneuver,
    *,
    seed: int | np.random.SeedSequence = 0,
    config: SimConfig | None = None,
    steps: int | None = None,
) -> Reference:
    """The reference ``simulate_flight`` gives its controller for the same arguments, warm-up
    rows included (position, velocity, acceleration (T, 3), yaw (T,)): what a flown log is
    scored against beyond the positions it records."""
    return flight_setup(maneuver, seed, config, steps).reference


def simulate_flight(
    maneuver: str | Maneuver,
    *,
    seed: int | np.random.SeedSequence = 0,
    config: SimConfig | None = None,
    steps: int | None = None,
    controller: Controller | None = None,
) -> Flight:
    """Simulate one flight of a maneuver (a registered name or a ``Maneuver``).

    seed: integer or SeedSequence; it draws the maneuver's parameters, the plant's
    imperfections, the wind and the sensor noise from independent streams. steps overrides the
    maneuver's length (recorded control steps). controller: what flies it, called once per
    control step as the ``Controller`` contract states (warm-up included); None flies a fresh
    ``PIDController`` of the config (the default flights). A stateful controller should be a
    fresh one per flight; the default PID is built for ``config.nominal``, while the plant flies
    the vehicle and load drawn for this flight when ``config.loads`` gives ranges (from a sixth
    stream of the seed). A controller with an ``attach(plant)`` method gets the flight's
    ``Plant`` once before the first step: a benchmark that predicts with the true plant (the
    oracle MPC) uses it; a controller of a real vehicle has no such view. With
    ``config.excitation`` active, its random signal is added to
    every command (``controller.excitation_signal``; thrust kept >= 0). Returns a ``Flight``
    with float64 arrays; ``arrays["T_ref"]`` and ``arrays["w_ref"]`` are the commands sent.

    Raises ``ValueError`` when the controller returns a non-finite thrust or rates, or rates
    not of shape (3,), naming the step, before the command reaches the plant.
    """
    cfg = config or SimConfig()
    setup = flight_setup(maneuver, seed, cfg, steps)
    man, n, times, flown, plant, ref = (setup.maneuver, setup.steps, setup.times, setup.flown,
                                        setup.plant, setup.reference)  # fmt: skip
    wind, mocap, s_exc = setup.wind, setup.mocap, setup.streams[4]
    h = cfg.control_dt
    total = len(times)
    warm = total - n
    # The PID is built for the nominal vehicle: like a real one it does not know the load.
    ctrl = PIDController(cfg.nominal) if controller is None else controller
    attach = getattr(ctrl, "attach", None)
    if attach is not None:  # a benchmark controller that looks at the true plant (the oracle)
        attach(plant)
    dither = excitation_signal(cfg.excitation, h, total, s_exc)  # (total, 4), zero when off

    rec = {k: np.empty((n, d)) for k, d in (("p", 3), ("v", 3), ("q", 4), ("p_load", 3))}
    rec.update(w_ref=np.empty((n, 3)), T_ref=np.empty((n, 1)))
    truth = {k: np.empty((n, d)) for k, d in (("p", 3), ("v", 3), ("q", 4), ("p_load", 3),
             ("v_load", 3), ("rates", 3), ("wind", 3))}  # fmt: skip
    truth.update(thrust=np.empty(n), cable=np.empty(n))
    for k in range(total):
        p, v, q, pl = plant.p, plant.v, plant.q, plant.p_load
        p_m, v_m, q_m, pl_m = mocap.measure(p, v, q, pl)
        rot_m = rotation_matrix(q_m)
        # Read-only views: the same arrays are recorded below (and the mocap keeps some).
        meas = Measurement(float(times[k]), *map(_read_only, (p_m, v_m, q_m, rot_m, pl_m)))
        thrust, rates = _checked(ctrl(meas, ref, k), k, warm)
        if cfg.excitation.active:
            thrust, rates = max(thrust + dither[k, 0], 0.0), rates + dither[k, 1:]
        i = k - warm
        if i >= 0:
            rec["p"][i], rec["v"][i], rec["q"][i], rec["p_load"][i] = p_m, v_m, q_m, pl_m
            rec["w_ref"][i], rec["T_ref"][i, 0] = rates, thrust
            truth["p"][i], truth["v"][i], truth["q"][i], truth["p_load"][i] = p, v, q, pl
            truth["v_load"][i], truth["rates"][i] = plant.v_load, plant.rates
            truth["thrust"][i], truth["cable"][i] = plant.thrust, plant.cable_length
            truth["wind"][i] = wind[k]
        plant.advance(thrust, rates, wind[k])

    arrays = published(rec, h, flown if cfg.loads.active else None)
    return Flight(man.name, arrays, truth, plant.params, flown)


def published(rec: dict[str, np.ndarray], h: float, flown: SimConfig | None = None) -> dict:
    """The recorded arrays (p, v, q w-x-y-z, p_load, w_ref, T_ref (n, 1), each (n, ...)) in
    the published schema (attitude x-y-z-w), ``h`` s apart; with ``flown`` (loads
    that vary from flight to flight) also this flight's constants, ``fileio.CONSTANT_KEYS``:
    without ranges the file is what it always was."""
    q = rec["q"] / np.linalg.norm(rec["q"], axis=1, keepdims=True)
    arrays = {
        "time": np.arange(len(q), dtype=np.float64) * h,
        "p": rec["p"],
        "v": rec["v"],
        "attitude": np.concatenate([q[:, 1:], q[:, :1]], axis=1),  # x-y-z-w
        "p_load": rec["p_load"],
        "w_ref": rec["w_ref"],
        "T_ref": rec["T_ref"],
    }
    if flown is not None:
        constants = vehicle_params(flown)
        arrays.update({key: np.array(getattr(constants, key)) for key in CONSTANT_KEYS})
    return arrays


def _checked(command: tuple[float, np.ndarray], k: int, warm: int) -> tuple[float, np.ndarray]:
    """A controller's (T N, omega (3,) rad/s) as (float, own float64 copy), or ValueError.

    Checked here so that a NaN never reaches MuJoCo (it would poison the state silently). The
    copy matters: the plant holds the rates across periods (latency), so a controller reusing
    its output buffer must not change a command already sent.
    """
    thrust, rates = command
    thrust = float(thrust)
    rates = np.array(rates, dtype=float)
    when = f"step {k} (" + ("warm-up)" if k < warm else f"recorded step {k - warm})")
    if rates.shape != (3,):
        raise ValueError(f"controller at {when}: body rates need shape (3,), got {rates.shape}")
    if not (math.isfinite(thrust) and np.isfinite(rates).all()):
        raise ValueError(
            f"controller returned a non-finite command at {when}: "
            f"thrust {thrust} N, body rates {rates.tolist()} rad/s"
        )
    return thrust, rates


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (``a`` itself stays writeable)."""
    view = a.view()
    view.flags.writeable = False
    return view
