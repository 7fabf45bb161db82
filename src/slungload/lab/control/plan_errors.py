"""Each model's errors along the plans the MPC weighs, against the plant's own responses.

A model that predicts logged flights well can still mislead an MPC: the MPC compares candidate
input sequences that no logged flight holds, and what matters is whether the model ranks them
as the plant would. ``plan_errors`` flies an MPC (over the physics or the learned model) in the
simulator and, every ``every`` control steps, takes the first ``candidates`` plans it is about
to weigh (row 0: its nominal plan), flies them on copies of the plant from its true state
(``plant_batch.lookahead``: the oracle's look-ahead, with the wind held) and has every model
predict them from the measured history. Per model it records

- the load position error along the plans, per horizon step (m);
- the error of the *response to the input change*: each plan's predicted outcome minus the
  nominal plan's against the same difference flown, per step (m); a bias common to all plans
  cancels here, as it does in the MPC's weighting;
- how the model ranks the plans under the MPC's own cost (``mppi.trajectory_cost``): the
  Spearman correlation of predicted and flown costs, and the regret of picking the plan the
  model scores best, as a share of the flown costs' spread (mean - min).

``slungload study plan-errors`` writes them (``plan-errors.md``, ``.csv``, ``.png``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...config import VehicleParams
from ...control.closed_loop import fly
from ...control.history import history_tail
from ...control.mpc import InputLimits, MPCConfig, SamplingMPC, candidate_model
from ...control.mppi import CandidateModel, knots_for, trajectory_cost
from ...layout import LOAD_POS, POS, QUAT, STATE_DIM, VEL
from ...sim.controller import Measurement
from ...sim.maneuvers import Reference
from .config import LEARNED, PlanErrorConfig
from .plant_batch import lookahead


@dataclass
class ProbeRecord:
    """What one model showed over the probes: per probe, load errors (N,) and response errors
    (N,) as mean squares over the candidates, the rank correlation and the regret."""

    load_sq: list[np.ndarray] = field(default_factory=list)
    response_sq: list[np.ndarray] = field(default_factory=list)
    spearman: list[float] = field(default_factory=list)
    regret: list[float] = field(default_factory=list)


def _ranks(a: np.ndarray) -> np.ndarray:
    order = np.argsort(a, kind="stable")
    ranks = np.empty(len(a))
    ranks[order] = np.arange(len(a))
    return ranks


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Rank correlation of two (C,) arrays (no tie correction: costs are continuous)."""
    ra, rb = _ranks(a) - 0.5 * (len(a) - 1), _ranks(b) - 0.5 * (len(b) - 1)
    den = np.sqrt((ra @ ra) * (rb @ rb))
    return float(ra @ rb / den) if den > 0 else float("nan")


class Probe:
    """The flying model, wrapped (a numpy ``CandidateModel``): it answers the MPC with the
    flying model's predictions and, at the probed steps, also flies the first candidates on
    the plant and scores every model's predictions of them (``ProbeRecord`` per model)."""

    numpy = True

    def __init__(
        self, flying: str, models: Mapping[str, CandidateModel], cfg: PlanErrorConfig,
        mpc: MPCConfig,
    ) -> None:  # fmt: skip
        self.flying = flying
        self.models = models
        self.name = models[flying].name
        self.history = max(m.history for m in models.values())
        self.cfg, self.mpc = cfg, mpc
        self.records = {name: ProbeRecord() for name in models}
        self.batch = None
        self.probe_now = False
        self.core = None  # the MPC's core (its cost's constants), set by ``ProbedMPC``
        self.reference = None

    def attach(self, plant) -> None:
        self.batch = lookahead(plant)
        for model in self.models.values():  # a model that predicts with the plant (the oracle)
            attach = getattr(model, "attach", None)
            if attach is not None:
                attach(plant)

    def _predict(self, name: str, x_hist, u_past, plans) -> np.ndarray:
        model = self.models[name]
        return model.predict_candidates(*history_tail(x_hist, u_past, model.history), plans)

    def predict_candidates(self, x_hist, u_past, plans) -> np.ndarray:
        out = self._predict(self.flying, x_hist, u_past, plans)
        if self.probe_now:
            self._probe(x_hist, u_past, plans[: self.cfg.candidates])
        return out

    def _probe(self, x_hist, u_past, plans) -> None:
        plant = self.batch.plant
        flown = self.batch.advance(plans, plant.wind)
        truth = np.empty((*plans.shape[:2], STATE_DIM))
        truth[..., POS], truth[..., VEL] = flown["p"], flown["v"]
        truth[..., QUAT], truth[..., LOAD_POS] = flown["q"], flown["p_load"]
        core = self.core
        target = core.target(self.reference)

        def cost(states: np.ndarray) -> np.ndarray:
            return trajectory_cost(states, plans, self.reference, core.u_prev, self.mpc,
                                   core.cable_length, core.hover_thrust, target)  # fmt: skip

        true_cost = cost(truth)
        spread = float(true_cost.mean() - true_cost.min())
        load_true = truth[..., LOAD_POS]
        for name, record in self.records.items():
            pred = np.asarray(self._predict(name, x_hist, u_past, plans), dtype=float)
            load = pred[..., LOAD_POS]
            record.load_sq.append(np.square(load - load_true).sum(-1).mean(0))
            moved = (load - load[:1]) - (load_true - load_true[:1])
            record.response_sq.append(np.square(moved[1:]).sum(-1).mean(0))
            c = cost(pred)
            record.spearman.append(spearman(c, true_cost))
            pick = int(np.argmin(np.where(np.isfinite(c), c, np.inf)))
            gap = float(true_cost[pick] - true_cost.min())
            record.regret.append(gap / spread if spread > 0 else 0.0)


class ProbedMPC:
    """A ``SamplingMPC`` over a ``Probe``: it tells the probe the reference ahead and when to
    probe (every ``every`` recorded steps), then steps as usual (a ``Controller``)."""

    def __init__(self, probe: Probe, limits: InputLimits, params: VehicleParams, warm: int):
        self.probe = probe
        self.mpc = SamplingMPC(probe, limits, probe.mpc, params)
        probe.core = self.mpc.core
        self.warm = warm

    def attach(self, plant) -> None:
        self.probe.attach(plant)

    def __call__(self, measurement: Measurement, reference: Reference, k: int):
        i = k - self.warm
        self.probe.probe_now = i >= 0 and i % self.probe.cfg.every == 0
        self.probe.reference = self.mpc.core.ahead(reference, k)
        return self.mpc(measurement, reference, k)

    @property
    def stats(self):
        return self.mpc.stats


def plan_errors(
    models: Mapping[str, Any],
    flying: str,
    plant_cfg,
    params: VehicleParams,
    mpc: MPCConfig,
    cfg: PlanErrorConfig | None = None,
    *,
    progress: Callable[[str], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Fly the MPC over ``models[flying]`` on the plant ``plant_cfg`` (a ``SimConfig``) for
    every maneuver x seed of ``cfg`` with the settings ``mpc`` (its horizon and K are
    ``cfg``'s) and probe every model of ``models`` (name -> a torch ``PredictionModel`` or a
    numpy ``CandidateModel``) along its plans. Returns per model: ``load`` and ``response``
    (N,) RMS errors per horizon step (m), ``spearman`` and ``regret`` (means over the probes),
    and ``probes`` (their count)."""
    cfg = cfg or PlanErrorConfig()
    numpy_models = {name: candidate_model(m) for name, m in models.items()}
    mpc = MPCConfig(**{**mpc.__dict__, "horizon": cfg.horizon, "samples": cfg.samples,
                       "knots": knots_for(cfg.horizon)})  # fmt: skip
    limits = InputLimits.from_sim(plant_cfg)
    warm = round(plant_cfg.warmup / plant_cfg.control_dt)
    totals = {name: ProbeRecord() for name in models}
    for maneuver in cfg.maneuvers:
        for seed in cfg.seeds:
            probe = Probe(flying, numpy_models, cfg, MPCConfig(**{**mpc.__dict__, "seed": seed}))
            log = fly(maneuver, seed, ProbedMPC(probe, limits, params, warm), label="probe",
                      config=plant_cfg, steps=cfg.steps)  # fmt: skip
            for name, record in probe.records.items():
                for key in ("load_sq", "response_sq", "spearman", "regret"):
                    getattr(totals[name], key).extend(getattr(record, key))
            if progress:
                done = "ok" if log.stopped is None else f"STOPPED: {log.stopped}"
                progress(f"{maneuver} s{seed} ({flying} MPC): "
                         f"{len(probe.records[flying].spearman)} probes ({done})")  # fmt: skip
    return {
        name: {
            "load": np.sqrt(np.mean(r.load_sq, axis=0)),
            "response": np.sqrt(np.mean(r.response_sq, axis=0)),
            "spearman": float(np.nanmean(r.spearman)),
            "regret": float(np.mean(r.regret)),
            "probes": len(r.spearman),
        }
        for name, r in totals.items()
    }


def run_plan_errors(
    learned: str | Path | None,
    out: str | Path,
    config: PlanErrorConfig | None = None,
    *,
    progress: Callable[[str], None] | None = print,
) -> Path:
    """``plan_errors`` of the physics model and the ``learned`` run (None: physics alone)
    along the plans of each MPC of ``config.flying``, on ``config.plant``; the report in
    ``out`` (``write_plan_errors``)."""
    from ...deploy.backends import load_model
    from ...models.prediction import PHYSICS
    from ...sim.config import vehicle_params
    from ...sim.plants import plant_config

    cfg = config or PlanErrorConfig()
    nominal = plant_config(cfg.plant)
    params = vehicle_params(nominal)
    models = {PHYSICS: load_model(PHYSICS, params, backend=cfg.backend)}
    if learned is not None:
        models[LEARNED] = load_model(learned, backend=cfg.backend)
    missing = [f for f in cfg.flying if f not in models]
    if missing:
        raise ValueError(f"the {', '.join(missing)} MPC needs a learned model (--model)")
    results = {flying: plan_errors(models, flying, nominal, params, MPCConfig(), cfg,
                                   progress=progress)
               for flying in cfg.flying}  # fmt: skip
    title = (f"Plan-wise errors on the {cfg.plant} plant, N = {cfg.horizon}, K = {cfg.samples}, "
             f"{len(cfg.maneuvers)} maneuvers x {len(cfg.seeds)} seeds")  # fmt: skip
    return write_plan_errors(results, out, title)


def write_plan_errors(
    results: Mapping[str, Mapping[str, dict[str, Any]]], out: str | Path, title: str
) -> Path:
    """``plan-errors.md``, ``.csv`` and ``.png`` in ``out``: per flying MPC and model, the
    errors at steps 1, 5, 10 and N, the rank correlation and the regret. ``results``: flying
    model -> ``plan_errors`` output."""
    from ...fileio import write_text
    from ...reporting import write_csv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for flying, per_model in results.items():
        for name, r in per_model.items():
            n = len(r["load"])
            picks = sorted({1, 5, 10, n} & set(range(1, n + 1)))
            rows.append({"mpc": flying, "model": name, "probes": r["probes"],
                         **{f"load_{s}": r["load"][s - 1] for s in picks},
                         **{f"response_{s}": r["response"][s - 1] for s in picks},
                         "spearman": r["spearman"], "regret": r["regret"]})  # fmt: skip
    heads = list(rows[0])
    write_csv(out / "plan-errors.csv", heads, [list(row.values()) for row in rows])
    lines = [f"# {title}", "", "Load position errors along the plans the MPC weighs (m, RMS "
             "over the probed candidates), the error of each plan's response to its input "
             "change against the nominal plan's (m), the Spearman correlation of predicted and "
             "flown costs, and the regret of the model's best-scored plan (share of the flown "
             "costs' spread); `lab/control/plan_errors.py`.", "",
             "| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]  # fmt: skip
    for row in rows:
        cells = [f"{v:.3f}" if isinstance(v, float) else str(v) for v in row.values()]
        lines.append("| " + " | ".join(cells) + " |")
    write_text(out / "plan-errors.md", "\n".join(lines) + "\n")
    _plot(results, out / "plan-errors.png", title)
    return out / "plan-errors.md"


def _plot(results, path: Path, title: str) -> None:
    from matplotlib.figure import Figure

    from ...reporting import save_figure

    fig = Figure(figsize=(10, 3.8))
    axes = fig.subplots(1, 2, sharex=True)
    names = list(dict.fromkeys(n for per_model in results.values() for n in per_model))
    colors = {n: f"C{i}" for i, n in enumerate(names)}  # a colour per model
    styles = {f: s for f, s in zip(results, ("-", "--", ":"), strict=False)}  # a line per MPC
    for flying, per_model in results.items():
        for name, r in per_model.items():
            steps = np.arange(1, len(r["load"]) + 1)
            look = dict(color=colors[name], linestyle=styles.get(flying, "-"))
            label = f"{name} (along the {flying} MPC's plans)"
            axes[0].plot(steps, r["load"], label=label, **look)
            axes[1].plot(steps, r["response"], label=label, **look)
    axes[0].set_title("load position error along the plans")
    axes[1].set_title("error of the response to the input change")
    for ax in axes:
        ax.set_xlabel("horizon step (0.03 s)")
        ax.set_ylabel("RMS error (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)
