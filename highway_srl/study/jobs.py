"""The paper's study as a list of jobs, for each budget (§4.3, Tables 5-6, the multi-lane table, Figs. 5-6).

A job is one training run folder: one method (or ablation) on one scene, every seed of the budget batched
in one process (`TrainConfig.seeds`), followed by its deployment evaluation. A job serves every artefact
that reads it: the two-lane MoE-RM-SRL run feeds Group 1, Table 5 and the training figures alike.

  Group 1   every method, two-lane trained at level C, evaluated at levels A-F  -> deployment Pareto figure
  Group 2   multi-lane (normal, adversarial; MoE-RM-SRL as in the paper's table), merging, exiting
  Group 3   adversarial two-lane, merging, exiting
  Table 5   ET-RL, MP-RL, SR-RL, RL, LM-RL, MoE-RM-SRL on the six scenes
  Table 6   MoE-RM-SRL without mapping / MoE / RM on adversarial two-lane
  training  T_c against rise time (all non-ablation runs) and training curves per scene

Every job runs under one control profile: the reproduction under "paper" (Eqs. 31-35 as printed, the paper's
adversary), and, where the budget lists it, the same jobs again under "safe" (our safety additions), a set
labelled "beyond the paper" in the tables and the report (folders runs/safe/SCENE/VARIANT).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field

from highway_srl.constants import DEFAULT_ADVERSARY, DEFAULT_PROFILE, TRAFFIC_LEVELS


@dataclass(frozen=True)
class Scene:
    key: str
    scenario: str  # highway_srl.constants.SCENARIOS
    adversarial: bool
    label: str  # the paper's name


SCENES: dict[str, Scene] = {s.key: s for s in (
    Scene("two-lane", "two-lane", False, "Two-lane"),
    Scene("merge", "merge", False, "Merging"),
    Scene("exit", "exit", False, "Exiting"),
    Scene("adv-two-lane", "two-lane", True, "Adv. two-lane"),
    Scene("adv-merge", "merge", True, "Adv. merging"),
    Scene("adv-exit", "exit", True, "Adv. exiting"),
    Scene("multi-lane", "multi-lane", False, "Multi-lane (normal)"),
    Scene("adv-multi-lane", "multi-lane", True, "Multi-lane (adversarial)"),
)}

TABLE5_SCENES = ("two-lane", "merge", "exit", "adv-two-lane", "adv-merge", "adv-exit")
GROUP2_SCENES = ("multi-lane", "adv-multi-lane", "merge", "exit")
GROUP3_SCENES = ("adv-two-lane", "adv-merge", "adv-exit")
MULTILANE_SCENES = ("multi-lane", "adv-multi-lane")

OURS = "moe-rm-srl"
# Every method the study knows, in the order tables and legends list them.
METHOD_LABELS: dict[str, str] = {
    "moe-rm-srl": "MoE-RM-SRL",
    "rl": "RL",
    "sr-rl": "SR-RL",
    "rm-rl": "RM-RL",
    "mp-rl": "MP-RL",
    "lm-rl": "LM-RL",
    "et-rl": "ET-RL",
    "rule-based": "Rule-based",
}
TABLE5_METHODS = ("et-rl", "mp-rl", "sr-rl", "rl", "lm-rl", "moe-rm-srl")  # the paper's column order
GROUP1_METHODS = tuple(METHOD_LABELS)  # every method, as in the deployment figure
ABLATIONS: dict[str, str] = {"no_mapping": "w/o MAP", "no_moe": "w/o MoE", "no_rm": "w/o RM"}
ABLATION_SCENE = "adv-two-lane"
TRAIN_TRAFFIC = "C"  # every group trains at level C (§4.3)
REPRODUCTION_PROFILE = DEFAULT_PROFILE  # the profile of the reproduction; any other is "beyond the paper"
STUDY_ADVERSARY = DEFAULT_ADVERSARY  # group 3's cut-ins, in every profile


@dataclass(frozen=True)
class Budget:
    name: str
    steps: int  # environment steps per seed
    envs: int  # environments per seed
    seeds: tuple[int, ...]  # independent runs, batched in one process per job
    learning_starts: int
    batch_size: int
    replay_ratio: float  # gradient steps per env step (Algorithm 1: 1.0); below 1 the report says so
    eval_episodes: int  # per seed and traffic level
    group1_levels: tuple[str, ...]
    checkpoint_every: int  # env steps between resume checkpoints
    expected_cost: str  # what it takes, said to the user in --help and the report
    profiles: tuple[str, ...] = (REPRODUCTION_PROFILE,)  # control profiles run; the first is the paper's


BUDGETS: dict[str, Budget] = {
    "smoke": Budget(
        "smoke", steps=1_344, envs=4, seeds=(0,), learning_starts=800, batch_size=32, replay_ratio=0.25,
        eval_episodes=4, group1_levels=("A", "C", "F"), checkpoint_every=10**9,
        expected_cost="about 10-11 minutes on a 2-core CPU for its 43 jobs (336 vector steps per run: one "
                      "episode per env, 1 seed, 4 episodes per level, Group 1 at levels A, C, F); checks that "
                      "every artefact is produced, "
                      "says nothing about the paper"),
    "quick": Budget(
        "quick", steps=40_000, envs=8, seeds=(0, 1), learning_starts=1_000, batch_size=64, replay_ratio=0.25,
        eval_episodes=20, group1_levels=tuple(TRAFFIC_LEVELS), checkpoint_every=8_000, profiles=("paper", "safe"),
        expected_cost="about 4 h on a 2-core CPU for its 86 jobs, both profiles (measured at 9fb10e1; "
                      "4e4 steps x 2 seeds per run, 20 episodes per seed and level); "
                      "enough for MoE-RM-SRL's return to rise, not for the paper's numbers"),
    "paper": Budget(
        "paper", steps=500_000, envs=16, seeds=tuple(range(10)), learning_starts=1_000, batch_size=256,
        replay_ratio=1.0, eval_episodes=100, group1_levels=tuple(TRAFFIC_LEVELS), checkpoint_every=50_000,
        profiles=("paper", "safe"),
        expected_cost="5e5 steps x 10 seeds per run (the seeds batched in one process), 100 episodes per seed "
                      "and level, 43 runs. CPU: about 2.2 h per run on one core (bench train --seeds 10: 631 "
                      "env-steps/s on one thread, 2026-12-02; one seed alone trains in 16-35 min), so about 2 "
                      "days for the study on a 2-core CPU, less with more cores (--jobs) or a Ray cluster. "
                      "GPU (--device cuda): roughly 10 min per run on one H100 (estimated from the measured "
                      "update cost, not timed end to end), about 7 h for the 43 runs one after another, less "
                      "with --jobs 4 sharing the GPU or several GPUs through Ray"),
}


def get_budget(name: str) -> Budget:
    if name not in BUDGETS:
        raise ValueError(f"unknown budget {name!r}; choose one of {', '.join(BUDGETS)}")
    return BUDGETS[name]


@dataclass(frozen=True)
class Job:
    """One run folder: `method` with ablation `options` on `scene`, all `seeds` batched, then evaluated."""

    method: str
    scene: str
    options: tuple[str, ...] = ()  # ablation switches, e.g. ("no_mapping",)
    seeds: tuple[int, ...] = (0,)
    steps: int = 500_000
    envs: int = 16
    learning_starts: int = 1_000
    batch_size: int = 256
    replay_ratio: float | None = 1.0
    checkpoint_every: int = 50_000
    eval_levels: tuple[str, ...] = ("C",)
    eval_episodes: int = 100
    artefacts: tuple[str, ...] = field(default=(), compare=False)
    profile: str = REPRODUCTION_PROFILE  # control profile of the method's rule layer
    adversary: str = STUDY_ADVERSARY  # group-3 cut-ins on the adversarial scenes
    legacy_updates_per_step: int | None = None  # studies written before replay_ratio (replay_ratio None)

    @property
    def variant(self) -> str:
        """The method and its ablation switches, e.g. 'moe-rm-srl' or 'moe-rm-srl-no_mapping'."""
        return "-".join((self.method, *self.options))

    @property
    def beyond_the_paper(self) -> bool:
        """A job of a profile other than the reproduction's (a study written before profiles had one set)."""
        return self.profile != REPRODUCTION_PROFILE and self.replay_ratio is not None

    @property
    def id(self) -> str:
        prefix = f"{self.profile}:" if self.beyond_the_paper else ""
        return f"{prefix}{self.scene}/{self.variant}"

    @property
    def folder(self) -> str:
        """The run folder, relative to the study's root (runs/PROFILE/... beyond the paper's profile)."""
        prefix = f"{self.profile}/" if self.beyond_the_paper else ""
        return f"runs/{prefix}{self.scene}/{self.variant}"

    @property
    def label(self) -> str:
        name = METHOD_LABELS.get(self.method, self.method)
        return " ".join([name, *(ABLATIONS.get(o, o) for o in self.options)])

    def train_config(self, device: str = "cpu"):
        from highway_srl.agents.dqn import DQNConfig
        from highway_srl.agents.train_config import TrainConfig, legacy_replay_ratio

        scene = SCENES[self.scene]
        dqn = DQNConfig(total_steps=self.steps, learning_starts=self.learning_starts, batch_size=self.batch_size)
        options = {o: True for o in self.options}
        replay_ratio = self.replay_ratio
        if replay_ratio is None:  # a study written before replay_ratio: its rate, as a config of then reads
            replay_ratio = legacy_replay_ratio(self.method, options, self.envs, self.legacy_updates_per_step)
        return TrainConfig(method=self.method, scenario=scene.scenario, traffic=TRAIN_TRAFFIC,
                           adversarial=scene.adversarial, steps=self.steps, envs=self.envs, seeds=self.seeds,
                           device=device, replay_ratio=replay_ratio, profile=self.profile,
                           adversary=self.adversary, dqn=dqn, options=options)

    def cost(self) -> int:
        """Relative cost for scheduling (vector steps of training and evaluation)."""
        return self.steps // self.envs * len(self.seeds) + 320 * len(self.eval_levels)

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("options", "seeds", "eval_levels", "artefacts"):
            d[k] = list(d[k])
        return d

    @staticmethod
    def from_dict(d: dict) -> "Job":
        d = dict(d)
        for k in ("options", "seeds", "eval_levels", "artefacts"):
            d[k] = tuple(d.get(k, ()))
        if "replay_ratio" not in d:  # written before profiles and replay_ratio: safe, mild, updates per step
            d.update(profile=d.get("profile", "safe"), adversary=d.get("adversary", "mild"), replay_ratio=None)
            d["legacy_updates_per_step"] = d.pop("updates_per_step", 4)
        return Job(**d)


def study_jobs(budget: Budget | str, methods: tuple[str, ...] | None = None,
               scenes: tuple[str, ...] | None = None) -> list[Job]:
    """Every job of the study at `budget`, each once, listing the artefacts it serves; most costly first.

    methods: restrict to these methods (ablations go with 'moe-rm-srl'); None: every method.
    scenes: restrict to these scenes (keys of SCENES); None: every scene.
    """
    b = get_budget(budget) if isinstance(budget, str) else budget
    if methods is not None:
        unknown = [m for m in methods if m not in METHOD_LABELS]
        if unknown:
            raise ValueError(f"unknown method(s) {', '.join(map(repr, unknown))}; the study knows "
                             f"{', '.join(METHOD_LABELS)}")
    if scenes is not None:
        unknown = [s for s in scenes if s not in SCENES]
        if unknown:
            raise ValueError(f"unknown scene(s) {', '.join(map(repr, unknown))}; the study knows "
                             f"{', '.join(SCENES)}")
    wanted: dict[tuple, set[str]] = {}

    def need(method: str, scene: str, artefact: str, options: tuple[str, ...] = ()) -> None:
        if (methods is None or method in methods) and (scenes is None or scene in scenes):
            wanted.setdefault((method, scene, options), set()).add(artefact)

    for m in GROUP1_METHODS:
        need(m, "two-lane", "group1_deployment")
        need(m, "two-lane", "deployment_pareto")
        need(m, "two-lane", "training_pareto")
        need(m, "two-lane", "training_curves")
    for scene in TABLE5_SCENES:
        for m in TABLE5_METHODS:
            need(m, scene, "table5")
            need(m, scene, "training_pareto")
            need(m, scene, "training_curves")
            if scene in GROUP2_SCENES:
                need(m, scene, "group2")
            if scene in GROUP3_SCENES:
                need(m, scene, "group3")
    for scene in MULTILANE_SCENES:
        for artefact in ("group2", "multilane", "training_pareto", "training_curves"):
            need(OURS, scene, artefact)
    need(OURS, ABLATION_SCENE, "table6")
    for option in ABLATIONS:
        need(OURS, ABLATION_SCENE, "table6", (option,))

    jobs = []
    for profile in b.profiles:
        for (method, scene, options), artefacts in wanted.items():
            levels = b.group1_levels if "group1_deployment" in artefacts else (TRAIN_TRAFFIC,)
            if TRAIN_TRAFFIC not in levels:  # Table 5's two-lane column is evaluated at the training level
                levels = tuple(sorted({*levels, TRAIN_TRAFFIC}, key=list(TRAFFIC_LEVELS).index))
            jobs.append(Job(method=method, scene=scene, options=options, seeds=b.seeds, steps=b.steps, envs=b.envs,
                            learning_starts=b.learning_starts, batch_size=b.batch_size,
                            replay_ratio=b.replay_ratio, checkpoint_every=b.checkpoint_every,
                            eval_levels=levels, eval_episodes=b.eval_episodes, artefacts=tuple(sorted(artefacts)),
                            profile=profile, adversary=STUDY_ADVERSARY))
    # the reproduction's profile first (an interrupted study has the paper's set before ours), then most costly
    jobs.sort(key=lambda j: (b.profiles.index(j.profile), -j.cost(), j.id))
    return jobs


ARTEFACTS = ("group1_deployment", "deployment_pareto", "group2", "multilane", "group3", "table5", "table6",
             "training_pareto", "training_curves")


def job_availability(job: Job) -> str | None:
    """None if the job's method (and ablation switches) can run now, else why not, in one sentence.

    Methods come from `highway_srl.agents.registry.METHODS`. An
    ablation switch counts as implemented only if the method rejects switches it does not know (probe with a
    made-up one) and accepts this one, or lists it in an `allowed_options` attribute: a method that ignores
    unknown options would silently train the full model under an ablation's name.
    """
    from highway_srl.agents.registry import METHODS, make_method

    if job.method not in METHODS:
        return (f"method {job.method!r} is not registered in highway_srl.agents.registry.METHODS "
                f"(registered: {', '.join(METHODS) or 'none'})")
    scenario = SCENES[job.scene].scenario
    if not job.options:
        return None
    declared = getattr(METHODS[job.method], "allowed_options", None)
    if declared is not None:
        missing = [o for o in job.options if o not in declared]
        return None if not missing else (f"method {job.method!r} does not support option(s) "
                                         f"{', '.join(missing)} (supported: {', '.join(declared) or 'none'})")
    try:
        make_method(job.method, scenario, 1, {"__unknown_probe__": True})
    except (ValueError, KeyError, TypeError):
        pass
    else:
        return (f"method {job.method!r} accepts unknown options silently, so ablation "
                f"{'+'.join(job.options)} cannot be told apart from the full method yet")
    try:
        make_method(job.method, scenario, 1, {o: True for o in job.options})
    except (ValueError, KeyError, TypeError) as err:
        return f"method {job.method!r} rejects option(s) {'+'.join(job.options)}: {err}"
    return None


def default_jobs() -> int:
    return max(1, os.cpu_count() or 1)
