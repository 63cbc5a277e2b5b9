"""`highway-srl falsify`: search for ego-avoidable collisions of the rule layer, and replay what it finds.

Breadth search over the batched simulator: in every chosen scene x level x nominal/adversarial, `episodes`
episodes in batches of `envs`; at each step the ego takes one of the actions the rule layer allows
(Table 1 through the profile's mappings): uniformly at random ("uniform"), the allowed action that brings
the nearest predicted contact soonest ("greedy-ttc", an adversarial ego), or ExG's draw through the MoE gate
("exg", the distribution of exploration and of scripts/shield_sweep.py); a learned ego ("learned": a DQN
rewarded for ego-avoidable collisions, trained first by experiments.adversary) comes in as `policies`.
Every collision is classified by the decision trace (experiments.collisions.DecisionTrace: kind, decision
class, ego-avoidable verdict of rules.avoidable). The report gives the episodes, the collisions by cause, the
ego-avoidable count and the 95 % upper bound on the per-episode rate of ego-avoidable collisions (3/N with
none, else the exact one-sided Clopper-Pearson bound). Each cause's first counterexample is kept as a
replayable case: the world's seed and env, the settings, and the ego's actions, which replay_case drives
again in a world of one env (env b of a batch depends only on its own seed, sim.World). The cross-entropy search over scenario
parameters (`--search ce`) is experiments/scenario_search.py; its cases also record the parameters.
"""

from __future__ import annotations

import collections
import contextlib
import math
import multiprocessing
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from highway_srl.agents.gating import explore_gate
from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, TRAFFIC_LEVELS, V_MAX_MPS
from highway_srl.experiments.collisions import DecisionTrace
from highway_srl.experiments.runs import check_output_folder, provenance, read_json, write_json
from highway_srl.experiments.scenario_params import check_parameters, scenario_world
from highway_srl.interrupts import held, quiet_worker
from highway_srl.rules import ACTIONS, FASTER, IDLE, LANE_CHANGE, SLOWER, SafetyLayer, control_profile
from highway_srl.scenarios import check_scenario
from highway_srl.sim import World

POLICIES = ("uniform", "greedy-ttc", "exg")
LEARNED = "learned"  # an ego trained first (experiments.adversary), handed to falsify as `policies`
NO_CONTACT_S = 1e6  # a predicted time to collision when nothing closes in


@dataclass
class FalsifySettings:
    scenes: tuple[str, ...] = ("two-lane",)
    levels: tuple[str, ...] = tuple(TRAFFIC_LEVELS)
    modes: tuple[bool, ...] = (False, True)  # adversarial off, on
    profile: str = "safe"
    policy: str = "uniform"
    episodes: int = 256  # per scene, level and mode
    envs: int = 256
    seed: int = 0
    steps: int = 320  # episode length
    adversary: str = "paper"

    def check(self) -> None:
        for scene in self.scenes:
            check_scenario(scene)
        for level in self.levels:
            if level not in TRAFFIC_LEVELS:
                raise ValueError(f"unknown traffic level {level!r}; choose from {', '.join(TRAFFIC_LEVELS)}")
        control_profile(self.profile)
        if self.policy not in (*POLICIES, LEARNED):
            raise ValueError(f"unknown policy {self.policy!r}; choose one of {', '.join((*POLICIES, LEARNED))}")
        for name in ("episodes", "envs", "steps"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.seed < 0:
            raise ValueError(f"seed must be non-negative, got {self.seed}")


@dataclass
class Case:
    """One counterexample: enough to drive the same episode again (replay_case)."""

    scene: str
    level: str
    adversarial: bool
    adversary: str
    profile: str
    seed: int  # the batch's world seed; the episode's own seed is seed + env
    env: int
    steps: int
    actions: list[int]  # the ego's actions (indices into ACTIONS), the last one led to the collision
    cause: str
    ego_avoidable: bool
    record: dict = field(default_factory=dict)  # the decision trace's record of the collision
    # scenario parameters set on the spawned world (experiments/scenario_params.py); {}: the spawn as drawn
    parameters: dict = field(default_factory=dict)


# what load_case accepts in each field of a case file (Case's annotations, checked at run time)
CASE_TYPES = {"scene": str, "level": str, "adversarial": bool, "adversary": str, "profile": str, "seed": int,
              "env": int, "steps": int, "actions": list, "cause": str, "ego_avoidable": bool, "record": dict,
              "parameters": dict}
CASE_TYPE_WORDS = {str: "a string", bool: "true or false", int: "an integer", list: "a list", dict: "an object"}


class AllowedActions:
    """What DecisionTrace reads of a method: the action names and the safe mask (the rule layer's own)."""

    action_names = ACTIONS

    @staticmethod
    def safe_mask(model) -> torch.Tensor:
        return model.mask


def choose(policy: str, view, generator: torch.Generator) -> torch.Tensor:
    """(B,) action indices among the allowed actions of view (a SafetyStep; its primary model), by `policy`
    (POLICIES)."""
    model = view.primary
    mask = model.mask
    if policy == "exg":
        return explore_gate(mask, generator)[0]
    if policy == "uniform":
        u = torch.rand(mask.shape, generator=generator, device=mask.device)
        return torch.where(mask, u, -1.0).argmax(1)
    score = torch.where(mask, predicted_ttc(model, view.snapshot.ego_vx), 2 * NO_CONTACT_S)
    return score.argmin(1)  # ties (nothing closing) go to the first: Faster, the most aggressive


def predicted_ttc(model, v: torch.Tensor) -> torch.Tensor:
    """(B, 4) time (s) to the nearest contact after each action from the ego's speed v (B,), at constant
    speeds from the next step:
    Faster, Idle, Slower against SV1 ahead (Slower also SV3 behind), LaneChange against SV2 ahead and SV4
    behind in the other lane. NO_CONTACT_S where nothing closes in."""
    g, sv = model.gaps_m, model.vehicles.vx
    faster = (v + EGO_ACCEL_MAX_MPS2 * DT_S).clamp(max=V_MAX_MPS)
    slower = (v - EGO_BRAKE_MAX_MPS2 * DT_S).clamp(min=0.0)

    def ttc(gap, closing):
        return torch.where(closing > 1e-6, gap.clamp(min=0.0) / closing.clamp(min=1e-6), NO_CONTACT_S)

    ahead = lambda speed: ttc(g[:, 0], speed - sv[:, 0])  # noqa: E731
    behind = lambda speed, k: ttc(g[:, k], sv[:, k] - speed)  # noqa: E731
    change = torch.minimum(ttc(g[:, 1], v - sv[:, 1]), behind(v, 3))
    return torch.stack([ahead(faster), ahead(v), torch.minimum(ahead(slower), behind(slower, 2)), change], 1)


def drive(world, layer, pick, trace: DecisionTrace, limit: int | None = None):
    """Drive one episode in every env of world through layer, pick(step, view) -> (B,) actions, recording
    the collisions in trace; returns (actions (B, steps) long, collided (B,), changed_lane (B,))."""
    b = world.num_envs
    steps = world.max_steps if limit is None else min(limit, world.max_steps)
    actions = torch.zeros(b, steps, dtype=torch.long)
    alive, collided = torch.ones(b, dtype=torch.bool), torch.zeros(b, dtype=torch.bool)
    changed, start_lane = torch.zeros(b, dtype=torch.bool), world.ego_lane.clone()
    view = layer.observe(world)
    for step in range(steps):
        action = pick(step, view)
        actions[:, step] = action
        events = world.step(*layer.act(action))
        trace(view, _Step(_Decision(action), events), alive)
        trace.after_step(world, events, alive)
        collided |= alive & events.collision
        changed |= alive & (world.ego_lane != start_lane)
        alive &= ~(events.terminated | events.truncated)
        if not bool(alive.any()):
            break
        view = layer.observe(world)
    return actions, collided, changed


@dataclass
class _Decision:
    action: torch.Tensor
    use_second: None = None


@dataclass
class _Step:
    decision: _Decision
    events: object


def sweep_batch(scene: str, level: str, adversarial: bool, settings: FalsifySettings, seed: int, envs: int,
                pick=None, **layer_options) -> tuple[dict, list[Case]]:
    """One batch of `envs` episodes (world seed `seed`): its counts and one Case per collision. pick(view,
    generator) -> (B,) actions: the ego (None: choose by settings.policy)."""
    world = World(scene, level, adversarial, envs, "cpu", seed, max_steps=settings.steps,
                  adversary=settings.adversary)
    layer = SafetyLayer(world.road, profile=settings.profile, **layer_options)
    gen = torch.Generator().manual_seed(seed)
    trace = DecisionTrace(AllowedActions())
    pick = pick or (lambda view, g: choose(settings.policy, view, g))
    actions, collided, changed = drive(world, layer, lambda step, view: pick(view, gen), trace)
    return batch_counts(trace, collided, changed), batch_cases(world, settings, seed, actions, trace)


def batch_counts(trace: DecisionTrace, collided: torch.Tensor, changed: torch.Tensor) -> dict:
    """A driven batch's counts: episodes, collisions, lane changes, by kind, by decision class, verdicts."""
    return {"episodes": collided.shape[0], "collisions": int(collided.sum()), "changed_lane": int(changed.sum()),
            "by_kind": dict(collections.Counter(rec["kind"] for rec in trace.records)),
            "by_decision": trace.counts(), **trace.verdicts()}


def batch_cases(world, settings: FalsifySettings, seed: int, actions: torch.Tensor, trace: DecisionTrace) -> list[Case]:
    """One Case per collision the trace recorded in a driven batch of world (world seed `seed`)."""
    return [Case(world.scenario, world.traffic, world.adversarial, settings.adversary, settings.profile, seed,
                 rec["env"], settings.steps, actions[rec["env"], :rec["step"] + 1].tolist(), cause_of(rec),
                 rec["ego_avoidable"], rec)
            for rec in trace.records]


def cause_of(record: dict) -> str:
    """A collision's cause: its kind, the decision class and the verdict's reason."""
    return f"{record['kind']}; {record['class']}; {record['reason']}"


def rate_upper_bound(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided upper confidence bound on a per-episode rate from k events in n episodes: 3/n for k = 0
    (the rule of three, -ln 0.05 = 3.0), else the exact Clopper-Pearson bound, the p with
    P(Binomial(n, p) <= k) = 1 - confidence (bisection on the binomial CDF)."""
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n and n >= 1, got k={k}, n={n}")
    if k == 0:
        return min(1.0, 3.0 / n)
    if k == n:
        return 1.0
    lo, hi = k / n, 1.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if binomial_cdf(k, n, mid) > 1.0 - confidence else (lo, mid)
    return hi


def binomial_cdf(k: int, n: int, p: float) -> float:
    """P(Binomial(n, p) <= k), summed in log space (n up to millions)."""
    if p <= 0.0:
        return 1.0
    if p >= 1.0:
        return 0.0 if k < n else 1.0
    log_p, log_q = math.log(p), math.log1p(-p)
    terms = [math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1) + i * log_p + (n - i) * log_q
             for i in range(k + 1)]
    top = max(terms)
    return min(1.0, math.exp(top) * sum(math.exp(t - top) for t in terms))


def add_counts(total: dict, part: dict) -> dict:
    """total + part for dicts of counts (nested dicts of counts summed key by key)."""
    for key, value in part.items():
        if isinstance(value, dict):
            add_counts(total.setdefault(key, {}), value)
        else:
            total[key] = total.get(key, 0) + value
    return total


def falsify(settings: FalsifySettings, out: str | Path | None = None, progress=None, processes: int = 1,
            policies: dict | None = None) -> dict:
    """The breadth search of the module docstring; the report (dict). out: a folder for one case JSON per
    cause found (scene and cause deduplicated; the report lists them) and report.json.
    progress(done, total), if given, is called after each batch. processes: batches run in this many
    forked worker processes of one thread each (1: in this process); a batch depends only on its
    scene, level, mode and seed, and the results are merged in plan order, so the report is the same for
    any count (the unit of work is a batch: --envs below --episodes gives the workers more to share).
    policies: {scene: pick(view, generator) -> (B,) actions}, the ego of policy "learned"
    (experiments.adversary.falsify_learned trains it)."""
    settings.check()
    trained = set(policies or {})
    if (settings.policy == LEARNED and not trained >= set(settings.scenes)) or (settings.policy != LEARNED and trained):
        raise ValueError(f"policy {LEARNED!r} and a trained ego for every scene go together (experiments.adversary)")
    check_processes(processes)
    if out is not None:
        check_report_folder(Path(out))
    plan = [(scene, adv, level) for scene in settings.scenes for adv in settings.modes for level in settings.levels]
    jobs = [(scene, level, adversarial, settings, settings.seed + start, min(settings.envs, settings.episodes - start),
             (policies or {}).get(scene))
            for scene, adversarial, level in plan for start in range(0, settings.episodes, settings.envs)]
    batches = len(jobs) // len(plan)
    cells, kept, total = [], {}, {}
    code, started = provenance(), time.monotonic()  # the code that runs is the code loaded now
    with batch_runner(processes) as run:
        for i, (counts, cases) in enumerate(run(_sweep_job, jobs)):
            if i % batches == 0:
                scene, adversarial, level = plan[i // batches]
                cells.append({"scene": scene, "level": level, "adversarial": adversarial})
            add_counts(cells[-1], counts)
            for case in cases:
                kept.setdefault((cells[-1]["scene"], case.cause), case)
            if progress is not None:
                progress(i + 1, len(jobs))
    for cell in cells:
        add_counts(total, {k: v for k, v in cell.items() if k not in ("scene", "level", "adversarial")})
    report = {"settings": asdict(settings), **total,
              "ego_avoidable_rate_upper_95": rate_upper_bound(total["ego_avoidable"], total["episodes"]),
              "cells": cells, "cases": [], **code, "processes": processes,
              "wall_s": round(time.monotonic() - started, 1)}
    if out is not None:
        report["cases"] = write_cases(Path(out), list(kept.values()))
        write_json(Path(out) / "report.json", report)
    else:
        report["cases"] = [{"cause": c.cause, "ego_avoidable": c.ego_avoidable} for c in kept.values()]
    return report


def check_processes(processes) -> None:
    if not isinstance(processes, int) or processes < 1:
        raise ValueError(f"processes must be a positive integer, got {processes!r}")


def check_report_folder(out: Path) -> None:
    """A folder falsify may write its report and cases to: writable, and without a report already."""
    check_output_folder(out)
    if (out / "report.json").exists():
        raise ValueError(f"--out {str(out)!r} already holds a falsify report; choose another folder")


def _sweep_job(job: tuple) -> tuple[dict, list[Case]]:
    return sweep_batch(*job)


@contextlib.contextmanager
def batch_runner(processes: int):
    """run(fn, jobs) -> fn(job) for each job, in the order of jobs: in this process, or in a pool of
    `processes` forked workers of one torch thread each (the order of the results is the order of jobs
    whichever worker finishes first)."""
    if processes == 1:
        yield lambda fn, jobs: map(fn, jobs)
        return
    try:
        ctx = multiprocessing.get_context("fork")
    except ValueError:
        raise ValueError("--processes needs the fork start method (Linux or macOS)") from None
    with held():  # the workers start deaf to Ctrl-C and `kill` (interrupts.py), so that ending the pool is quiet
        pool = ctx.Pool(processes, initializer=_quiet_worker_of_one_thread)
    with pool:
        yield lambda fn, jobs: pool.imap(fn, jobs)


def _quiet_worker_of_one_thread() -> None:
    """A pool worker's start: the pool's SIGTERM at its end (and Ctrl-C, the command's to report) end it
    without a word, where the handlers forked from the command would raise a traceback; one torch thread."""
    quiet_worker()
    torch.set_num_threads(1)


def write_cases(folder: Path, cases: list[Case]) -> list[dict]:
    """One JSON per case, ego-avoidable ones first; returns their paths and causes."""
    listed = []
    for n, case in enumerate(sorted(cases, key=lambda c: not c.ego_avoidable)):
        mode = "adversarial" if case.adversarial else "nominal"
        path = folder / f"case-{n:03d}-{case.scene}-{case.level}-{mode}.json"
        write_json(path, asdict(case))
        listed.append({"path": str(path), "cause": case.cause, "ego_avoidable": case.ego_avoidable})
    return listed


def load_case(path: str | Path) -> Case:
    """A case written by falsify; ValueError naming what is wrong otherwise."""
    data = read_json(Path(path))
    try:
        case = Case(**data)
    except TypeError as err:
        raise ValueError(f"{path} is not a falsify case ({err})") from None
    for name, kind in CASE_TYPES.items():
        value = getattr(case, name)
        # bool is an int to Python; a seed of true, or an adversarial flag of 1, is a damaged file all the same
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ValueError(f"{path}: {name} must be {CASE_TYPE_WORDS[kind]}, got {value!r}")
    if case.seed < 0 or case.env < 0:
        raise ValueError(f"{path}: seed and env must be non-negative, got {case.seed} and {case.env}")
    try:
        check_parameters(case.parameters)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    if not case.actions or any(type(a) is not int or not 0 <= a < len(ACTIONS) for a in case.actions):
        raise ValueError(f"{path}: actions must be a non-empty list of indices into {', '.join(ACTIONS)}")
    return case


# where a replaying profile forbids a recorded action: the most cautious allowed one instead
CAUTIOUS_ORDER = (SLOWER, IDLE, LANE_CHANGE, FASTER)


def replay_case(case: Case, profile: str | None = None, substitute: bool = False, **layer_options) -> dict:
    """Drive the case's episode again with its actions (under `profile`, default the case's own, and the
    SafetyLayer options given): whether it collides, where, whether every action was allowed, and the
    decision trace's verdict. substitute: where the profile forbids the recorded action, take the first
    allowed of CAUTIOUS_ORDER instead (how a counterexample found under one profile is put to another:
    the ego follows the recorded plan as far as the rule layer lets it); `substituted` counts them."""
    profile = profile or case.profile
    world = case_world(case)
    layer = SafetyLayer(world.road, profile=profile, **layer_options)
    recorded = torch.tensor(case.actions)
    order = torch.tensor(CAUTIOUS_ORDER)
    substituted = []

    def pick(step, view):
        action, mask = recorded[step:step + 1], view.primary.mask
        if substitute and not bool(mask[0, action[0]]):
            substituted.append(step)
            return order[mask[0, order].nonzero()[0]]
        return action

    trace = DecisionTrace(AllowedActions())
    drive(world, layer, pick, trace, limit=len(case.actions))
    rec = trace.records[0] if trace.records else None
    result = {"profile": profile, "collided": rec is not None, "step": None if rec is None else rec["step"],
              "expected_step": len(case.actions) - 1, "substituted": len(substituted)}
    if rec is not None:
        result.update(cause=cause_of(rec), ego_avoidable=rec["ego_avoidable"],
                      all_allowed=all(r["action"] in r["allowed"] for r in rec["decisions"]))
    result["confirmed"] = result["collided"] and result["step"] == result["expected_step"]
    return result


def case_world(case: Case) -> World:
    """The case's episode in a world of one env: env b of a batch depends only on its own seed (and its
    scenario parameters)."""
    return scenario_world(case.scene, case.level, case.adversarial, [case.seed + case.env], case.steps,
                          case.adversary, [case.parameters])


def render_case(case: Case, out: str | Path, profile: str | None = None, overwrite: bool = False) -> list[Path]:
    """The case's episode as a GIF (and a PNG of its middle frame beside it), each frame titled with the
    action taken and the actions the rule layer allowed; an existing GIF or PNG only with overwrite."""
    from highway_srl.experiments.renderings import draw_episode

    out = Path(out)
    if out.suffix.lower() != ".gif":
        raise ValueError(f"--gif must end in .gif, got {str(out)!r}")
    check_output_folder(out.parent, "--gif")
    world = case_world(case)
    layer = SafetyLayer(world.road, profile=profile or case.profile)
    step = iter(case.actions)

    def driver(w):
        view, action = layer.observe(w), next(step)
        allowed = [name for name, ok in zip(ACTIONS, view.primary.mask[0].tolist()) if ok]
        return layer.act(torch.tensor([action])), [f"{ACTIONS[action]}", "allowed: " + ",".join(allowed)]
    return draw_episode(world, driver, len(case.actions), out, overwrite=overwrite)
