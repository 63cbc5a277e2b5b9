"""`highway-srl falsify --search ce`: a cross-entropy search over scenario parameters for ego-avoidable
collisions of the rule layer.

The breadth search (experiments/falsify.py) draws every scene from the simulator's full ranges. This one
learns where the holes are: each iteration draws `samples` scenarios from a distribution over the scene,
the traffic level, nominal/adversarial (categorical) and the initial-scene knobs of
experiments/scenario_params.KNOBS (independent Gaussians in [0, 1] coordinates, clipped to the range),
drives them batched (one env per sample, one world per scene, level and mode) with the ego the settings'
policy picks, and scores each episode: 2 for an ego-avoidable collision, else 1 / (1 + the least
predicted time to contact of the actions taken), in (0, 1]. The distribution is refitted to the
`elite` fraction of highest scores, smoothed (new = (1 - smoothing) old + smoothing fit; categories keep at
least FLOOR, standard deviations at least MIN_STD, so no part of the space is shut for good). Every
ego-avoidable collision is kept as a case with its world seed and scenario parameters, which
falsify.replay_case drives again.
"""

from __future__ import annotations

import collections
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch

from highway_srl.experiments import falsify as fz
from highway_srl.experiments.collisions import DecisionTrace
from highway_srl.experiments.runs import check_output_folder, write_json
from highway_srl.experiments.scenario_params import KNOBS, scenario_world
from highway_srl.rules import SafetyLayer

FLOOR = 0.02  # least probability of a category after a refit
MIN_STD = 0.05  # least standard deviation of a knob (in [0, 1] coordinates) after a refit
AVOIDABLE_SCORE = 2.0


@dataclass
class SearchSettings:
    iterations: int = 8
    samples: int = 256  # scenarios per iteration
    elite: float = 0.2  # fraction of the samples the distribution is refitted to
    smoothing: float = 0.7

    def check(self) -> None:
        for name in ("iterations", "samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("elite", "smoothing"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)!r}")
        if round(self.elite * self.samples) < 2:
            raise ValueError(f"elite x samples must keep at least 2 scenarios, got {self.elite} x {self.samples}")


@dataclass
class Distribution:
    """The sampling distribution: choices and probabilities per categorical dimension, mean and standard
    deviation per knob of KNOBS (in [0, 1] coordinates: low + (high - low) z)."""

    choices: dict[str, list]  # "scene", "level", "adversarial" -> the values to choose among
    probs: dict[str, torch.Tensor]  # the same keys -> (n,) float64 probabilities
    mean: torch.Tensor  # (len(KNOBS),) float64
    std: torch.Tensor

    @classmethod
    def initial(cls, settings: fz.FalsifySettings) -> "Distribution":
        """Uniform over the settings' scenes, levels and modes; each knob centred in its range, wide."""
        choices = {"scene": list(settings.scenes), "level": list(settings.levels), "adversarial": list(settings.modes)}
        probs = {k: torch.full((len(v),), 1.0 / len(v), dtype=torch.float64) for k, v in choices.items()}
        k = len(KNOBS)
        return cls(choices, probs, torch.full((k,), 0.5, dtype=torch.float64), torch.full((k,), 0.3, dtype=torch.float64))

    def sample(self, n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """n draws: an index per categorical dimension (n,) long and "z" (n, len(KNOBS)) in [0, 1]."""
        draws = {k: torch.multinomial(p, n, replacement=True, generator=generator) for k, p in self.probs.items()}
        noise = torch.randn(n, len(KNOBS), generator=generator, dtype=torch.float64)
        draws["z"] = (self.mean + self.std * noise).clamp(0.0, 1.0)
        return draws

    def refit(self, draws: dict[str, torch.Tensor], scores: torch.Tensor, search: SearchSettings) -> "Distribution":
        """The distribution moved toward the elite (the round(elite x n) highest scores, earlier draws first
        among equals) by `smoothing`."""
        keep = max(2, round(search.elite * scores.shape[0]))
        elite = torch.argsort(scores, descending=True, stable=True)[:keep]
        a = search.smoothing
        probs = {}
        for k, p in self.probs.items():
            freq = torch.bincount(draws[k][elite], minlength=p.shape[0]).double() / keep
            q = ((1 - a) * p + a * freq).clamp(min=FLOOR)
            probs[k] = q / q.sum()
        z = draws["z"][elite]
        mean = (1 - a) * self.mean + a * z.mean(0)
        std = ((1 - a) * self.std + a * z.std(0)).clamp(min=MIN_STD)
        return Distribution(self.choices, probs, mean, std)

    def as_dict(self) -> dict:
        out = {k: dict(zip(map(str, self.choices[k]), [round(x, 4) for x in p.tolist()])) for k, p in self.probs.items()}
        for i, (name, (lo, hi)) in enumerate(KNOBS.items()):
            out[name] = {"mean": round(lo + (hi - lo) * float(self.mean[i]), 4),
                         "std": round((hi - lo) * float(self.std[i]), 4)}
        return out


def parameters_of(z: torch.Tensor) -> list[dict]:
    """Scenario parameters (KNOBS, in their units) of draws z (n, len(KNOBS)) in [0, 1]: Python floats,
    which a case's JSON keeps exactly, so its replay sets the very values driven."""
    values = torch.tensor(list(KNOBS.values()), dtype=torch.float64)
    x = (values[:, 0] + (values[:, 1] - values[:, 0]) * z).clamp(values[:, 0], values[:, 1])
    return [dict(zip(KNOBS, map(float, row))) for row in x]


class _WatchedTrace:
    """A DecisionTrace that also keeps each env's least predicted time to contact (falsify.predicted_ttc)
    of the actions taken while its episode runs."""

    def __init__(self, envs: int) -> None:
        self.trace = DecisionTrace(fz.AllowedActions())
        self.min_ttc = torch.full((envs,), fz.NO_CONTACT_S)

    def __call__(self, view, step, alive) -> None:
        action = step.decision.action
        ttc = fz.predicted_ttc(view.primary, view.snapshot.ego_vx).gather(1, action[:, None])[:, 0]
        self.min_ttc = torch.where(alive, torch.minimum(self.min_ttc, ttc), self.min_ttc)
        self.trace(view, step, alive)

    def after_step(self, world, events, alive) -> None:
        self.trace.after_step(world, events, alive)


def run_group(job: tuple) -> tuple[torch.Tensor, dict, list[fz.Case]]:
    """One world of one scene, level and mode: (scene, level, adversarial, settings, seeds, parameters).
    Returns the scores (B,), the counts (as falsify's batches) and the ego-avoidable collisions as cases."""
    scene, level, adversarial, settings, seeds, parameters = job
    world = scenario_world(scene, level, adversarial, seeds, settings.steps, settings.adversary, parameters)
    layer = SafetyLayer(world.road, profile=settings.profile)
    gen = torch.Generator().manual_seed(seeds[0])
    watched = _WatchedTrace(len(seeds))
    actions, collided, changed = fz.drive(world, layer, lambda step, view: fz.choose(settings.policy, view, gen),
                                          watched)
    scores = 1.0 / (1.0 + watched.min_ttc.double())
    cases = []
    for case in fz.batch_cases(world, settings, seeds[0], actions, watched.trace):
        if case.ego_avoidable:
            scores[case.env] = AVOIDABLE_SCORE
            cases.append(replace(case, seed=seeds[case.env], env=0, parameters=parameters[case.env]))
    return scores, fz.batch_counts(watched.trace, collided, changed), cases


def one_iteration(dist: Distribution, first_seed: int, settings: fz.FalsifySettings, search: SearchSettings,
                  run, generator: torch.Generator) -> tuple[dict, torch.Tensor, dict, list[fz.Case]]:
    """Draw, drive and score one iteration's scenarios (env i gets world seed first_seed + i); returns the
    draws, the scores (n,), the counts and the cases."""
    n = search.samples
    draws = dist.sample(n, generator)
    parameters = parameters_of(draws["z"])
    cell = [tuple(int(i) for i in ids) for ids in zip(draws["scene"], draws["level"], draws["adversarial"])]
    groups = collections.defaultdict(list)
    for i, key in enumerate(cell):
        groups[key].append(i)
    order = sorted(groups)
    jobs = [(dist.choices["scene"][s], dist.choices["level"][lv], dist.choices["adversarial"][m], settings,
             [first_seed + i for i in groups[(s, lv, m)]], [parameters[i] for i in groups[(s, lv, m)]])
            for s, lv, m in order]
    scores, counts, cases = torch.zeros(n, dtype=torch.float64), {}, []
    for key, (part, part_counts, part_cases) in zip(order, run(run_group, jobs)):
        scores[groups[key]] = part
        fz.add_counts(counts, part_counts)
        cases += part_cases
    return draws, scores, counts, cases


def ce_search(settings: fz.FalsifySettings, search: SearchSettings, out: str | Path | None = None, progress=None,
              processes: int = 1) -> dict:
    """The search of the module docstring; the report (dict), like falsify's with the iterations' history
    and the final distribution. out: a folder for report.json and one case JSON per ego-avoidable
    collision. progress(done, total) after each iteration. processes: the iteration's worlds in this many
    forked workers (falsify.batch_runner); the report is the same for any count."""
    settings.check()
    search.check()
    fz.check_processes(processes)
    if out is not None:
        fz.check_report_folder(Path(out))
    generator = torch.Generator().manual_seed(settings.seed)
    dist, total, kept, history = Distribution.initial(settings), {}, [], []
    with fz.batch_runner(processes) as run:
        for it in range(search.iterations):
            first = settings.seed + it * search.samples
            draws, scores, counts, cases = one_iteration(dist, first, settings, search, run, generator)
            fz.add_counts(total, counts)
            kept += cases
            history.append({"iteration": it, "episodes": counts["episodes"], "collisions": counts["collisions"],
                            "ego_avoidable": counts["ego_avoidable"], "mean_score": round(float(scores.mean()), 4),
                            "distribution": dist.as_dict()})
            dist = dist.refit(draws, scores, search)
            if progress is not None:
                progress(it + 1, search.iterations)
    report = {"settings": asdict(settings), "search": {"method": "ce", **asdict(search)}, **total,
              "ego_avoidable_causes": len({(c.scene, c.cause) for c in kept}),
              "iterations": history, "distribution": dist.as_dict()}
    if out is not None:
        report["cases"] = fz.write_cases(Path(out), kept)
        write_json(Path(out) / "report.json", report)
    else:
        report["cases"] = [{"cause": c.cause, "ego_avoidable": c.ego_avoidable} for c in kept]
    return report
