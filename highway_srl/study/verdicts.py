"""The paper's claims judged on our numbers with the seed as the unit (stats.py, seed_tables.py).

Each claim is a list of checks (one per scene, level or ablated part); a check is True, False or None (no
result to judge), and the verdict follows from them: confirmed, partly confirmed, not confirmed, or cannot be
checked. Every check's line ends with what it rests on: seeds, episodes, budget and control profile.

  collision-free training   the mean of the seeds' T_c prints as 1.000, per Table 5 scene
  Pareto front              judged on seed means with their 95 % t intervals: MoE-RM-SRL is on the front only if
                            no baseline is as good on both axes beyond its interval and better on one, and none
                            of its seeds collapsed (a collapsed seed is named, never averaged away)
  merging, exiting success  seed-mean R_s at least HIGH_SUCCESS, no baseline above its interval, and none of
                            MoE-RM-SRL's seeds collapsed (else "not shown")
  ablation                  a part "matters" only where the full model is better with p < 0.05 (bootstrap over
                            seeds; one seed a side: the two-proportion test on the pooled episodes), else "not
                            shown"

and, beyond the paper, its promise kept or not under each profile (promise_claim): no collision the ego could
have avoided in MoE-RM-SRL's training or deployment, per scene, with the rate's 95 % upper bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from highway_srl.experiments.falsify import rate_upper_bound
from highway_srl.study import seed_tables as ST
from highway_srl.study.collision_tables import deployment_verdicts, training_verdicts
from highway_srl.study import stats as S
from highway_srl.study.results import Results
from highway_srl.study.table import fmt
from highway_srl.study.paper_numbers import TABLE5
from highway_srl.study.jobs import (ABLATION_SCENE, ABLATIONS, GROUP1_METHODS, METHOD_LABELS, OURS, SCENES,
                                    TABLE5_METHODS, TABLE5_SCENES)

COLLISION_FREE = 0.9995  # T_c that prints as 1.000, the paper's value for MoE-RM-SRL in every scene
HIGH_SUCCESS = 0.5  # "high" success: most episodes reach the merge's end or the off-ramp


@dataclass
class Check:
    what: str
    ok: bool | None  # None: no result to judge
    detail: str


@dataclass
class Claim:
    key: str
    statement: str  # what the paper says
    criterion: str  # how we judge it
    checks: list[Check] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        known = [c.ok for c in self.checks if c.ok is not None]
        if not known:
            return "cannot be checked"
        missing = len(self.checks) - len(known)
        if all(known):
            return "confirmed" if not missing else f"confirmed where checked ({len(known)} of {len(self.checks)})"
        if not any(known):
            return "not confirmed"
        return f"partly confirmed ({sum(known)} of {len(self.checks)} checks)"


def dominates(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """a Pareto-dominates b, every coordinate higher-is-better: a >= b everywhere and > somewhere."""
    return all(x >= y for x, y in zip(a, b)) and any(x > y for x, y in zip(a, b))


def basis(results: Results, seeds: int | str, episodes: int, what: str = "episodes") -> str:
    """What a verdict line rests on: '(3 seeds, 300 episodes; budget paper, paper profile)'."""
    return (f"({seeds} seed{'' if seeds == 1 else 's'}, {episodes:,} {what}; budget {results.budget}, "
            f"{results.profile or 'paper'} profile)")


def _collapsed_text(fallen: dict, name: str, kind: str) -> str:
    return ", ".join(f"seed {s} collapsed ({name} {fmt(kind, v)})" for s, v in sorted(fallen.items()))


def claims(results: Results) -> list[Claim]:
    """The paper's claims, each checked on the study's results."""
    return [_collision_free_claim(results), _pareto_claim(results),
            _success_claim(results, "merge_success", ("merge", "adv-merge"), "merging"),
            _success_claim(results, "exit_success", ("exit", "adv-exit"), "exiting"), _ablation_claim(results)]


def _ours_by_scene(results: Results, claim: Claim, scenes, key: str, missing: str):
    """(scene, label, seed summary) of MoE-RM-SRL in each scene that has `key`; the others get a check
    without a verdict that says `missing`."""
    for scene in scenes:
        s = ST.summary(results.get(OURS, scene))
        if s[key] is None:
            claim.checks.append(Check(SCENES[scene].label, None, missing))
        else:
            yield scene, SCENES[scene].label, s


def _collision_free_claim(results: Results) -> Claim:
    """Table 5's collision-free training of MoE-RM-SRL, per scene."""
    c = Claim("collision_free_training", "MoE-RM-SRL trains without collisions (Table 5: T_c = 1.000 in all six "
              "scenes).", f"The mean over seeds of MoE-RM-SRL's T_c is at least {COLLISION_FREE} (prints as 1.000) "
              "in each scene; the 95% t interval over seeds and the lowest seed are stated.")
    for scene, label, s in _ours_by_scene(results, c, TABLE5_SCENES, "T_c", "no finished training episodes"):
        seeds = ST.train_seeds(results.get(OURS, scene))
        low = min(seeds.items(), key=lambda kv: (kv[1]["T_c"] if kv[1]["T_c"] is not None else 2.0, kv[0]))
        detail = (f"T_c {ST.interval_text('f4', s['T_c'])} over seeds, lowest seed {low[0]} at "
                  f"{fmt('f4', low[1]['T_c'])}; {sum(v['collisions'] or 0 for v in seeds.values())} collision(s)")
        if "T_c" in s["collapsed"]:
            detail += "; " + _collapsed_text(s["collapsed"]["T_c"], "T_c", "f3")
        c.checks.append(Check(label, s["T_c"].mean >= COLLISION_FREE,
                              f"{detail} {basis(results, s['seeds'], s['episodes'], 'training episodes')}"))
    return c


def _negated(iv: S.Interval) -> S.Interval:
    """Lower is better -> higher is better (rise time)."""
    return S.Interval(-iv.mean, None if iv.high is None else -iv.high, None if iv.low is None else -iv.low, iv.n)


def _pareto_check(what: str, points: dict, describe, results: Results) -> Check:
    """points: method label -> (axes as Intervals, collapsed seeds text, seeds, episodes) or None."""
    ours = points.get(METHOD_LABELS[OURS])
    others = {m: p for m, p in points.items() if m != METHOD_LABELS[OURS] and p is not None}
    if ours is None:
        return Check(what, None, "no MoE-RM-SRL result")
    axes, fallen, seeds, episodes = ours
    on = f"MoE-RM-SRL at {describe(axes)} {basis(results, seeds, episodes)}"
    if not others:
        return Check(what, None, f"{on}; no baseline result to compare with")
    over = [m for m, p in others.items() if S.dominates_beyond(p[0], axes)]
    if over:
        return Check(what, False, f"{on} is dominated beyond its intervals by "
                     + ", ".join(f"{m} ({describe(others[m][0])})" for m in over))
    if fallen:
        return Check(what, False, f"not shown: {on} is on the front by its mean only; {fallen}")
    under = [m for m, p in others.items() if dominates(tuple(i.mean for i in axes), tuple(i.mean for i in p[0]))]
    seen = [f"{m}: {p[1]}" for m, p in others.items() if p[1]]
    return Check(what, True, f"{on} is on the front: no baseline is better beyond its intervals; by the means it "
                 f"dominates {', '.join(under) if under else 'none'} of {len(others)} baseline(s)"
                 + (f" (baselines with collapsed seeds: {'; '.join(seen)})" if seen else ""))


def _deploy_point(res, level: str):
    s = ST.summary(res, level)
    if s["avg_speed"] is None or s["C_r"] is None:
        return None
    fallen = _collapsed_text(s["collapsed"].get("C_r", {}), "C_r", "pct")
    return (s["avg_speed"], s["C_r"]), fallen, s["deploy_seeds"], s["deploy_episodes"]


def _train_point(res):
    s = ST.summary(res)
    if s["T_c"] is None or s["rise_time"] is None:
        return None
    fallen = _collapsed_text(s["collapsed"].get("T_c", {}), "T_c", "f3")
    return (s["T_c"], _negated(s["rise_time"])), fallen, s["seeds"], s["episodes"]


def _pareto_claim(results: Results) -> Claim:
    """MoE-RM-SRL on the Pareto front: deployment per Group 1 level, training per Table 5 scene."""
    c = Claim("pareto", "MoE-RM-SRL dominates the Pareto front: in deployment it occupies the upper right (speed, "
              "C_r) at every traffic level, and in training it combines collision-free training with a fast reward "
              "rise.", "On seed means with 95% t intervals over seeds: no baseline is at least MoE-RM-SRL's upper "
              "bound on both axes and above it on one, in (average speed, C_r) at each Group 1 level and in (T_c, "
              "-rise time) in each Table 5 scene; and no seed of MoE-RM-SRL collapsed.")
    for level in results.levels:
        pts = {METHOD_LABELS[m]: _deploy_point(results.get(m, "two-lane"), level) for m in GROUP1_METHODS}
        c.checks.append(_pareto_check(
            f"deployment, level {level}", pts, lambda p: f"{ST.interval_text('f2', p[0])} m/s, C_r "
            f"{ST.interval_text('pct', p[1])}", results))
    for scene in TABLE5_SCENES:
        pts = {METHOD_LABELS[m]: _train_point(results.get(m, scene)) for m in TABLE5_METHODS}
        c.checks.append(_pareto_check(
            f"training, {SCENES[scene].label}", pts, lambda p: f"T_c {ST.interval_text('f3', p[0])}, rise "
            f"{ST.interval_text('f0', _negated(p[1]))} steps", results))
    return c


def _success_claim(results: Results, key: str, scenes: tuple[str, str], doing: str) -> Claim:
    """MoE-RM-SRL's success rate in a scene and its adversarial twin, against every baseline."""
    paper = " and ".join(f"{SCENES[s].label} {TABLE5[s]['R_s'][OURS]:.1%}" for s in scenes)
    c = Claim(key, f"MoE-RM-SRL keeps high success on {doing} (Table 5: R_s {paper}).",
              f"The mean over seeds of MoE-RM-SRL's R_s is at least {HIGH_SUCCESS:.0%}, no baseline's seed mean "
              "lies above its 95% t interval, and no seed of MoE-RM-SRL collapsed; pooled rates [Wilson] beside.")
    for scene, label, s in _ours_by_scene(results, c, scenes, "R_s", "no MoE-RM-SRL result"):
        base = {METHOD_LABELS[m]: ST.summary(results.get(m, scene))["R_s"] for m in TABLE5_METHODS if m != OURS}
        base = {m: iv for m, iv in base.items() if iv is not None}
        better = [m for m, iv in base.items() if S.beyond(iv, s["R_s"])]
        detail = (f"R_s {ST.interval_text('pct', s['R_s'])} over seeds, pooled "
                  f"{ST.interval_text('pct', s['R_s_pooled'])} (paper {TABLE5[scene]['R_s'][OURS]:.1%})")
        fallen = s["collapsed"].get("R_s")
        if fallen:
            detail += "; " + _collapsed_text(fallen, "R_s", "pct")
        detail += ("; baselines " + ", ".join(f"{m} {fmt('pct', iv.mean)}" for m, iv in base.items())
                   if base else "; no baseline result to compare with")
        if better:
            detail += f"; above its interval: {', '.join(better)}"
        ok = s["R_s"].mean >= HIGH_SUCCESS and not better
        if ok and fallen:  # high by the mean only: a collapsed seed is named, never averaged away
            ok, detail = False, "not shown: " + detail
        c.checks.append(Check(label, ok, f"{detail} {basis(results, s['deploy_seeds'], s['deploy_episodes'])}"))
    return c


def _ablation_claim(results: Results) -> Claim:
    """Table 6: the full model better than each ablated variant on adversarial two-lane, significantly."""
    c = Claim("ablation", "Each ablated part matters (Table 6: without mapping, MoE or RM, deployment C_r and R_r "
              "drop on adversarial two-lane).", f"The full MoE-RM-SRL is better than the variant in C_r or R_r with "
              f"p < {S.SIGNIFICANCE} (bootstrap over seeds, {S.BOOTSTRAP_DRAWS:,} draws; with one seed a side, the "
              "two-proportion test on the pooled C_r episodes) and not significantly worse in the other; else "
              "the part's effect is not shown.")
    full = results.get(OURS, ABLATION_SCENE)
    for option, label in ABLATIONS.items():
        res = results.get(OURS, ABLATION_SCENE, (option,))
        fd, vd = ST.deploy_seeds(full), ST.deploy_seeds(res)
        if not fd or not vd:
            why = "no result for the full model" if not fd else f"no result for {label}"
            if res is not None and res.status == "unavailable":
                why += " (unavailable)"
            c.checks.append(Check(label, None, why))
            continue
        c.checks.append(ablation_check(label, fd, vd, results))
    return c


def promise_claim(results: Results) -> Claim:
    """The paper's promise of collision-free driving in the form our safe profile is built to keep, judged on
    one profile's jobs: MoE-RM-SRL's collisions the ego could have avoided (rules/avoidable.py), in every
    scene, training and each deployment level together. A collision left unjudged counts against the promise."""
    profile = results.profile or "paper"
    c = Claim("no_ego_avoidable", f"No collision the ego could have avoided, in training or deployment "
              f"({profile} profile; docs/paper-notes.md, 'Ego-avoidable collisions').",
              "MoE-RM-SRL has no ego-avoidable and no unjudged collision in a scene's training and deployment "
              "episodes over every finished seed; the 95% upper bound on the per-episode rate is stated (3/N "
              "with none in N episodes, else Clopper-Pearson).")
    for scene, spec in SCENES.items():
        res = results.get(OURS, scene)
        if res is None or not res.done:
            c.checks.append(Check(spec.label, None, "no finished seeds"))
            continue
        phases = [training_verdicts(res)] + [deployment_verdicts(lv) for lv in res.evaluation["levels"].values()]
        if any(p["ego_avoidable"] is None for p in phases):
            c.checks.append(Check(spec.label, None, "records written before the collision verdicts"))
            continue
        episodes = res.train()["episodes"] + sum(lv["episodes"] for lv in res.evaluation["levels"].values())
        avoidable, unjudged = (sum(p[k] for p in phases) for k in ("ego_avoidable", "not_judged"))
        detail = (f"{avoidable} ego-avoidable, {unjudged} not judged, {sum(p['unavoidable'] for p in phases)} "
                  f"unavoidable in {episodes:,} episodes (training and deployment); rate of the first two at most "
                  f"{rate_upper_bound(avoidable + unjudged, episodes):.1e} an episode (95%)")
        c.checks.append(Check(spec.label, avoidable + unjudged == 0,
                              f"{detail} {basis(results, len(ST.train_seeds(res)), episodes)}"))
    return c


def p_text(p: float) -> str:
    """'p 0.0312', or 'p < 0.0002' at the bootstrap's resolution (every draw on one side)."""
    return f"p < {2 / S.BOOTSTRAP_DRAWS:.4f}" if p <= 1 / S.BOOTSTRAP_DRAWS else f"p {p:.4f}"


def ablation_check(label: str, full: dict, variant: dict, results: Results) -> Check:
    """full, variant: deploy_seeds of the two jobs ({seed: {episodes, C_r, R_r, ...}})."""
    tests, better, worse = [], False, False
    if len(full) >= 2 and len(variant) >= 2:
        for key, kind in (("C_r", "pp"), ("R_r", "sd")):
            d = S.bootstrap_difference([s[key] for s in full.values()], [s[key] for s in variant.values()])
            effect = f"{100 * d.effect:+.1f} points" if key == "C_r" else f"{d.effect:+.2f}"
            tests.append(f"{key} full - {label} {effect}, {p_text(d.p)} (bootstrap over seeds)")
            better |= d.significant and d.effect > 0
            worse |= d.significant and d.effect < 0
    else:
        k = [sum(round(s["C_r"] * s["episodes"]) for s in side.values()) for side in (full, variant)]
        n = [sum(s["episodes"] for s in side.values()) for side in (full, variant)]
        p = S.two_proportion_p(k[0], n[0], k[1], n[1])
        effect = k[0] / n[0] - k[1] / n[1]
        tests.append(f"C_r full - {label} {100 * effect:+.1f} points, {p_text(p)} (pooled episodes, one seed a side)")
        better, worse = p < S.SIGNIFICANCE and effect > 0, p < S.SIGNIFICANCE and effect < 0
    ok = better and not worse
    seeds, episodes = f"{len(full)} + {len(variant)}", sum(s["episodes"] for s in (*full.values(), *variant.values()))
    head = "matters" if ok else "not shown"
    return Check(label, ok, f"{head}: {'; '.join(tests)} {basis(results, seeds, episodes)}")
