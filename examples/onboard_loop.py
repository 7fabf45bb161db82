"""A vehicle's own control loop around the MPC: PX4-style measurements in, commands out.

    slungload export runs/ps-exc --for-mpc --format compiled --out ps.mpc.npz   # once, where
    slungload export physics --for-mpc --format compiled --out vehicle.mpc.npz  # torch is
    python examples/onboard_loop.py ps.mpc.npz --vehicle vehicle.mpc.npz [--samples 256]

The MPC's model is any exported MPC model: a compiled one (``.mpc.npz``, numpy + Numba, as
fast as the full install's compiled backend) or a candidates graph (``.mpc.onnx``, ONNX
Runtime), a trained network's or the physics model's (``slungload export physics --for-mpc
--out physics.mpc.npz``). Every control
period h = 0.03 s (the data rate) the loop

1. reads a measurement as PX4 reports it: position and velocity in NED, attitude body (FRD)
   -> NED, and the load's position (motion capture or an estimator) in NED;
2. converts it to the package's frames with ``slungload.frames`` (world z up, FLU body) and
   packs the state x = (p, v, q w-x-y-z, pL) (``slungload.layout``);
3. takes the reference at the next N steps (positions, velocities, yaw);
4. calls ``controller.step(x, reference)``, which keeps the history itself and returns
   thrust (N) and body rates (rad/s, FLU);
5. converts the rates back to FRD and sends them with the thrust.

Everything here imports numpy, Numba or onnxruntime and the package's torch-free modules only:
it runs in the onboard install (``pip install '.[onboard]'`` from a checkout). The stand-in
vehicle below (``SimulatedVehicle``: the package's discrete model, exported and stepped one
command at a time) is what a real loop replaces with the autopilot link (MAVLink / uORB /
ROS 2 telemetry in, an attitude-rate setpoint out).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from slungload import InputLimits, MPCConfig, MPPIController, ReferenceAhead, frames
from slungload.config import VehicleParams
from slungload.deploy.backends import load_exported
from slungload.layout import LOAD_POS, POS, QUAT, VEL

H = 0.03  # s, control period (the data rate)


def reference_ahead(t: float, n: int) -> ReferenceAhead:
    """A 0.6 m move in x over 2 s (smooth), at 1.5 m height, yaw 0: rows t + h ... t + N h."""
    times = t + H * np.arange(1, n + 1)
    s = np.clip(times / 2.0, 0.0, 1.0)
    shape, rate = 10 * s**3 - 15 * s**4 + 6 * s**5, (30 * s**2 - 60 * s**3 + 30 * s**4) / 2.0
    curve = (60 * s - 180 * s**2 + 120 * s**3) / 4.0 * (times < 2.0)  # d2 shape / dt2
    position = np.stack([0.6 * shape, np.zeros(n), np.full(n, 1.5)], axis=-1)
    velocity = np.stack([0.6 * rate, np.zeros(n), np.zeros(n)], axis=-1)
    acceleration = np.stack([0.6 * curve, np.zeros(n), np.zeros(n)], axis=-1)
    return ReferenceAhead(position, velocity, np.zeros(n), acceleration)  # any MPCConfig.cost


def state_from_px4(p_ned, v_ned, q_ned_frd, p_load_ned) -> np.ndarray:
    """The package's state (13,) from PX4's NED / FRD measurements."""
    return np.concatenate(
        [
            frames.world_vectors(p_ned, "ned"),
            frames.world_vectors(v_ned, "ned"),
            frames.attitudes(q_ned_frd, "ned", "frd"),
            frames.world_vectors(p_load_ned, "ned"),
        ]
    )


class SimulatedVehicle:
    """Stand-in for the autopilot link: the discrete model (an exported physics model,
    ``deploy.backends.load_exported``) stepped one command at a time (the first step of a plan
    that holds it), reporting in NED / FRD."""

    def __init__(self, path: str, params: VehicleParams) -> None:
        self.model = load_exported(path)
        p = np.array([0.0, 0.0, 1.5])
        x = np.concatenate([p, np.zeros(3), [1.0, 0, 0, 0], p - [0, 0, params.cable_length]])
        hover = (params.mass_quad + params.mass_load) * params.gravity
        m = self.model.history  # the states the model reads the load's motion from
        self.x_hist = np.repeat(x[None], m, axis=0)
        self.u_past = np.repeat([[hover, 0.0, 0.0, 0.0]], m - 1, axis=0)

    def measure(self):
        """(p NED, v NED, q FRD -> NED w-x-y-z, load position NED), as PX4 would report."""
        x = self.x_hist[-1]
        q_ned = frames.quat_multiply(frames.quat_conjugate(frames.Q_ENU_FROM_NED), x[QUAT])
        q_ned_frd = frames.quat_multiply(q_ned, frames.Q_FLU_FROM_FRD)
        to_ned = frames.world_vectors  # (x, y, z) -> (y, x, -z) is its own inverse
        return to_ned(x[POS], "ned"), to_ned(x[VEL], "ned"), q_ned_frd, to_ned(x[LOAD_POS], "ned")

    def send(self, thrust: float, rates_frd: np.ndarray) -> None:
        rates = frames.body_vectors(rates_frd, "frd")  # FRD -> FLU is its own inverse too
        u = np.array([thrust, *rates])
        plan = np.repeat(u[None, None], self.model.horizon or 1, axis=1)  # (1, N, 4)
        x = self.model.predict_candidates(self.x_hist, self.u_past, plan)[0, 0]
        self.x_hist = np.concatenate([self.x_hist[1:], x[None]])
        self.u_past = np.concatenate([self.u_past[1:], u[None]])


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="the MPC's exported model (.mpc.npz or .mpc.onnx)")
    parser.add_argument(
        "--vehicle",
        required=True,
        help="the stand-in vehicle: the physics model exported (slungload export physics "
        "--for-mpc --format compiled, or an .mpc.onnx of it with --horizon 2)",
    )
    parser.add_argument("--samples", type=int, default=256, help="K (default 256)")
    parser.add_argument("--steps", type=int, default=200, help="control steps (default 200)")
    args = parser.parse_args(argv)
    params = VehicleParams()
    hover = (params.mass_quad + params.mass_load) * params.gravity
    limits = InputLimits(0.3 * hover, 2.0 * hover, 4.0)  # N, N, rad/s: the vehicle's box
    config = MPCConfig(samples=args.samples)  # an ONNX graph's N: the file's
    mpc = MPPIController.from_file(args.model, limits, config)  # numpy + Numba or onnxruntime
    vehicle = SimulatedVehicle(args.vehicle, params)
    errors = []
    for k in range(args.steps):
        x = state_from_px4(*vehicle.measure())  # 1-2
        reference = reference_ahead(k * H, mpc.cfg.horizon)  # 3
        command = mpc.step(x, reference)  # 4
        vehicle.send(command.thrust, frames.body_vectors(command.rates, "frd"))  # 5
        errors.append(np.linalg.norm(x[POS] - reference_ahead((k - 1) * H, 1).position[0]))
    rmse = math.sqrt(np.mean(np.square(errors)))
    stats = mpc.stats
    print(
        f"{args.steps} steps, K = {mpc.cfg.samples}, N = {mpc.cfg.horizon}: vehicle RMSE "
        f"{rmse:.3f} m, fallbacks {stats.fallback_steps}, hover {stats.hover_steps}"
    )
    return rmse


if __name__ == "__main__":
    main()
