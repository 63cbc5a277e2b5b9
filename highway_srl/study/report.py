"""report.md and report.html of a study folder: setting, the paper's claims judged on our numbers, every
table and figure, and the jobs that did not finish.

The claims are judged by code from the tables' numbers, never written by hand (verdicts.py, with the seed
as the unit). A folder of seed chunks (chunks.py) gets one report over all of them, written in the same bytes
each time from the same records: it names the chunks' commits, not the commit of the code writing it.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from highway_srl.study import chunks
from highway_srl.study.causes import INTRO, TITLE, causes
from highway_srl.study import figures as F
from highway_srl.study import seed_tables as ST
from highway_srl.study import tables as T
from highway_srl.study.results import Results, job_fraction
from highway_srl.study.table import Table, write_text
from highway_srl.study.side_by_side import headline, side_by_side
from highway_srl.experiments.runs import provenance
from highway_srl.study.jobs import BUDGETS, Job
from highway_srl.study.verdicts import Claim, claims, promise_claim

# The results page (docs/results.md) carries summary.md between these lines: `reproduce --report-only --page`
PAGE_BEGIN = "<!-- begin: the study's summary.md, written by `highway-srl reproduce --report-only --page` -->"
PAGE_END = "<!-- end: the study's summary.md -->"

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


def _setting(results: Results, progress: Table | None) -> list[str]:
    state = results.state
    b = state.get("budget_config", {})
    inv = state.get("invocations", [])
    wall = sum(i.get("wall_s") or 0.0 for i in inv)
    ended = sum(i.get("wall_s") is not None for i in inv)
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
    rates = [r.metrics.get("env_steps_per_s") for r in results if r.metrics and r.metrics.get("env_steps_per_s")]
    lines = [
        f"- **Budget:** `{state.get('budget')}`: {b.get('steps', 0):,} env steps per seed, {b.get('envs')} envs per "
        f"seed, seeds {', '.join(map(str, b.get('seeds', [])))} ({len(b.get('seeds', []))} run(s) per method and "
        f"scene, batched in one process{' per chunk' if 'chunks' in state else ''}), {b.get('eval_episodes')} deployment episodes per seed and level, Group 1 "
        f"levels {', '.join(b.get('group1_levels', []))}; DQN batch {b.get('batch_size')}, "
        + _rate(b) + f", learning starts at {b.get('learning_starts', 0):,} steps.",
        f"- **Methods:** {', '.join(state['methods']) if state.get('methods') else 'all the study knows'} (not "
        "the paper's Manual baseline: people at the keyboard, `highway-srl play`); jobs: "
        + ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) + ".",
        f"- **Machine:** {machine}; host {m.get('host', '?')}; executor "  # older study.json files say 'backend'
        f"{last.get('executor', last.get('backend', '?'))} with {last.get('jobs', '?')} job(s) at a time.",
        f"- **Wall time:** {_duration(wall)} in the {ended} of {len(inv)} invocation(s) that ended (one stopped by"
        f" a kill or a reboot records none; the last: {_duration(last.get('wall_s'))});"
        f" {_duration(job_s)} of job time in finished jobs"
        + (f"; {sum(rates) / len(rates):,.0f} env-steps/s per training process on average" if rates else "") + ".",
        _version(state),
        *([f"- **Progress:** {progress.notes[0].removesuffix('.')} (`tables/progress.md`)."] if progress else []),
        f"- **The paper's budget** (`--budget paper`): {BUDGETS['paper'].expected_cost}.",
    ]
    return lines


def _version(state: dict) -> str:
    """The code that made the study: its commit (and earlier invocations' and the report writer's, if other);
    for a chunked study each chunk's seeds and commit, and nothing that changes when the report is rewritten."""
    if "chunks" in state:
        return ("- **Chunks:** " + "; ".join(
            f"`{c['name']}/` (seeds {', '.join(map(str, c.get('seeds') or []))}; commit {c.get('commit') or 'unknown'})"
            for c in state["chunks"]) + f"; highway-srl {state.get('version')}; first study started "
            f"{state.get('created')}. This report merges them (`reproduce --report-only` on this folder).")
    inv, prov = state.get("invocations", []), provenance()
    older = sorted({f"{i.get('version')} {i.get('commit') or 'unknown'}" for i in inv if "commit" in i
                    and (i.get("version"), i.get("commit")) != (state.get("version"), state.get("commit"))})
    return (f"- **Version:** highway-srl {state.get('version')}, commit {state.get('commit') or 'unknown'}"
            + (f" (earlier invocations: {', '.join(older)})" if older else "")
            + (f" (this report written by {prov['version']}, commit {prov['commit'] or 'unknown'})"
               if (prov["version"], prov["commit"]) != (state.get("version"), state.get("commit")) else "")
            + f"; study started {state.get('created')}.")


def table_blocks(t: Table, folder: str) -> list[tuple]:
    """A table's heading, the table and where its files are."""
    return [("h2", t.title), ("table", t), ("p", f"Files: `{folder}/{t.name}.csv`, `{folder}/{t.name}.md`.")]


def claim_blocks(c: Claim, criterion: bool = True) -> list[tuple]:
    """A claim's statement, verdict and (unless criterion is False) criterion, then one line per check."""
    return [("p", f"**{c.statement}** Verdict: **{c.verdict}**." + (f" Criterion: {c.criterion}" if criterion else "")),
            ("ul", [f"{ch.what}: {_mark(ch.ok)} {ch.detail}" for ch in c.checks])]


def summary_blocks(results: Results, tables: dict[str, Table], judged: list[Claim],
                   promises: list[Claim], why: list[str]) -> list[tuple]:
    """summary.md: the report's setting lines, MoE-RM-SRL's printed cells side by side, every verdict with its
    checks (criteria: the report's) and the likely causes of the gaps, for the results page to carry word for
    word."""
    setting = [line for line in _setting(results, tables.get("progress"))
               if line.startswith(("- **Budget:**", "- **Chunks:**", "- **Progress:**"))]
    blocks: list[tuple] = [("ul", setting)]
    if results.beyond():
        t = headline(results)
        blocks += [("p", f"**{t.title}** (every method: `tables/side_by_side.md`)"), ("table", t)]
    for c in (*judged, *promises):
        blocks += claim_blocks(c, criterion=False)
    return blocks + [("p", f"**{TITLE}.** {INTRO}"), ("ul", why)]


def build_blocks(root: Path, results: Results, tables: dict[str, Table], figures: list[Path],
                 judged: list[Claim], promises: list[Claim], why: list[str]) -> list[tuple]:
    blocks: list[tuple] = [("h1", "MoE-RM-SRL study: our runs beside the paper")]
    blocks.append(("ul", _setting(results, tables.get("progress"))))
    if results.budget != "paper":
        blocks.append(("p", f"These runs use the `{results.budget}` budget, far below the paper's 5e5 steps x 10 runs "
                            "x 100 episodes: the verdicts below describe these runs only and are no evidence for or "
                            "against the paper."))
    blocks.append(("h2", "The paper's claims, judged on our numbers"))
    for c in judged:
        blocks += claim_blocks(c)
    blocks += [("h2", TITLE), ("p", INTRO), ("ul", why)]
    blocks.append(("h2", "Beyond the paper: the promise, collision by collision"))
    blocks.append(("p", "The paper's promise of driving without collisions, judged as our safe profile states it "
                        "(docs/paper-notes.md, 'Ego-avoidable collisions'): the paper profile is the printed "
                        "equations' reference, each other profile ours."))
    for c in promises:
        blocks += claim_blocks(c)
    blocks.append(("h2", "Figures"))
    for path in figures:
        if path.suffix == ".png":
            blocks.append(("img", path.relative_to(root).as_posix(), path.stem.replace("_", " ")))
    for name in T.REPORT_TABLES:
        blocks += table_blocks(tables[name], "tables")
    for name in ("training_pareto", "training_curves"):
        blocks += table_blocks(tables[name], "figures")
    for name in ("seed_intervals", "seeds"):
        blocks += table_blocks(tables[name], "tables")
    for other in results.beyond():
        blocks.append(("h2", f"Beyond the paper: the same study under the `{other.profile}` control profile"))
        blocks.append(("p", f"Not part of the reproduction. The same jobs, traffic and adversary with our safety "
                            f"additions to the mappings on (docs/paper-notes.md, 'Profiles: paper vs safe'); run "
                            f"folders under `runs/{other.profile}/`. The claims above are judged on the paper "
                            "profile only."))
        for name in (*T.REPORT_TABLES, "training_pareto", "seed_intervals", "seeds"):
            blocks += table_blocks(tables[f"{name}_{other.profile}"], "tables")
    if "side_by_side" in tables:
        blocks += table_blocks(tables["side_by_side"], "tables")
    if "progress" in tables:
        blocks += table_blocks(tables["progress"], "tables")
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
    chunk = entry.get("chunk") or (entry.get("chunks") or ["."])[0]  # a chunked study: the job's own chunk
    frac = job_fraction(root / chunk, job)
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


def seed_tables(results: Results) -> dict[str, Table]:
    """The seed-as-unit tables of the reproduction, then of each other profile as NAME_PROFILE."""
    out = {"seed_intervals": ST.intervals_table(results), "seeds": ST.seeds_table(results)}
    progress = ST.progress_table(results)
    if progress is not None:
        out["progress"] = progress
    for other in results.beyond():
        for t in (ST.intervals_table(other), ST.seeds_table(other)):
            t.name, t.title = f"{t.name}_{other.profile}", f"Beyond the paper ({other.profile} profile): {t.title}"
            out[t.name] = t
    return out


def write_report(root: str | Path) -> Path:
    """Tables, figures, report.md and report.html of the study folder `root`; returns report.md's path."""
    root = Path(root)
    results = chunks.load_study(root)
    tables = T.all_tables(results)
    tables.update(seed_tables(results))
    if results.beyond():  # every printed cell: paper | ours (paper profile) | ours (each other profile)
        tables["side_by_side"] = side_by_side(results)
    for t in tables.values():
        t.write(root / "tables")
    figures, figure_tables = F.all_figures(results, root / "figures")
    tables.update(figure_tables)
    judged, promises = claims(results), [promise_claim(r) for r in (results, *results.beyond())]
    why = causes(results)
    blocks = build_blocks(root, results, tables, figures, judged, promises, why)
    md = root / "report.md"
    write_text(md, render_markdown(blocks))
    write_text(root / "report.html", render_html(blocks, root))
    write_text(root / "summary.md", render_markdown(summary_blocks(results, tables, judged, promises, why)))
    return md


def write_page(page: str | Path, summary: str) -> None:
    """Put `summary` between PAGE_BEGIN and PAGE_END of the Markdown file `page`, leaving the rest as it is."""
    page = Path(page)
    if not page.is_file():
        raise ValueError(f"--page {str(page)!r} is not a file")
    lines = page.read_text().split("\n")
    if lines.count(PAGE_BEGIN) != 1 or lines.count(PAGE_END) != 1 or lines.index(PAGE_BEGIN) > lines.index(PAGE_END):
        raise ValueError(f"--page {str(page)!r} needs one line '{PAGE_BEGIN}' and, after it, one line '{PAGE_END}': "
                         "the summary goes between them")
    start, end = lines.index(PAGE_BEGIN), lines.index(PAGE_END)
    write_text(page, "\n".join(lines[:start + 1] + ["", summary.rstrip("\n"), ""] + lines[end:]))
