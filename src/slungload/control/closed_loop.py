"""Closed-loop flights in the simulator, guarded, logged and scored.

``fly(maneuver, seed, controller)`` flies one maneuver through ``sim.simulate_flight`` with the
controller wrapped in a ``Guard``. Before each step the guard checks the measurement: a vehicle
outside the ``Arena`` box, or a non-finite measurement (an unstable simulation), ends the run
with that reason (``RunStopped``, raised from the controller call at the top of the
simulator's loop, before anything reaches MuJoCo); so does a non-finite command or one of the
wrong shape. ``fly`` never raises for a run that goes wrong in these ways: it returns a
``FlightLog`` whose ``stopped`` names the reason (an exception the controller raises itself is
a bug in it, and propagates). The log holds what the controller saw and did at every step
(measured states, the reference, the commands, the compute time of each call);
``flight_metrics`` scores the recorded part (t >= 0) of it:

- vehicle tracking RMSE, m: ||p - p_ref|| over the recorded steps;
- load tracking RMSE, m: ||pL - (p_ref - l e3)||, l the effective cable length;
- swing angle RMS and max, deg: the angle between the cable pL - p and -e3;
- time at a limit, %: steps whose command sits at a thrust or body-rate bound;
- compute per control step, ms: median and p99 of the controller call (warm-up included).

``realized_cost`` sums an MPC's own cost over a log, term by term (any controller's flight).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..config import VehicleParams
from ..fileio import write_npz
from ..frames import swing_angle
from ..layout import LOAD_POS, POS, QUAT, RATES, THRUST, VEL
from ..sim.config import SimConfig
from ..sim.controller import Controller, Measurement
from ..sim.flight import published, simulate_flight
from ..sim.maneuvers import Reference
from .cost import cost_target, lean_rows, reference_rows, shape_of, trajectory_cost
from .mpc import InputLimits, MPCConfig


@dataclass(frozen=True)
class Arena:
    """Box the vehicle must stay in, m (world frame). The references stay within |x|, |y| <= 2
    and 1 <= z <= 2.2; below z = 0.75 the hanging load would be at the floor."""

    lo: tuple[float, float, float] = (-3.0, -3.0, 0.75)
    hi: tuple[float, float, float] = (3.0, 3.0, 3.5)

    def outside(self, p: np.ndarray) -> str | None:
        """Why position p (3,) is not inside, or None."""
        for axis, name in enumerate("xyz"):
            if not self.lo[axis] <= p[axis] <= self.hi[axis]:
                return (
                    f"vehicle left the arena: {name} = {p[axis]:.2f} m outside "
                    f"[{self.lo[axis]}, {self.hi[axis]}]"
                )
        return None


class RunStopped(Exception):
    """Raised by the guard to end a flight; the message is the reason."""


class Guard:
    """Wraps a controller: checks every measurement and command, logs, times each call."""

    def __init__(self, controller: Controller, arena: Arena, warmup_steps: int) -> None:
        self.controller = controller
        self.arena = arena
        self.warm = warmup_steps
        self.rows: list[dict[str, Any]] = []
        self.planned: int | None = None  # recorded steps of the flight (from the reference)

    def attach(self, plant) -> None:
        """Pass the flight's plant on to a controller that looks at it (the oracle MPC)."""
        attach = getattr(self.controller, "attach", None)
        if attach is not None:
            attach(plant)

    def __call__(self, measurement: Measurement, reference: Reference, k: int):
        self.planned = len(reference.yaw) - self.warm
        x = measurement.state
        if not np.isfinite(x).all():
            raise RunStopped(f"non-finite measurement at step {k} (unstable simulation)")
        reason = self.arena.outside(measurement.p)
        if reason:
            raise RunStopped(f"{reason} at t = {measurement.t:.2f} s")
        start = time.perf_counter()
        thrust, rates = self.controller(measurement, reference, k)
        elapsed = time.perf_counter() - start
        rates = np.asarray(rates, dtype=float)
        if rates.shape != (3,) or not (math.isfinite(float(thrust)) and np.isfinite(rates).all()):
            raise RunStopped(f"controller returned an invalid command at step {k}")
        self.rows.append(
            dict(t=measurement.t, x=x, p_ref=reference.position[k].copy(),
                 u=np.array([float(thrust), *rates]), compute=elapsed)
        )  # fmt: skip
        return float(thrust), rates


@dataclass
class FlightLog:
    """One guarded flight: what the controller saw and did, and how it ended."""

    maneuver: str
    seed: int
    controller: str
    planned_steps: int  # recorded steps the maneuver asks for
    t: np.ndarray  # (S,) s, warm-up steps negative
    states: np.ndarray  # (S, 13) measured x, q w-x-y-z
    p_ref: np.ndarray  # (S, 3) m
    inputs: np.ndarray  # (S, 4) commands (T N, omega rad/s)
    compute: np.ndarray  # (S,) s per controller call
    stopped: str | None = None  # why the run ended early, None when it flew to the end
    stats: dict[str, Any] = field(default_factory=dict)  # the controller's counters

    def published(self, dt: float) -> dict[str, np.ndarray]:
        """The recorded part (t >= 0, up to where the flight stopped) in the published flight
        schema, ``dt`` s apart: what the controller measured and commanded. That is what
        ``simulate`` writes of the same flight when the simulator adds no excitation to the
        commands and flies one load (no per-flight constants)."""
        x, u = self.states[self.t >= 0], self.inputs[self.t >= 0]
        rec = {"p": x[:, POS], "v": x[:, VEL], "q": x[:, QUAT], "p_load": x[:, LOAD_POS],
               "w_ref": u[:, RATES], "T_ref": u[:, THRUST]}  # fmt: skip
        return published(rec, dt)


def fly(
    maneuver: str,
    seed: int,
    controller: Controller,
    *,
    label: str,
    config: SimConfig | None = None,
    arena: Arena | None = None,
    steps: int | None = None,
) -> FlightLog:
    """Fly ``maneuver`` with sim seed ``seed`` and a fresh ``controller``; a run that leaves the
    arena or goes non-finite ends with ``stopped`` set, without raising (see the module)."""
    cfg = config or SimConfig()
    warm = round(cfg.warmup / cfg.control_dt)
    guard = Guard(controller, arena or Arena(), warm)
    stopped = None
    try:
        simulate_flight(maneuver, seed=seed, config=cfg, steps=steps, controller=guard)
    except RunStopped as exc:
        stopped = str(exc)
    rows = guard.rows
    stats = getattr(controller, "stats", None)
    return FlightLog(
        maneuver,
        seed,
        label,
        int(guard.planned or 0),
        np.array([r["t"] for r in rows]),
        np.array([r["x"] for r in rows]).reshape(-1, 13),
        np.array([r["p_ref"] for r in rows]).reshape(-1, 3),
        np.array([r["u"] for r in rows]).reshape(-1, 4),
        np.array([r["compute"] for r in rows]),
        stopped,
        _stats_dict(stats),
    )


def _stats_dict(stats: Any) -> dict[str, Any]:
    if stats is None:
        return {}
    return {
        "mpc_steps": stats.steps,
        "fallback_steps": stats.fallback_steps,
        "fallbacks": dict(stats.fallbacks),
        "nonfinite_steps": stats.nonfinite_steps,
        "hover_steps": stats.hover_steps,
        "physics_only_steps": stats.physics_only_steps,
        "surprised_steps": stats.surprised_steps,
    }


LOG_ARRAYS = ("t", "states", "p_ref", "inputs", "compute")  # what a saved flight log holds


def log_path(out: str | Path, plant: str, label: str, maneuver: str, seed: int) -> Path:
    """Where a flown flight lands under ``out``, without suffix (a ``.npz`` log, ``write_log``,
    and beside it the study's ``.json`` row): ``flights/<plant>/<controller>/<maneuver>_s<seed>``,
    with any character a file name may not hold as "_"."""
    safe = lambda s: "".join(c if c.isalnum() or c in "-_." else "_" for c in s)  # noqa: E731
    return Path(out) / "flights" / safe(plant) / safe(label) / f"{maneuver}_s{seed}"


def write_log(path: str | Path, log: FlightLog) -> None:
    """A flight log's arrays as one ``.npz`` (``read_log`` reads it back)."""
    write_npz(path, {name: getattr(log, name) for name in LOG_ARRAYS})


def read_log(path: str | Path, row: dict[str, Any]) -> FlightLog:
    """The log ``write_log`` wrote, with its ``flight_metrics`` ``row`` for the rest."""
    with np.load(path) as z:
        arrays = [z[name] for name in LOG_ARRAYS]
    return FlightLog(row["maneuver"], row["seed"], row["controller"], row["planned_steps"],
                     *arrays, row["stopped"])  # fmt: skip


def flight_metrics(log: FlightLog, limits: InputLimits, cable_length: float) -> dict[str, Any]:
    """Scores of the recorded part (t >= 0) of a flight (see the module)."""
    rec = log.t >= -1e-9
    x, p_ref, u = log.states[rec], log.p_ref[rec], log.inputs[rec]
    load_ref = p_ref - np.array([0.0, 0.0, cable_length])
    swing = np.degrees(swing_angle(x)) if len(x) else np.zeros(0)
    compute = log.compute * 1e3

    def rms(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean(a))) if a.size else math.nan

    at_limit = [limits.at_limit(row) for row in u]
    return {
        "maneuver": log.maneuver,
        "seed": log.seed,
        "controller": log.controller,
        "completed": log.stopped is None,
        "stopped": log.stopped,
        "steps": int(rec.sum()),
        "planned_steps": log.planned_steps,
        "vehicle_rmse": rms(np.sum((x[:, POS] - p_ref) ** 2, axis=1)),
        "load_rmse": rms(np.sum((x[:, LOAD_POS] - load_ref) ** 2, axis=1)),
        "swing_rms": rms(swing**2),
        "swing_max": float(swing.max()) if swing.size else math.nan,
        "at_limit": 100.0 * float(np.mean(at_limit)) if at_limit else math.nan,
        "compute_median": float(np.median(compute)) if compute.size else math.nan,
        "compute_p99": float(np.percentile(compute, 99)) if compute.size else math.nan,
        **{k: v for k, v in log.stats.items()},
    }


COST_TERMS = {  # the groups of a flight's MPC cost: name -> the MPCConfig weights it sums
    "vehicle": ("w_position",),
    "velocity": ("w_velocity",),
    "load": ("w_load",),
    "swing": ("w_swing",),
    "bounds": ("w_yaw", "w_tilt", "w_swing_bound", "w_floor"),
    "inputs": ("w_thrust", "w_rates", "w_thrust_rate", "w_rates_rate"),
}


def realized_cost(
    log: FlightLog, reference: Reference, mpc: MPCConfig, params: VehicleParams
) -> dict[str, float]:
    """The MPC's own cost (``mppi.trajectory_cost`` under ``mpc``, its terminal weight left
    out) over the recorded part of a flown log, against the flight's whole reference
    (``sim.flight.flight_reference``, row k at control step k): "total" and each group of
    ``COST_TERMS``. What an MPC with a perfect model minimises, so how near a flight came to
    it, whatever the controller; ``params``: the cable length and hover thrust of the cost."""
    rec = np.flatnonzero(log.t >= -1e-9)
    if rec.size == 0 or rec[0] == 0:
        raise ValueError(f"{log.controller} {log.maneuver} s{log.seed}: no warm-up or no record")
    swing = (params.cable_length, params.gravity, params.dt)  # as the controller reads it
    ref = reference_rows(reference, rec, lean_rows(mpc, *swing), shape_of(mpc, *swing))
    x, u = log.states[rec][None], log.inputs[rec][None]
    hover = (params.mass_quad + params.mass_load) * params.gravity
    target = cost_target(mpc, ref, params.cable_length, params.gravity)
    weights = [w for ws in COST_TERMS.values() for w in ws]
    out = {}
    for name, ws in COST_TERMS.items():
        only = replace(mpc, terminal=0.0, **{w: getattr(mpc, w) if w in ws else 0.0
                                              for w in weights})  # fmt: skip
        cost = trajectory_cost(x, u, ref, log.inputs[rec[0] - 1], only, params.cable_length, hover,
                               target)  # fmt: skip
        out[name] = float(cost[0])
    out["total"] = sum(out.values())
    return out
