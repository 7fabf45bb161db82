"""Fly the learned MPC of several trained runs on the same validation flights and pair them:
lost flights, swings past 60 deg, and the paired differences of each run against the first.
A choice between models (e.g. before and after `record`) made here never touches the
control study's evaluation seeds. The MPC flies the learned settings of a study's
settings.json at N = --horizon (or the defaults), K = --samples.

    python examples/fly_validation_seeds.py runs/ps-small-s0 runs/rec-s0 --maneuvers xy_step \\
        --seeds 300..339 --settings study/settings.json --workers 2
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import dataclass

from slungload.cli.common import comma_names, seed_range
from slungload.control.closed_loop import flight_metrics, fly
from slungload.control.mpc import InputLimits, MPCConfig, knots_for, mpc_maker
from slungload.deploy.backends import load_model
from slungload.deploy.predictor import torch_threads
from slungload.fileio import read_json
from slungload.lab.control.config import BENCHMARK_SEEDS, NOMINAL, SHIFTS, RecordConfig
from slungload.lab.control.study import plant_config
from slungload.reporting import paired_interval
from slungload.sim.config import SimConfig, tuples_from_json, vehicle_params
from slungload.workers import run_jobs

METRICS = ("load_rmse", "swing_rms", "swing_max", "vehicle_rmse")


@dataclass(frozen=True)
class Job:
    run: str
    plant: str
    maneuver: str
    seed: int
    mpc: MPCConfig


def fly_one(job: Job) -> tuple[Job, dict]:
    nominal = SimConfig()
    plant, params, limits = (
        plant_config(job.plant),
        vehicle_params(nominal),
        InputLimits.from_sim(nominal),
    )
    with torch_threads(1):
        model = load_model(job.run, params, backend="compiled")
        mpc = mpc_maker(model, limits, job.mpc, params)(job.seed)
        log = fly(job.maneuver, job.seed, mpc, label=job.run, config=plant, steps=300)
    return job, flight_metrics(log, limits, plant.cable_length)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="trained run folders; the first is the reference")
    parser.add_argument("--maneuvers", type=comma_names, default=["xy_step"])
    parser.add_argument("--seeds", default="300..339", help="sim seeds (none of a benchmark's)")
    parser.add_argument("--plants", default=NOMINAL, help=f"';'-separated: {NOMINAL};"
                        + ";".join(SHIFTS).replace("%", "%%"))  # fmt: skip
    parser.add_argument("--settings", help="a control study's settings.json (its learned MPC)")
    parser.add_argument("--horizon", type=int, default=15)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    seeds = seed_range(args.seeds)
    taken = sorted(BENCHMARK_SEEDS.union(RecordConfig().seeds).intersection(seeds))
    if taken:
        parser.error(f"seeds {taken} are a benchmark's (evaluation or tuning) or recorded ones")
    tuned = {}
    if args.settings:  # the learned MPC's settings at this horizon
        per_horizon = read_json(args.settings)["mpc"]["learned"]
        if str(args.horizon) not in per_horizon:
            parser.error(f"{args.settings} holds the learned MPC's settings for N = "
                         f"{', '.join(per_horizon)}, not {args.horizon}")  # fmt: skip
        tuned = tuples_from_json(per_horizon[str(args.horizon)])
    mpc = MPCConfig(**tuned, horizon=args.horizon, knots=knots_for(args.horizon),
                    samples=args.samples)  # fmt: skip
    plants = [p.strip() for p in args.plants.split(";") if p.strip()]
    jobs = [Job(run, plant, m, s, mpc) for plant in plants for run in args.runs
            for m in args.maneuvers for s in seeds]  # fmt: skip
    rows: dict[tuple[str, str], dict[tuple[str, int], dict]] = {}
    for job, row in run_jobs(fly_one, jobs, workers=args.workers, desc="flights", unit="flight"):
        rows.setdefault((job.plant, job.run), {})[(job.maneuver, job.seed)] = row
    for plant in plants:
        ref = rows[(plant, args.runs[0])]
        for run in args.runs:
            mine = rows[(plant, run)]
            lost = [f"{m} {s}" for (m, s), r in sorted(mine.items()) if not r["completed"]]
            past = sum(r["swing_max"] > 60 for r in mine.values())
            done = [r for r in mine.values() if r["completed"]]
            load = statistics.fmean(r["load_rmse"] for r in done) if done else float("nan")
            print(f"{plant} {run}: lost {len(lost)} of {len(mine)} {lost}, past 60 deg {past}, "
                  f"load RMSE {load:.3f} m over the flights it finished")  # fmt: skip
            if run == args.runs[0]:
                continue
            both = [k for k in mine if mine[k]["completed"] and ref[k]["completed"]]
            for metric in METRICS:
                mean, low, high = paired_interval([mine[k][metric] - ref[k][metric] for k in both])
                print(
                    f"    - first, {metric}: {mean:+.3f} [{low:+.3f}, {high:+.3f}] "
                    f"({len(both)} pairs)"
                )


if __name__ == "__main__":
    main()
