"""report.md and report.html of a study folder: setting, the paper's claims judged on our numbers, every
table and figure, and the jobs that did not finish.

The claims are judged by code from the tables' numbers, never written by hand. Each claim is a list of
checks (one per scene, level or ablated part); a check is True, False or None (no result to judge), and the
verdict follows from them: confirmed, partly confirmed, not confirmed, or cannot be checked.
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass, field
from pathlib import Path

from highway_srl.study import figures as F
from highway_srl.study import tables as T
from highway_srl.study.paper_numbers import TABLE5
from highway_srl.study.side_by_side import side_by_side
from highway_srl.experiments.runs import provenance
from highway_srl.study.jobs import (ABLATION_SCENE, ABLATIONS, BUDGETS, GROUP1_METHODS, METHOD_LABELS, OURS,
                                           SCENES, TABLE5_METHODS, TABLE5_SCENES, TRAIN_TRAFFIC, Job)

COLLISION_FREE = 0.9995  # T_c that prints as 1.000, the paper's value for MoE-RM-SRL in every scene
HIGH_SUCCESS = 0.5  # "high" success on exiting: most episodes reach the off-ramp


# --------------------------------------------------------------------------------------------- claims


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


def _pareto_check(what: str, points: dict[str, tuple[float, ...] | None], describe) -> Check:
    ours = points.get(METHOD_LABELS[OURS])
    others = {m: p for m, p in points.items() if m != METHOD_LABELS[OURS] and p is not None}
    if ours is None:
        return Check(what, None, "no MoE-RM-SRL result")
    if not others:
        return Check(what, None, f"MoE-RM-SRL at {describe(ours)}; no baseline result to compare with")
    over = [m for m, p in others.items() if dominates(p, ours)]
    under = [m for m, p in others.items() if dominates(ours, p)]
    if over:
        return Check(what, False, f"MoE-RM-SRL at {describe(ours)} is dominated by "
                     + ", ".join(f"{m} ({describe(others[m])})" for m in over))
    return Check(what, True, f"MoE-RM-SRL at {describe(ours)} is on the front; it dominates "
                 f"{', '.join(under) if under else 'none'} of {len(others)} baseline(s)")


def claims(results: T.Results) -> list[Claim]:
    """The paper's claims, each checked on the study's results."""
    return [_collision_free_claim(results), _pareto_claim(results), _exit_success_claim(results),
            _ablation_claim(results)]


def _collision_free_claim(results: T.Results) -> Claim:
    """Table 5's collision-free training of MoE-RM-SRL, per scene."""
    c = Claim("collision_free_training", "MoE-RM-SRL trains without collisions (Table 5: T_c = 1.000 in all six "
              "scenes).", f"T_c of MoE-RM-SRL is at least {COLLISION_FREE} (prints as 1.000) in each scene.")
    for scene in TABLE5_SCENES:
        res = results.get(OURS, scene)
        t = res.train() if res is not None and res.done else None
        label = SCENES[scene].label
        if t is None or t["T_c"] is None:
            c.checks.append(Check(label, None, "no finished training episodes"))
        else:
            c.checks.append(Check(label, t["T_c"] >= COLLISION_FREE,
                                  f"T_c {t['T_c']:.4f} ({t['collisions']} collision(s) in {t['episodes']} episodes)"))
    return c


def _pareto_claim(results: T.Results) -> Claim:
    """MoE-RM-SRL on the Pareto front: deployment per Group 1 level, training per Table 5 scene."""
    c = Claim("pareto", "MoE-RM-SRL dominates the Pareto front: in deployment it occupies the upper right (speed, "
              "C_r) at every traffic level, and in training it combines collision-free training with a fast reward "
              "rise.", "MoE-RM-SRL is not Pareto-dominated by any baseline in (average speed, C_r) at each Group 1 "
              "level, nor in (T_c, -rise time) in each Table 5 scene.")
    for level in results.levels:
        pts = {}
        for m in GROUP1_METHODS:
            res = results.get(m, "two-lane")
            d = res.deploy(level) if res is not None and res.done else None
            pts[METHOD_LABELS[m]] = (d["avg_speed"], d["C_r"]) if d else None
        c.checks.append(_pareto_check(f"deployment, level {level}", pts,
                                      lambda p: f"{p[0]:.2f} m/s, C_r {100 * p[1]:.1f}%"))
    for scene in TABLE5_SCENES:
        pts = {}
        for m in TABLE5_METHODS:
            res = results.get(m, scene)
            t = res.train() if res is not None and res.done else None
            ok = t is not None and t["T_c"] is not None and t["rise_time"] is not None
            pts[METHOD_LABELS[m]] = (t["T_c"], -t["rise_time"]) if ok else None
        c.checks.append(_pareto_check(f"training, {SCENES[scene].label}", pts,
                                      lambda p: f"T_c {p[0]:.3f}, rise {-p[1]:,.0f} steps"))
    return c


def _exit_success_claim(results: T.Results) -> Claim:
    """MoE-RM-SRL's success on (adversarial) exiting, against every baseline."""
    c = Claim("exit_success", "MoE-RM-SRL keeps high success on exiting (Table 5: R_s 80.2%, adversarial 81.5%, "
              "the best of all methods).", f"MoE-RM-SRL's R_s on exiting is at least {HIGH_SUCCESS:.0%} and no "
              "baseline's is higher, in normal and adversarial exiting.")
    for scene in ("exit", "adv-exit"):
        res = results.get(OURS, scene)
        d = res.deploy(TRAIN_TRAFFIC) if res is not None and res.done else None
        label = SCENES[scene].label
        if d is None or d.get("R_s") is None:
            c.checks.append(Check(label, None, "no MoE-RM-SRL result"))
            continue
        base = {}
        for m in TABLE5_METHODS:
            r = results.get(m, scene)
            bd = r.deploy(TRAIN_TRAFFIC) if m != OURS and r is not None and r.done else None
            if bd is not None and bd.get("R_s") is not None:
                base[METHOD_LABELS[m]] = bd["R_s"]
        better = {m: v for m, v in base.items() if v > d["R_s"]}
        ok = d["R_s"] >= HIGH_SUCCESS and not better
        detail = f"R_s {d['R_s']:.1%} (paper {TABLE5[scene]['R_s'][OURS]:.1%})"
        if base:
            detail += "; baselines " + ", ".join(f"{m} {v:.1%}" for m, v in base.items())
        else:
            detail += "; no baseline result to compare with"
        c.checks.append(Check(label, ok, detail))
    return c


def _ablation_claim(results: T.Results) -> Claim:
    """Table 6: the full model Pareto-dominates each ablated variant on adversarial two-lane."""
    c = Claim("ablation", "Each ablated part matters (Table 6: without mapping, MoE or RM, deployment C_r and R_r "
              "drop on adversarial two-lane).", "The full MoE-RM-SRL is at least as good as the variant in both C_r "
              "and R_r and better in one (it Pareto-dominates the variant in deployment).")
    full = results.get(OURS, ABLATION_SCENE)
    fd = full.deploy(TRAIN_TRAFFIC) if full is not None and full.done else None
    for option, label in ABLATIONS.items():
        res = results.get(OURS, ABLATION_SCENE, (option,))
        vd = res.deploy(TRAIN_TRAFFIC) if res is not None and res.done else None
        if fd is None or vd is None:
            why = "no result for the full model" if fd is None else f"no result for {label}"
            if res is not None and res.status == "unavailable":
                why += " (unavailable)"
            c.checks.append(Check(label, None, why))
            continue
        c.checks.append(Check(label, dominates((fd["C_r"], fd["R_r"]), (vd["C_r"], vd["R_r"])),
                              f"full C_r {fd['C_r']:.1%}, R_r {fd['R_r']:.1f}; {label} C_r {vd['C_r']:.1%}, "
                              f"R_r {vd['R_r']:.1f}"))
    return c


# --------------------------------------------------------------------------------------------- the report


def _rate(budget: dict) -> str:
    """The update rate of a study's budget in words; below Algorithm 1's one update per env step, says so."""
    ratio = budget.get("replay_ratio")
    if ratio is None:  # a study written before replay_ratio
        return f"{budget.get('updates_per_step')} update(s) per acting member per vector step"
    text = f"replay ratio {ratio:g} (gradient steps per env step)"
    if ratio < 1:
        text += f", below Algorithm 1's 1 update per env step (this budget lowers it {1 / ratio:g}x to save time)"
    return text


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "n/a"
    seconds = float(seconds)
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _setting(results: T.Results) -> list[str]:
    state = results.state
    b = state.get("budget_config", {})
    inv = state.get("invocations", [])
    wall = sum(i.get("wall_s") or 0.0 for i in inv)
    job_s = sum((j.get("wall_s") or 0.0) for j in state.get("jobs", {}).values() if j.get("status") == "done")
    counts: dict[str, int] = {}
    for j in state.get("jobs", {}).values():
        counts[j.get("status", "pending")] = counts.get(j.get("status", "pending"), 0) + 1
    m = state.get("machine", {})
    machine = (f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, torch {m.get('torch', '?')}, "
               f"device {m.get('device', '?')}")
    if m.get("gpu"):
        machine += f" ({m['gpu']})"
    last = inv[-1] if inv else {}
    prov = provenance()
    older = sorted({f"{i.get('version')} {i.get('commit') or 'unknown'}" for i in inv if "commit" in i
                    and (i.get("version"), i.get("commit")) != (state.get("version"), state.get("commit"))})
    rates = [r.metrics.get("env_steps_per_s") for r in results if r.metrics and r.metrics.get("env_steps_per_s")]
    lines = [
        f"- **Budget:** `{state.get('budget')}`: {b.get('steps', 0):,} env steps per seed, {b.get('envs')} envs per "
        f"seed, seeds {', '.join(map(str, b.get('seeds', [])))} ({len(b.get('seeds', []))} run(s) per method and "
        f"scene, batched in one process), {b.get('eval_episodes')} deployment episodes per seed and level, Group 1 "
        f"levels {', '.join(b.get('group1_levels', []))}; DQN batch {b.get('batch_size')}, "
        + _rate(b) + f", learning starts at {b.get('learning_starts', 0):,} steps.",
        f"- **Methods:** {', '.join(state['methods']) if state.get('methods') else 'all the study knows'} (not "
        "the paper's Manual baseline: people at the keyboard, `highway-srl play`); jobs: "
        + ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) + ".",
        f"- **Machine:** {machine}; host {m.get('host', '?')}; executor "  # older study.json files say 'backend'
        f"{last.get('executor', last.get('backend', '?'))} with {last.get('jobs', '?')} job(s) at a time.",
        f"- **Wall time:** {_duration(wall)} over {len(inv)} invocation(s) (the last: {_duration(last.get('wall_s'))});"
        f" {_duration(job_s)} of job time in finished jobs"
        + (f"; {sum(rates) / len(rates):,.0f} env-steps/s per training process on average" if rates else "") + ".",
        f"- **Version:** highway-srl {state.get('version')}, commit {state.get('commit') or 'unknown'}"
        + (f" (earlier invocations: {', '.join(older)})" if older else "")
        + (f" (this report written by {prov['version']}, commit {prov['commit'] or 'unknown'})"
           if (prov["version"], prov["commit"]) != (state.get("version"), state.get("commit")) else "")
        + f"; study started {state.get('created')}.",
        f"- **The paper's budget** (`--budget paper`): {BUDGETS['paper'].expected_cost}.",
    ]
    return lines


def table_blocks(t: T.Table, folder: str) -> list[tuple]:
    """A table's heading, the table and where its files are."""
    return [("h2", t.title), ("table", t), ("p", f"Files: `{folder}/{t.name}.csv`, `{folder}/{t.name}.md`.")]


def build_blocks(root: Path, results: T.Results, tables: dict[str, T.Table], figures: list[Path]) -> list[tuple]:
    blocks: list[tuple] = [("h1", "MoE-RM-SRL study: our runs beside the paper")]
    blocks.append(("ul", _setting(results)))
    if results.budget != "paper":
        blocks.append(("p", f"These runs use the `{results.budget}` budget, far below the paper's 5e5 steps x 10 runs "
                            "x 100 episodes: the verdicts below describe these runs only and are no evidence for or "
                            "against the paper."))
    blocks.append(("h2", "The paper's claims, judged on our numbers"))
    for c in claims(results):
        blocks.append(("p", f"**{c.statement}** Verdict: **{c.verdict}**. Criterion: {c.criterion}"))
        blocks.append(("ul", [f"{ch.what}: {_mark(ch.ok)} {ch.detail}" for ch in c.checks]))
    blocks.append(("h2", "Figures"))
    for path in figures:
        if path.suffix == ".png":
            blocks.append(("img", path.relative_to(root).as_posix(), path.stem.replace("_", " ")))
    for name in T.REPORT_TABLES:
        blocks += table_blocks(tables[name], "tables")
    for name in ("training_pareto", "training_curves"):
        blocks += table_blocks(tables[name], "figures")
    for other in results.beyond():
        blocks.append(("h2", f"Beyond the paper: the same study under the `{other.profile}` control profile"))
        blocks.append(("p", f"Not part of the reproduction. The same jobs, traffic and adversary with our safety "
                            f"additions to the mappings on (docs/paper-notes.md, 'Profiles: paper vs safe'); run "
                            f"folders under `runs/{other.profile}/`. The claims above are judged on the paper "
                            "profile only."))
        for name in (*T.REPORT_TABLES, "training_pareto"):
            blocks += table_blocks(tables[f"{name}_{other.profile}"], "tables")
    if "side_by_side" in tables:
        blocks += table_blocks(tables["side_by_side"], "tables")
    not_done = [(job_id, j) for job_id, j in sorted(results.state.get("jobs", {}).items()) if j.get("status") != "done"]
    blocks.append(("h2", "Jobs not done"))
    if not_done:
        blocks.append(("ul", [f"`{job_id}`: {j.get('status')}{': ' + j['message'] if j.get('message') else ''}"
                              + _training_logged(results.root, j) for job_id, j in not_done]))
        blocks.append(("p", "Run the same command again to retry them; finished jobs are kept."))
    else:
        blocks.append(("p", "None: every job finished."))
    return blocks


def _training_logged(root: Path, entry: dict) -> str:
    """How far a job not done has trained, from its scalars.csv (a study running or stopped), else ''."""
    job = Job.from_dict(entry["job"])
    frac = T.job_fraction(root, job)
    return f" ({frac * job.steps:,.0f} of {job.steps:,} env steps logged)" if 0 < frac < 1 else ""


def _mark(ok: bool | None) -> str:
    return {True: "yes.", False: "**no.**", None: "not checked:"}[ok]


def render_markdown(blocks: list[tuple]) -> str:
    out = []
    for kind, *rest in blocks:
        if kind == "h1":
            out.append(f"# {rest[0]}\n")
        elif kind == "h2":
            out.append(f"## {rest[0]}\n")
        elif kind == "p":
            out.append(rest[0] + "\n")
        elif kind == "ul":
            out.append("\n".join(f"- {item.removeprefix('- ')}" for item in rest[0]) + "\n")
        elif kind == "table":
            t = rest[0]
            out.append(t.markdown(heading=False))
        elif kind == "img":
            out.append(f"![{rest[1]}]({rest[0]})\n")
    return "\n".join(out)


def _inline(text: str) -> str:
    s = html.escape(text, quote=False)
    s = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", s)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", s)


def render_html(blocks: list[tuple], root: Path) -> str:
    body = []
    for kind, *rest in blocks:
        if kind in ("h1", "h2"):
            body.append(f"<{kind}>{_inline(rest[0])}</{kind}>")
        elif kind == "p":
            body.append(f"<p>{_inline(rest[0])}</p>")
        elif kind == "ul":
            body.append("<ul>" + "".join(f"<li>{_inline(i.removeprefix('- '))}</li>" for i in rest[0]) + "</ul>")
        elif kind == "table":
            headers, cells = rest[0].formatted()
            rows = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in cells)
            head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
            if rest[0].notes:
                body.append("".join(f"<p class='note'>{_inline(n)}</p>" for n in rest[0].notes))
        elif kind == "img":
            data = base64.b64encode((root / rest[0]).read_bytes()).decode()
            body.append(f"<figure><img alt='{html.escape(rest[1])}' src='data:image/png;base64,{data}'>"
                        f"<figcaption>{html.escape(rest[0])}</figcaption></figure>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}"
             "table{border-collapse:collapse;font-size:85%;margin:0.5em 0}td,th{border:1px solid #ccc;"
             "padding:2px 6px;text-align:left}th{background:#f3f3f3}img{max-width:100%}.note{font-size:85%;"
             "color:#555}code{background:#f3f3f3}")
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>MoE-RM-SRL study</title>"
            f"<style>{style}</style></head><body>" + "\n".join(body) + "</body></html>\n")


def write_report(root: str | Path) -> Path:
    """Tables, figures, report.md and report.html of the study folder `root`; returns report.md's path."""
    root = Path(root)
    results = T.load_results(root)
    tables = T.all_tables(results)
    if results.beyond():  # every printed cell: paper | ours (paper profile) | ours (each other profile)
        tables["side_by_side"] = side_by_side(results)
    for t in tables.values():
        t.write(root / "tables")
    figures, figure_tables = F.all_figures(results, root / "figures")
    tables.update(figure_tables)
    blocks = build_blocks(root, results, tables, figures)
    md = root / "report.md"
    T.write_text(md, render_markdown(blocks))
    T.write_text(root / "report.html", render_html(blocks, root))
    return md
