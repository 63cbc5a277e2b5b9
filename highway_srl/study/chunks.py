"""A study run in seed chunks, read as one: ROOT holds no study.json but several study folders (chunks),
each an ordinary study of the same budget whose settings differ only in their seeds (and profiles), e.g.

  reproduce --budget paper --seeds 0,1,2 --out ROOT/seeds-0-2
  reproduce --budget paper --seeds 3,4,5 --out ROOT/seeds-3-5

Why: a paper-budget job batches its seeds in one process for hours; a machine that is wiped every few hours
finishes a chunk of three seeds where it would not finish ten. A job is the same job across chunks by its id
(profile, scene, variant); its merged result has the union of the seeds of the chunks where it finished:
metrics.json's and eval.json's per-seed entries side by side, the pooled numbers recomputed over all of them
(Wilson for rates, the pooled t interval for means). A seed finished in two chunks of one job is an error,
never counted twice. Everything is read from the chunks' files in a fixed order, so the merged report is the same
bytes each time it is written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.study import stats as S
from highway_srl.study.jobs import Job
from highway_srl.study.results import Result, Results, job_episodes, load_results

STUDY_FILE = "study.json"
SEED_FREE = ("name", "expected_cost", "seeds", "profiles")  # budget settings a chunk may choose for itself
DEPLOY_KEYS = ("episodes", "C_r", "avg_speed", "R_r", "R_s", "adversary")
VERDICTS = "collision_verdicts"  # metrics.json's training collisions by verdict: per_seed and all


@dataclass
class MergedResult(Result):
    """One job over several chunks: its training episodes are every chunk's."""

    folders: list[Path] = field(default_factory=list)

    def episodes(self) -> list[dict]:
        return [e for folder in self.folders for e in job_episodes(folder, self.job)]


def chunk_folders(root: Path) -> list[Path]:
    """The subfolders of root that hold a study, by name."""
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if p.is_dir() and (p / STUDY_FILE).exists())


def load_study(root: str | Path) -> Results:
    """The study of root: its own study.json, else its chunks merged; ValueError if it holds neither."""
    root = Path(root)
    if (root / STUDY_FILE).exists():
        return load_results(root)
    chunks = chunk_folders(root)
    if not chunks:
        raise ValueError(f"{str(root)!r} holds no study (study.json) and no chunk folders with one: start one "
                         "with reproduce --budget ...")
    return merge([load_results(c) for c in chunks], root)


def check_chunks(parts: list[Results], budget: str | None = None) -> None:
    """One-line errors for chunks of different budgets or settings (other than seeds and profiles)."""
    first = parts[0]
    for p in parts:
        name = p.root.name
        if budget is not None and p.budget != budget:
            raise ValueError(f"chunk {name!r} holds a study of budget {p.budget!r}, not {budget!r}")
        if p.budget != first.budget:
            raise ValueError(f"chunks {first.root.name!r} and {name!r} hold studies of budgets {first.budget!r} "
                             f"and {p.budget!r}; one merged report takes one budget")
        mine, theirs = (_settings(q.state) for q in (p, first))
        changed = sorted(k for k in {*mine, *theirs} if mine.get(k) != theirs.get(k))
        if changed:
            raise ValueError(f"chunks {first.root.name!r} and {name!r} differ in {', '.join(changed)}; chunks of "
                             "one study may differ only in seeds and profiles")


def _settings(state: dict) -> dict:
    return {k: v for k, v in state.get("budget_config", {}).items() if k not in SEED_FREE}


def merge(parts: list[Results], root: Path) -> Results:
    """The chunks' studies as one, rooted at root (their parent)."""
    check_chunks(parts)
    found: dict[str, list[tuple[str, Result]]] = {}
    for p in parts:
        for res in sorted(p.every, key=lambda r: r.job.id):
            found.setdefault(res.job.id, []).append((p.root.name, res))
    jobs, results = {}, []
    for job_id in sorted(found):
        _check_seeds(job_id, found[job_id])
        res, entry, rest = _merge_job(found[job_id])
        results.append(res)
        jobs[job_id] = entry
        for name, other in rest:  # the chunks where this job has not finished: listed under "not done"
            jobs[f"{name}/{job_id}"] = {"job": other.job.to_dict(), "status": other.status,
                                        "message": other.message, "chunk": name}
    return Results(root, _merged_state(parts, jobs), results)


def _check_seeds(job_id: str, entries: list[tuple[str, Result]]) -> None:
    """A seed finished in two chunks of one job is an error (a chunk where the job has not finished holds no
    result of its seeds, so it may overlap: it is listed as not done)."""
    owner: dict[int, str] = {}
    for name, res in [(n, r) for n, r in entries if r.done]:
        for seed in res.job.seeds:
            if seed in owner:
                raise ValueError(f"seed {seed} of job {job_id} is in two chunks, {owner[seed]!r} and {name!r}; "
                                 "remove it from one of them")
            owner[seed] = name


def _merge_job(entries: list[tuple[str, Result]]) -> tuple[Result, dict, list[tuple[str, Result]]]:
    """(merged Result, its study.json entry, the chunks where it is not done) of one job id."""
    done = [(n, r) for n, r in entries if r.done]
    rest = [(n, r) for n, r in entries if not r.done]
    use = done or entries[:1]
    seeds = tuple(sorted(s for _, r in use for s in r.job.seeds))
    job = Job.from_dict({**use[0][1].job.to_dict(), "seeds": list(seeds)})
    first = use[0][1]
    res = MergedResult(job, first.status, first.message, first.folder, folders=[r.folder for _, r in use])
    if done:
        res.metrics = merge_metrics([r.metrics for _, r in done])
        res.evaluation = merge_evaluation([r.evaluation for _, r in done])
        res.status = "done"
    entry = {"job": job.to_dict(), "status": res.status, "message": res.message,
             "chunks": [n for n, _ in use], "wall_s": None}
    walls = [r.metrics.get("wall_s") for _, r in done if r.metrics.get("wall_s") is not None]
    if walls:
        entry["wall_s"] = sum(walls)
    return res, entry, rest if done else entries[1:]


def _by_seed(d: dict) -> dict:
    return dict(sorted(d.items(), key=lambda kv: int(kv[0])))


def merge_metrics(parts: list[dict]) -> dict:
    """metrics.json of several chunks of one job: per-seed entries side by side, means over all seeds."""
    if len(parts) == 1:
        return parts[0]
    per_seed = _by_seed({k: v for p in parts for k, v in p["per_seed"].items()})
    mean = {}
    for key in parts[0].get("mean", {}):
        vals = [m[key] for m in per_seed.values() if m.get(key) is not None]
        mean[key] = sum(vals) / len(vals) if vals else None
    rates = [p["env_steps_per_s"] for p in parts if p.get("env_steps_per_s")]
    out = {**parts[0], "per_seed": per_seed, "mean": mean, "seeds": [int(s) for s in per_seed],
           "wall_s": sum(p.get("wall_s") or 0.0 for p in parts),
           "env_steps_per_s": sum(rates) / len(rates) if rates else None,
           "commit": _joined(p.get("commit") for p in parts)}
    out.pop(VERDICTS, None)
    if all(p.get(VERDICTS) for p in parts):  # a chunk trained before the verdicts leaves the job's split unknown
        out[VERDICTS] = {"per_seed": _by_seed({k: v for p in parts for k, v in p[VERDICTS]["per_seed"].items()}),
                         "all": {k: sum(p[VERDICTS]["all"][k] for p in parts) for k in parts[0][VERDICTS]["all"]}}
    return out


def _joined(values) -> str | None:
    """One value if the chunks agree, else each distinct one, comma-separated, in order."""
    distinct = list(dict.fromkeys(v for v in values if v))
    return ", ".join(distinct) if distinct else None


def merge_evaluation(parts: list[dict]) -> dict:
    """eval.json of several chunks of one job: per-seed entries side by side, pooled numbers recomputed."""
    if len(parts) == 1:
        return parts[0]
    levels = {}
    for level in TRAFFIC_LEVELS:
        have = [(p["levels"][level], p.get("trained_seeds") or []) for p in parts if level in p.get("levels", {})]
        if have:
            levels[level] = merge_level(have)
    seeds = sorted(s for p in parts for s in p.get("trained_seeds") or [])
    return {**parts[0], "trained_seeds": seeds, "levels": levels, "commit": _joined(p.get("commit") for p in parts)}


def merge_level(parts: list[tuple[dict, list[int]]]) -> dict:
    """One traffic level over chunks: (level, the chunk's trained seeds) each."""
    per_seed = {}
    for lv, seeds in parts:
        per_seed.update(lv.get("per_seed") or {str(seeds[0]): {k: lv[k] for k in DEPLOY_KEYS if k in lv}})
    per_seed = _by_seed(per_seed)
    seeds = list(per_seed.values())
    out: dict = {"episodes": sum(s["episodes"] for s in seeds)}
    for key in ("C_r", "avg_speed", "R_r", "R_s"):
        if all(key in s for s in seeds):
            out[key] = _pooled(key, [s[key] for s in seeds])
    adversaries = [(s["adversary"], s["episodes"]) for s in seeds if s.get("adversary")]
    if len(adversaries) == len(seeds) and seeds:
        out["adversary"] = {k: sum(a[k] * n for a, n in adversaries) / out["episodes"]
                            for k in adversaries[0][0]}
    censuses = [lv.get("collisions") for lv, _ in parts]
    if all(censuses):
        out["collisions"] = merge_census(censuses)
    out["per_seed"] = per_seed
    return out


def _pooled(key: str, parts: list[dict]) -> dict:
    if key in ("C_r", "R_s"):
        iv = S.wilson(sum(round(p["value"] * p["n"]) for p in parts), sum(p["n"] for p in parts))
        return {"value": iv.mean, "low": iv.low, "high": iv.high, "n": iv.n}
    return S.pooled_mean_interval(parts)


def merge_census(parts: list[dict]) -> dict:
    """The collision censuses of several chunks as one: counts added, speeds at contact weighted by count."""
    out: dict = {"collisions": sum(c["collisions"] for c in parts)}
    for key in ("ego_avoidable", "unavoidable"):  # the verdicts: only where every chunk judged its collisions
        if all(key in c for c in parts):
            out[key] = sum(c[key] for c in parts)
    for key in ("by_kind", "by_detail", "by_decision", "by_reason"):
        if all(key in c for c in parts):
            total: dict[str, int] = {}
            for c in parts:
                for k, v in c[key].items():
                    total[k] = total.get(k, 0) + v
            out[key] = dict(sorted(total.items(), key=lambda kv: -kv[1])) if key != "by_decision" else total
    for key in ("while_ego_changing", "sv_changing", "sv_forced_cut_in"):
        out[key] = sum(c.get(key) or 0 for c in parts)
    for key in ("mean_ego_speed", "mean_sv_speed"):
        have = [(c[key], c["collisions"]) for c in parts if c.get(key) is not None and c["collisions"]]
        weight = sum(n for _, n in have)
        out[key] = round(sum(v * n for v, n in have) / weight, 2) if weight else None
    return out


def _merged_state(parts: list[Results], jobs: dict) -> dict:
    """study.json of the merged study: the chunks' seeds and invocations together, the first chunk's budget."""
    states = [p.state for p in parts]
    config = dict(states[0].get("budget_config", {}))
    config["seeds"] = sorted({s for st in states for s in st.get("budget_config", {}).get("seeds", [])})
    profiles = dict.fromkeys(p for st in states for p in st.get("budget_config", {}).get("profiles", ["paper"]))
    config["profiles"] = sorted(profiles, key=lambda p: p != "paper")  # the reproduction first, as in each chunk
    invocations = [{**i, "chunk": p.root.name} for p in parts for i in p.state.get("invocations", [])]
    methods = [st.get("methods") for st in states]
    return {"kind": "highway-srl study", "budget": states[0].get("budget"), "budget_config": config,
            "created": min(st.get("created") or "" for st in states), "invocations": invocations, "jobs": jobs,
            "methods": None if None in methods else list(dict.fromkeys(m for ms in methods for m in ms)),
            "machine": states[-1].get("machine", {}), "version": _joined(st.get("version") for st in states),
            "commit": _joined(st.get("commit") for st in states),
            "chunks": [{"name": p.root.name, "seeds": p.state.get("budget_config", {}).get("seeds"),
                        "commit": _joined([p.state.get("commit")]  # and every commit a call of it ran
                                          + [i.get("commit") for i in p.state.get("invocations", [])])}
                       for p in parts]}
