"""The device check: one call that tests and benches the GPU and writes one JSON file.

    python scripts/device_check.py                 # on a CUDA machine: about 20 minutes on an H200, two leases
    python scripts/device_check.py --cpu-smoke     # the same parts at toy sizes on the CPU (the test suite runs it)
    python scripts/device_check.py --only sim-,train-moe-rm-srl-10-seeds-compiled   # the parts whose names start so

Parts, in order: the GPU tests; the simulator eager at 4,096 / 65,536 / 262,144 envs (two-lane C) and
level F, merge, adversarial exit at 65,536; training MoE-RM-SRL at 1 and 10 seeds (16 envs each) at
Algorithm 1's update rate (one gradient step per env step), eager (the static, sync-free step: the CUDA
default) and compiled (CUDA graphs, the split step: docs/benchmarks.md), and 4 and 8 eager 10-seed jobs side
by side (the study's jobs sharing the GPU); the simulator compiled, same sizes;
the host's CPU cores: one world of 65,536 envs in a process per core (World(processes=P)) against one
process of all threads; last, if the budget is left, 1 seed compiled with the update rounds unrolled into
one graph. Each part runs in its own process with a time limit from the overall budget, so a failure, a
hang or a part that does not fit still leaves the others' figures and the JSON. Projections: the paper run
(5e5 env steps, one seed) and the whole study (43 jobs x 10 seeds x 5e5 steps, the 10 seeds batched), from
the eager and from the compiled training.

Without a CUDA device it falls back to the smoke run (a note on stderr, "cpu_smoke": true in the JSON).
Needs only torch, numpy and pytest (no gymnasium: the GPU machine has none).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER_STEPS = 500_000
STUDY_JOBS, STUDY_SEEDS = 43, 10
SIM_SIZES = [("two-lane", "C", False, 4096), ("two-lane", "C", False, 65_536), ("two-lane", "C", False, 262_144),
             ("two-lane", "F", False, 65_536), ("merge", "C", False, 65_536), ("exit", "C", True, 65_536)]
TRAIN_ENVS = 16
COPIES = (4, 8)  # training processes side by side on the GPU


def plan(smoke: bool) -> list[dict]:
    """The parts, each {name, cap_s, args} (args for --part)."""
    parts = [{"name": "gpu-tests", "cap_s": 150, "args": ["--part", "tests"]}]
    sizes = [(sc, tr, adv, 2) for sc, tr, adv, _ in SIM_SIZES[-1:]] if smoke else SIM_SIZES
    steps = "1" if smoke else "50"
    for compiled in (False, True):
        if compiled:  # training before the compiled sims: compiling may eat the rest of the budget
            for how in ("eager", "compiled"):
                for seeds in (1, 10):
                    # compiled: the split step (the step, one round per call, the tail: compile_vector_step)
                    # compiled: 172 s (1 seed) and 243 s (10 seeds) of compiling on an H200, cold cache
                    parts.append({"name": train_part(seeds, how), "cap_s": 90 if how == "eager" else 300,
                                  "args": ["--part", "train", "--seeds", str(seeds), "--steps", "1" if smoke else "40"]
                                  + ["--compiled"] * (how == "compiled")})
                if how == "eager":  # jobs side by side on one GPU (reproduce --device cuda --jobs N): does it scale?
                    for copies in (2,) if smoke else COPIES:
                        parts.append({"name": f"{train_part(STUDY_SEEDS, how)}-x{copies}", "cap_s": 120,
                                      "args": ["--part", "train-copies", "--copies", str(copies), "--seeds",
                                               str(STUDY_SEEDS), "--steps", "1" if smoke else "150"]})
        for sc, tr, adv, envs in sizes:
            name = f"sim-{sc}-{tr}{'-adv' if adv else ''}-{envs}-{'compiled' if compiled else 'eager'}"
            args = ["--part", "sim", "--scenario", sc, "--traffic", tr, "--envs", str(envs), "--steps", steps]
            args += ["--adversarial"] * adv + ["--compiled"] * compiled
            parts.append({"name": name, "cap_s": 200 if compiled else 60, "args": args})
    # the host's CPU: a GPU machine's many cores are where World(processes=P) shows how it scales
    parts.append({"name": f"sim-two-lane-C-{4 if smoke else 65_536}-cpu-processes", "cap_s": 90,
                  "args": ["--part", "cpu-processes", "--envs", "4" if smoke else "65536",
                           "--steps", "1" if smoke else "20"]})
    if not smoke:  # the rounds unrolled into one graph (TrainConfig.compile_unrolled), against the split
        # default: one replay per step instead of 1 + rounds; last, as it compiles longest
        parts.append({"name": train_part(1, "compiled") + "-unrolled", "cap_s": 240,
                      "args": ["--part", "train", "--seeds", "1", "--steps", "40", "--compiled", "--unrolled"]})
    return parts


def select(parts: list[dict], only: str) -> list[dict]:
    """The parts whose names start with one of the comma-separated prefixes (all when none is given)."""
    prefixes = [p.strip() for p in only.split(",") if p.strip()]
    chosen = [part for part in parts if not prefixes or part["name"].startswith(tuple(prefixes))]
    if not chosen:
        raise SystemExit(f"device_check: --only {only!r} names no part; the parts: "
                         + ", ".join(part["name"] for part in parts))
    return chosen


def run_part(args) -> dict:
    """One part, in this process; returns its figures."""
    device = "cpu" if args.cpu_smoke else "cuda"
    if args.part == "tests":
        tests = ["tests/sim/test_gpu.py", "tests/agents/test_gpu_update.py", "tests/sim/test_compile.py"]
        # no -q: pyproject's addopts has one, and -qq prints no counts line when all pass
        cmd = [sys.executable, "-m", "pytest", "-x", "-p", "no:cacheprovider", *tests]
        if args.cpu_smoke:
            # a token run of the machinery: one of the cheapest tests there (the graph checks trace for seconds)
            cmd += ["-k", "static_step_is_bit_identical and two-lane-None"]
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        # the counts line ("N passed, M warnings in S s"), not the last line: a warnings summary can end the output
        counts = [line for line in done.stdout.splitlines() if re.search(r"\d+ (passed|failed|error)", line)]
        tail = counts[-1:] or done.stdout.strip().splitlines()[-1:] or [done.stderr.strip()[-300:]]
        return {"returncode": done.returncode, "summary": tail[0]}
    if args.part == "sim":
        from highway_srl.experiments.bench import bench_sim

        how = ("eager" if args.cpu_smoke else True) if args.compiled else False  # smoke: capture, no codegen
        return bench_sim(args.scenario, args.traffic, args.envs, args.steps, device, args.adversarial,
                         warmup=1 if args.cpu_smoke else 10, compile=how)
    if args.part == "cpu-processes":
        return bench_cpu_processes(args.envs, args.steps, args.cpu_smoke)
    if args.part == "train":
        return bench_training(args.seeds, args.steps, device, args.cpu_smoke, args.compiled, args.unrolled)
    if args.part == "train-copies":
        return bench_training_copies(args.copies, args.seeds, args.steps, args.cpu_smoke)
    raise ValueError(f"unknown part {args.part!r}")


def bench_cpu_processes(envs: int, steps: int, smoke: bool) -> dict:
    """The simulator on the CPU, eager: one process with torch's threads against a process per core."""
    from highway_srl.experiments.bench import bench_sim

    cores = 2 if smoke else min(os.cpu_count() or 1, 16)
    one = bench_sim("two-lane", "C", envs, steps, "cpu", warmup=1 if smoke else 3)
    many = bench_sim("two-lane", "C", envs, steps, "cpu", warmup=1 if smoke else 3, processes=cores)
    return {"envs": envs, "processes": cores, "one_process_env_steps_per_s": one["env_steps_per_s"],
            "one_process_threads": one["machine"]["threads"], "processes_env_steps_per_s": many["env_steps_per_s"],
            "over_one_process": round(many["env_steps_per_s"] / one["env_steps_per_s"], 3), "machine": one["machine"]}


def bench_training_copies(copies: int, seeds: int, steps: int, smoke: bool) -> dict:
    """`copies` eager training processes started together, each as the "train" part: their rates while all run.
    aggregate: the sum of the copies' rates; conservative: copies x the slowest (the timed windows overlap only
    roughly: each starts after its own set-up)."""
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / f"copy-{i}.json" for i in range(copies)]
        cmd = [sys.executable, __file__, "--part", "train", "--seeds", str(seeds), "--steps", str(steps)]
        procs = [subprocess.Popen(cmd + ["--part-out", str(out)] + ["--cpu-smoke"] * smoke, cwd=ROOT,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for out in outs]
        errors = [proc.communicate()[1] for proc in procs]
        if any(proc.returncode for proc in procs):
            raise RuntimeError("a copy failed: " + next(e for p, e in zip(procs, errors) if p.returncode)[-800:])
        rates = [json.loads(out.read_text())["env_steps_per_s"] for out in outs]
    return {"copies": copies, "seeds": seeds, "envs": TRAIN_ENVS, "vector_steps": steps, "env_steps_per_s": rates,
            "aggregate_env_steps_per_s": round(sum(rates), 1),
            "conservative_env_steps_per_s": round(copies * min(rates), 1)}


def train_part(seeds: int, how: str) -> str:
    return f"train-moe-rm-srl-{seeds}-seeds" + ("-compiled" if how == "compiled" else "")


def bench_training(seeds: int, steps: int, device: str, smoke: bool, compiled: bool, unrolled: bool = False) -> dict:
    """Env-steps/s of MoE-RM-SRL training, TRAIN_ENVS envs per seed, at one gradient step per env step
    (replay_ratio 1), in the static step: eager or compiled (smoke: graph capture only, aot_eager).
    setup_s: building, filling the buffers to a batch and the warm-up steps, compilation included."""
    from highway_srl.experiments.train import bench_train_form

    # smoke: 1 env (one masked update round a step), batches of 2 (buffers filled after one step) and
    # buffers of 16 rows (not 100,000 rows x 11 members x 10 seeds: 3.4 GB), or the 10 seeds cost minutes
    envs, batch, capacity = (1, 2, 16) if smoke else (TRAIN_ENVS, 256, None)
    how = ("aot_eager" if smoke else True) if compiled else False
    form = bench_train_form("moe-rm-srl", "two-lane", "C", envs, steps, device, seeds, how, True, batch, capacity,
                            unrolled)
    return {"method": "moe-rm-srl", "envs": envs, "seeds": seeds, "vector_steps": steps,
            "wall_s": form["wall_s"], "setup_s": form["warmup_s"], "env_steps_per_s": form["env_steps_per_s"],
            "env_steps_per_s_with_compile": form["env_steps_per_s_with_compile"], "compile": how, "static": True,
            "replay_ratio": 1.0, "batch_size": batch, "unrolled": unrolled}


def projections(results: dict) -> dict:
    """Minutes for the paper run and hours for the study, from the training figures (None where missing):
    under "eager" and "compiled", and at the top level from the faster of the two."""
    out = {"paper_run_steps": PAPER_STEPS, "study": f"{STUDY_JOBS} jobs x {STUDY_SEEDS} seeds x {PAPER_STEPS} steps"}
    rate = lambda seeds, how: results.get(train_part(seeds, how), {}).get("result", {}).get("env_steps_per_s")  # noqa: E731
    best = {}
    for how in ("eager", "compiled"):
        one, ten = rate(1, how), rate(10, how)
        out[how] = {"paper_run_min": round(PAPER_STEPS / one / 60, 2) if one else None,
                    "ten_seeds_min": round(STUDY_SEEDS * PAPER_STEPS / ten / 60, 2) if ten else None,
                    "study_h": round(STUDY_JOBS * STUDY_SEEDS * PAPER_STEPS / ten / 3600, 2) if ten else None}
        f = out[how]
        f["ten_seeds_cost_vs_one"] = round(f["ten_seeds_min"] / f["paper_run_min"], 2) if one and ten else None
        for key in ("paper_run_min", "ten_seeds_min", "study_h"):
            if f[key] is not None and (best.get(key) is None or f[key] < best[key]):
                best[key] = f[key]
    out.update({key: best.get(key) for key in ("paper_run_min", "ten_seeds_min", "study_h")})
    for copies in COPIES:  # the study with `copies` jobs side by side, eager, at the conservative rate
        rate_n = results.get(f"{train_part(STUDY_SEEDS, 'eager')}-x{copies}", {}).get("result", {})
        rate_n = rate_n.get("conservative_env_steps_per_s")
        out[f"eager_x{copies}_study_h"] = round(STUDY_JOBS * STUDY_SEEDS * PAPER_STEPS / rate_n / 3600, 2) if rate_n else None
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=None, help="JSON path (default: $OUT/device_check.json, else ./device_check.json)")
    p.add_argument("--cpu-smoke", action="store_true", help="toy sizes on the CPU: checks the script, not a device")
    p.add_argument("--budget-s", type=float, default=450.0, help="wall-clock budget of all parts together")
    p.add_argument("--only", default="", help="comma-separated name prefixes: run only the parts whose names start "
                   "with one (a later lease measures what an earlier one left; the names are the JSON's keys)")
    p.add_argument("--part", help=argparse.SUPPRESS)
    p.add_argument("--part-out", help=argparse.SUPPRESS)
    for name in ("--scenario", "--traffic"):
        p.add_argument(name, help=argparse.SUPPRESS)
    for name in ("--envs", "--steps", "--seeds", "--copies"):
        p.add_argument(name, type=int, help=argparse.SUPPRESS)
    p.add_argument("--adversarial", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--compiled", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--unrolled", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))

    if args.part:
        result = run_part(args)
        Path(args.part_out).write_text(json.dumps(result))
        return 0

    if not args.cpu_smoke:
        import torch

        if not torch.cuda.is_available():
            print("device_check: no CUDA device here: the smoke run on the CPU instead (checks the script, "
                  "not a device)", file=sys.stderr)
            args.cpu_smoke = True
    default_dir = os.environ.get("OUT") or "."
    out = Path(args.out or Path(default_dir) / "device_check.json")
    start = time.perf_counter()
    report = {"started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "cpu_smoke": args.cpu_smoke,
              "commit": _commit(), "parts": {}}
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    with tempfile.TemporaryDirectory() as tmp:
        for part in select(plan(args.cpu_smoke), args.only):
            left = args.budget_s - (time.perf_counter() - start)
            limit = min(part["cap_s"], left)
            if limit < 10:
                report["parts"][part["name"]] = {"status": "skipped", "why": "budget spent"}
                continue
            part_out = Path(tmp) / f"{part['name']}.json"
            cmd = [sys.executable, __file__, *part["args"], "--part-out", str(part_out)]
            cmd += ["--cpu-smoke"] * args.cpu_smoke
            t0 = time.perf_counter()
            # its own process group: a part that times out goes with whatever it started (train-copies' copies)
            proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    start_new_session=True)
            try:
                _, stderr = proc.communicate(timeout=limit)
                entry = {"status": "ok" if proc.returncode == 0 else "failed"}
                if proc.returncode == 0:
                    entry["result"] = json.loads(part_out.read_text())
                else:
                    entry["error"] = stderr.strip()[-1500:]
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.communicate()
                entry = {"status": "timeout", "limit_s": round(limit, 1)}
            except Exception as err:  # noqa: BLE001 (one failure must still leave the JSON)
                entry = {"status": "failed", "error": f"{type(err).__name__}: {err}"}
            entry["wall_s"] = round(time.perf_counter() - t0, 2)
            report["parts"][part["name"]] = entry
            print(f"{part['name']}: {entry['status']} ({entry['wall_s']} s)", file=sys.stderr, flush=True)
    report["projections"] = projections(report["parts"])
    report["wall_s"] = round(time.perf_counter() - start, 1)
    text = json.dumps(report, indent=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp_path = out.with_name(out.name + ".tmp")
    tmp_path.write_text(text)
    tmp_path.replace(out)  # atomic: a reader never sees half a file
    print(text)
    return 0


def _commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip() or None
    except OSError:
        return None


if __name__ == "__main__":
    sys.exit(main())
