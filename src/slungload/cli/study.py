"""Study commands: study data|size|loads|control|control-loads, and tune. Each study is the
lab's (``lab.study``, ``lab.control``); every default is read from its config."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..lab.study.config import DataStudyConfig, LoadsStudyConfig, SizeStudyConfig
from .common import (
    add_cluster_option,
    backends_help,
    choices,
    comma_ints,
    comma_names,
    given,
    joined,
    load_range,
    new_command,
    seed_range,
)
from .study_control import add_study_control, add_study_control_loads, add_study_plan_errors


def add_study(sub: Any) -> None:
    p = new_command(
        sub,
        "study",
        "the studies: where physics-informed training helps, network size, many loads, and "
        "the MPC in closed loop",
        "`study data`: RMSE against the number of training flights. `study size`: validation "
        "RMSE against the MPC's batched rollout time, per network size. `study loads`: one "
        "model for many loads. `study control`: where the learned model pays in the MPC "
        "(the PID, the geometric controller, the physics, learned and oracle MPCs, horizons, "
        "shifted plants). `study control-loads`: the MPC flying loads its model never saw. "
        "Each writes its report (data.md, size.md, loads.md, study.md, control-loads.md) and "
        "keeps what it finished, so an interrupted study can be re-run.",
    )
    kinds = p.add_subparsers(dest="study", metavar="STUDY", required=True)
    _add_study_data(kinds)
    _add_study_size(kinds)
    _add_study_loads(kinds)
    add_study_control(kinds)
    add_study_control_loads(kinds)
    add_study_plan_errors(kinds)


def _add_training_options(p: argparse.ArgumentParser, cfg: Any, seeds_help: str) -> None:
    """``--seeds``, ``--preset`` (and ``--epochs`` where ``cfg`` has it), ``--workers``,
    ``--cluster`` and ``--quiet``: how a study trains, its defaults read from ``cfg``."""
    p.add_argument(
        "--seeds",
        metavar="SEEDS",
        help=f"{seeds_help}: N, A..B or A,B (default {joined(cfg.seeds)})",
    )
    p.add_argument("--preset", choices=choices("presets"),
                   help=f"training schedule (default {cfg.preset})")  # fmt: skip
    if hasattr(cfg, "epochs"):
        p.add_argument(
            "--epochs",
            type=int,
            help="epochs in place of the preset's (its schedule fitted to them)",
        )
    p.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    add_cluster_option(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _training_changes(args: argparse.Namespace) -> dict[str, Any]:
    """The training options given, as a study config's changes."""
    return given(seeds=None if args.seeds is None else seed_range(args.seeds),
                 preset=args.preset, epochs=getattr(args, "epochs", None))  # fmt: skip


def _add_study_data(kinds: Any) -> None:
    cfg = DataStudyConfig()
    d = kinds.add_parser(
        "data",
        help="RMSE against the number of training flights",
        description="Train each loss variant on nested subsets of the training flights "
        f"(validation and test flights fixed) and plot the RMSE at N = {cfg.horizon} against "
        "the number of training flights. Writes data.md, data.csv and data.png into OUT.",
    )
    d.add_argument("--out", required=True, type=Path, help="output folder")
    d.add_argument("--flights", type=comma_ints, metavar="K,K",
                   help=f"training-flight counts (default {joined(cfg.flights)}); the simulated "
                   "dataset is sized for the largest")  # fmt: skip
    d.add_argument("--data", type=Path, help="dataset folder (default: simulate one)")
    d.add_argument("--variants", type=comma_names, metavar="V,V",
                   help=f"loss variants (default {','.join(cfg.variants)})")  # fmt: skip
    d.add_argument("--models", type=comma_names, metavar="NAME,NAME",
                   help=f"architectures (default {','.join(cfg.architectures)})")  # fmt: skip
    _add_training_options(d, cfg, "training seeds")
    d.set_defaults(func=cmd_study_data)


def cmd_study_data(args: argparse.Namespace) -> int:
    from ..lab.study import study_data

    changes = _training_changes(args) | given(
        flights=args.flights and tuple(args.flights),
        variants=args.variants and tuple(args.variants),
        architectures=args.models and tuple(args.models),
    )
    config = replace(DataStudyConfig(), **changes)
    study_data(out=args.out, config=config, data=args.data, workers=args.workers,
               cluster=args.cluster, progress=not args.quiet)  # fmt: skip
    print(args.out / "data.md")
    return 0


def _add_study_size(kinds: Any) -> None:
    from ..config import MODEL_SIZES

    cfg = SizeStudyConfig()
    s = kinds.add_parser(
        "size",
        help=f"validation RMSE at N = {cfg.horizon} against the MPC's batched rollout time, per "
        "network size",
        description="Train reproduce's best configuration (physics-step, no-physics, mixed step "
        "weighting, N = 50, smoothed load estimate) at each named network size, evaluate it on "
        f"the validation flights at N = {cfg.horizon}, time one batched rollout in the MPC's "
        "shape (K plans of N steps, one torch thread) and train the sizes on the Pareto front "
        "with more seeds. Writes size.md, size.csv, timing.csv and size.png into OUT; finished "
        "runs are kept, so an interrupted study can be re-run.",
    )
    s.add_argument("--data", required=True, type=Path,
                   help="dataset folder (for control: excited flights)")  # fmt: skip
    s.add_argument("--out", required=True, type=Path, help="output folder")
    s.add_argument("--sizes", type=comma_names, metavar="NAME,NAME",
                   help="network sizes: "
                   + "; ".join(f"{n} ({size.summary()})" for n, size in MODEL_SIZES.items())
                   + f" (default {','.join(cfg.sizes)})")  # fmt: skip
    s.add_argument("--front-seeds", metavar="SEEDS",
                   help=f"further seeds of the sizes on the Pareto front (default "
                   f"{joined(cfg.front_seeds)}; 'none': no more)")  # fmt: skip
    s.add_argument("--samples", type=int, metavar="K", help=f"plans (default {cfg.samples})")
    s.add_argument("--steps", type=int, metavar="N", help=f"plan steps (default {cfg.steps})")
    s.add_argument("--repeats", type=int, help=f"timed rollouts (default {cfg.repeats})")
    s.add_argument("--backend", choices=choices("backends"),
                   help=f"what the rollouts are timed on: {backends_help()} (default "
                   f"{cfg.backend})")  # fmt: skip
    s.add_argument("--no-train", action="store_true",
                   help="train nothing: evaluate and time the finished runs (re-time on a quiet "
                   "machine, or report a study cut short)")  # fmt: skip
    _add_training_options(s, cfg, "every size's seeds")
    s.set_defaults(func=cmd_study_size)


def cmd_study_size(args: argparse.Namespace) -> int:
    from ..lab.study import study_size

    changes = _training_changes(args) | given(
        sizes=args.sizes and tuple(args.sizes),
        samples=args.samples, steps=args.steps, repeats=args.repeats, backend=args.backend,
    )  # fmt: skip
    if args.front_seeds is not None:  # "none": no further seeds, an empty tuple
        none = args.front_seeds.strip() == "none"
        changes["front_seeds"] = () if none else seed_range(args.front_seeds)
    config = replace(SizeStudyConfig(), **changes)
    study_size(data=args.data, out=args.out, config=config, workers=args.workers,
               cluster=args.cluster, train=not args.no_train, progress=not args.quiet)  # fmt: skip
    print(args.out / "size.md")
    return 0


def _add_study_loads(kinds: Any) -> None:
    from dataclasses import fields

    from ..lab.study.config import NETWORK_ROWS, PHYSICS_ROWS, RANGES

    cfg = LoadsStudyConfig()
    s = kinds.add_parser(
        "loads",
        help="one model for many loads: unseen loads inside and beyond the training range",
        description="Simulate flights of one load, of loads drawn from a range and of loads "
        "beyond it; train the physics-step network (reproduce's best configuration) on "
        + "; ".join(
            f"{label!r}: {data} flights, f with the {c} constants"
            + (", its correction seeing them" if seeing else "")
            for label, (data, c, seeing) in NETWORK_ROWS.items()
        )  # fmt: skip
        + "; compare with physics run with "
        + ", ".join(f"the {c} constants ({label!r})" for label, c in PHYSICS_ROWS.items())
        + " on unseen loads inside the range (the test flights) and beyond it (every flight). "
        "Writes loads.md, loads.csv, flights.csv, loads.png and the evaluation reports "
        "inside/ and beyond/ into OUT; datasets and finished runs are kept, so an "
        "interrupted study can be re-run.",
    )
    s.add_argument("--out", required=True, type=Path, help="output folder")
    for f in fields(LoadsStudyConfig):
        if f.name in RANGES:
            low, high = getattr(cfg, f.name)
            s.add_argument(f"--{f.name.replace('_', '-')}", type=load_range, metavar="LO:HI",
                           help=f"{f.metadata['text']}, {f.metadata['unit']} (default "
                           f"{low:g}:{high:g})")  # fmt: skip
    s.add_argument("--flights", type=int,
                   help=f"flights of one load and of many (default {cfg.flights})")  # fmt: skip
    s.add_argument("--beyond-flights", type=int,
                   help=f"flights beyond the range (default {cfg.beyond_flights})")  # fmt: skip
    s.add_argument("--size", choices=choices("sizes"),
                   help=f"network size (default {cfg.size})")  # fmt: skip
    s.add_argument("--sim-seed", type=int, help=f"simulation seed (default {cfg.sim_seed})")
    _add_training_options(s, cfg, "training seeds")
    s.set_defaults(func=cmd_study_loads)


def cmd_study_loads(args: argparse.Namespace) -> int:
    from ..lab.study import study_loads
    from ..lab.study.config import RANGES

    changes = _training_changes(args) | given(
        flights=args.flights, beyond_flights=args.beyond_flights, size=args.size,
        sim_seed=args.sim_seed, **{name: getattr(args, name) for name in RANGES},
    )  # fmt: skip
    config = replace(LoadsStudyConfig(), **changes)
    study_loads(out=args.out, config=config, workers=args.workers, cluster=args.cluster,
                progress=not args.quiet)  # fmt: skip
    print(args.out / "loads.md")
    return 0


def add_tune(sub: Any) -> None:
    from ..lab.study.config import SearchSpace, TuneSettings

    space, settings = SearchSpace(), TuneSettings()
    p = new_command(
        sub,
        "tune",
        "search for the training configuration that suits a dataset (Ray Tune)",
        "A configuration search on the validation flights: Optuna's TPE proposes trials over "
        + "; ".join(
            f"{name} {'/'.join(map(str, getattr(space, name)))}"
            for name in (
                "architecture",
                "variant",
                "steps",
                "horizon",
                "load_estimate",
                "size",
                "batch_size",
            )
        )  # fmt: skip
        + f"; learning rate {space.lr[0]:g}-{space.lr[1]:g} (log-uniform), the first trial "
        "being reproduce's configuration; ASHA stops poor trials early on each epoch's "
        "validation loss; a finished trial scores combined RMSE at N = 50 on the validation "
        "flights, mean of two seeds. Writes trials.csv, tune.md, tune.png and best.toml "
        "(`slungload train --config best.toml` retrains the winner). Needs Ray (pip install "
        "'slungload[cluster]'); docs/cluster.md.",
    )
    p.add_argument("--data", required=True, type=Path, help="dataset folder")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--trials", type=int, default=settings.trials,
                   help=f"trials (default {settings.trials})")  # fmt: skip
    p.add_argument(
        "--preset", default=settings.preset, choices=choices("presets"),
        help=f"the search budget's schedule (default {settings.preset})",
    )  # fmt: skip
    p.add_argument("--epochs", type=int, default=settings.epochs,
                   help=f"epochs per trial, the preset's schedule fitted to them (default "
                   f"{settings.epochs})")  # fmt: skip
    p.add_argument(
        "--final-preset", default=settings.final_preset, choices=choices("presets"),
        help=f"best.toml's schedule, what the winner retrains with (default "
        f"{settings.final_preset})",
    )  # fmt: skip
    p.add_argument(
        "--concurrent", type=int, default=settings.concurrent,
        help=f"trials at a time, one CPU each (default {settings.concurrent})",
    )  # fmt: skip
    p.add_argument(
        "--cluster", default="local", metavar="ADDRESS",
        help="where the trials run: local (a Ray instance on this machine; the default), auto "
        "(the cluster RAY_ADDRESS names) or ray://HOST:PORT; the dataset and OUT on storage "
        "every node sees",
    )  # fmt: skip
    p.set_defaults(func=cmd_tune)


def cmd_tune(args: argparse.Namespace) -> int:
    from ..lab.study.config import TuneSettings
    from ..lab.study.tune import run_tune

    settings = replace(TuneSettings(), trials=args.trials, preset=args.preset, epochs=args.epochs,
                       final_preset=args.final_preset, concurrent=args.concurrent)  # fmt: skip
    run_tune(args.data, args.out, settings, cluster=args.cluster)
    print(args.out / "tune.md")
    return 0
