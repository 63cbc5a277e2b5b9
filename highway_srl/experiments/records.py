"""One schema for the run-folder files read back: episodes.jsonl, scalars.csv, metrics.json, eval.json
(config.json: TrainConfig.from_dict and runs.train_config; the resume checkpoint: train.py).

Each reader checks every field's type, range and finiteness and raises ValueError in one line naming the
file (and line) and the field: the CLI's one-line error, exit status 2. A damaged line is never skipped:
the reader stops there, or, where the caller allows it (train --resume --drop-damaged), keeps the rows
before it and says how many it dropped. The one exception is the text after a file's last newline, a line
an interrupted append cut short: it is dropped and the caller is told so (the note).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from highway_srl.experiments.runs import is_finite_number, is_int, read_json, read_text

# kinds of field: count (integer >= 0), number (finite), fraction (finite, 0-1), bool, text; "?" allows null
KINDS = {"count": ("a non-negative integer", lambda v: is_int(v) and v >= 0),
         "number": ("a finite number", is_finite_number),
         "fraction": ("a number from 0 to 1", lambda v: is_finite_number(v) and 0 <= v <= 1),
         "bool": ("true or false", lambda v: isinstance(v, bool)),
         "text": ("a string", lambda v: isinstance(v, str))}


def check_fields(obj, spec: dict[str, str], where: str, optional: tuple[str, ...] = ()) -> dict:
    """obj, a JSON object holding each field of spec (name -> kind) of its kind; ValueError naming the first
    field that is missing or wrong (where: the file and the path to obj)."""
    if not isinstance(obj, dict):
        raise ValueError(f"{where} must be a JSON object, got {_shown(obj)}")
    for name, kind in spec.items():
        if name not in obj:
            if name in optional:
                continue
            raise ValueError(f"{where}: {name} is missing")
        value, nullable = obj[name], kind.endswith("?")
        words, ok = KINDS[kind.rstrip("?")]
        if not ((nullable and value is None) or ok(value)):
            raise ValueError(f"{where}: {name} must be {words}{' or null' if nullable else ''}, got {_shown(value)}")
    return obj


def check_lists(obj: dict, spec: dict[str, str], where: str) -> None:
    """Each list of spec (name -> kind of its items) that obj holds is a JSON list of items of that kind."""
    for name, kind in spec.items():
        items = obj.get(name, [])
        words, ok = KINDS[kind]
        if not isinstance(items, list) or not all(ok(item) for item in items):
            raise ValueError(f"{where}: {name} must be a JSON list, each item {words}, got {_shown(items)}")


def _shown(value) -> str:
    text = json.dumps(value) if not isinstance(value, float) or math.isfinite(value) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


# ------------------------------------------------------------------ episodes.jsonl
EPISODE_FIELDS = {"seed": "count", "step": "count", "return": "number", "length": "count", "collision": "bool",
                  "avg_speed": "number", "success": "bool", "deploy_reward": "number", "rm_return": "number"}
EPISODE_OPTIONAL = ("rm_return",)  # logs written before it existed


def episode_row(line: str, seeds, max_step: int) -> dict:
    """One line of a training run's episodes.jsonl, checked; ValueError saying what is wrong with it."""
    try:
        row = json.loads(line)
    except json.JSONDecodeError as err:
        raise ValueError(f"not JSON ({err.msg})") from None
    check_fields(row, EPISODE_FIELDS, "the row", EPISODE_OPTIONAL)
    if row["seed"] not in seeds:
        raise ValueError(f"seed {row['seed']} is not one of the run's seeds {list(seeds)}")
    if not 1 <= row["step"] <= max_step:
        raise ValueError(f"step {row['step']} is outside 1-{max_step}")
    return row


def read_episode_log(path: Path, seeds, max_step: int, drop_damaged: bool = False) -> tuple[list[dict], str | None]:
    """(rows, note) of a training run's episodes.jsonl, every row checked (episode_row). A damaged line is a
    ValueError with its number, or with drop_damaged the end of the log: the rows before it are kept and the
    note says how many were dropped. note also tells of a cut-off last line (dropped); None: nothing was."""
    if not path.exists():
        return [], None
    lines = read_text(path).split("\n")
    torn = lines.pop()  # after the last newline: "" unless the last append was cut short
    rows = []
    for n, line in enumerate(lines, 1):
        try:
            rows.append(episode_row(line, seeds, max_step))
        except ValueError as err:
            if not drop_damaged:
                raise ValueError(f"{path} line {n} is damaged: {err}; nothing was changed (train --resume "
                                 f"--drop-damaged keeps the {n - 1} rows before it)") from None
            dropped = len(lines) - n + 1 + bool(torn)
            return rows, f"{path}: dropped {dropped} row(s) from line {n} on, where it is damaged ({err})"
    return rows, (f"{path}: dropped its cut-off last line (an interrupted write)" if torn else None)


# ------------------------------------------------------------------ scalars.csv
def scalar_rows(path: Path, keep_until: int, drop_damaged: bool = False) -> tuple[list[str], list[list[str]], str | None]:
    """(header, rows up to env step keep_until, note) of a run's scalars.csv, every row checked: as many cells
    as the header, env_steps an increasing integer, every other cell empty or a finite number. Damage and
    the note as in read_episode_log. The columns are training_log.TrainingLog's: env_steps first, the others read
    by the header's names (a newer version appends columns, such as mean_length, lr and updates; a run
    started by an older one lacks them)."""
    lines = read_text(path).split("\n")
    torn = lines.pop()
    header = lines[0].split(",") if lines else []
    if not header or header[0] != "env_steps" or not all(header):
        raise ValueError(f"{path} line 1 is not scalars.csv's header (env_steps,...): {_shown(lines[0] if lines else '')}")
    rows, last = [], -1
    for n, line in enumerate(lines[1:], 2):
        cells = line.split(",")
        problem = _scalar_problem(cells, header, last)
        if problem is not None:
            if not drop_damaged:
                raise ValueError(f"{path} line {n} is damaged: {problem}; nothing was changed (train --resume "
                                 f"--drop-damaged keeps the rows before it)")
            return header, rows, f"{path}: dropped the rows from line {n} on, where it is damaged ({problem})"
        last = int(cells[0])
        if last <= keep_until:
            rows.append(cells)
    return header, rows, (f"{path}: dropped its cut-off last line (an interrupted write)" if torn else None)


def _scalar_problem(cells: list[str], header: list[str], last: int) -> str | None:
    """What is wrong with one scalars.csv row (None: nothing)."""
    if len(cells) != len(header):
        return f"{len(cells)} cells under a header of {len(header)}"
    if not cells[0].isdigit() or int(cells[0]) <= last:
        return f"env_steps {_shown(cells[0])} is not an integer above the row before's"
    for name, cell in zip(header[1:], cells[1:]):
        try:
            if cell and not math.isfinite(float(cell)):
                return f"{name} is {cell}"
        except ValueError:
            return f"{name} is not a number: {_shown(cell)}"
    return None


# ------------------------------------------------------------------ metrics.json, eval.json
SEED_METRICS = {"episodes": "count", "T_c": "fraction?", "T_r": "number?", "T_r_rm": "number?",
                "rise_time_steps": "count?", "rise_time_range_steps": "count?"}
MEAN_METRICS = {"T_c": "fraction?", "T_r": "number?", "T_r_rm": "number?", "rise_time_steps": "number?",
                "rise_time_range_steps": "number?", "avg_speed": "number?"}
RUN_METRICS = {"method": "text", "scenario": "text", "env_steps_per_seed": "count", "wall_s": "number",
               "env_steps_per_s": "number"}


def read_metrics(path: Path) -> dict:
    """A run's metrics.json (train.training_metrics and the run's settings), every field used checked."""
    data = check_fields(read_json(path), RUN_METRICS, str(path))
    for name in ("per_seed", "mean"):
        if not isinstance(data.get(name), dict):
            raise ValueError(f"{path}: {name} must be a JSON object, got {_shown(data.get(name))}")
    if not data["per_seed"]:
        raise ValueError(f"{path}: per_seed is empty (a finished run has one entry per trained seed)")
    for seed, values in seed_keyed(data["per_seed"], f"{path}: per_seed").items():
        check_fields(values, SEED_METRICS, f"{path}: per_seed.{seed}")
    check_fields(data["mean"], MEAN_METRICS, f"{path}: mean", tuple(MEAN_METRICS))
    if "collision_verdicts" in data:  # runs trained before the verdicts have none
        verdicts = check_fields(data["collision_verdicts"], {}, f"{path}: collision_verdicts")
        check_fields(verdicts.get("all"), VERDICT_COUNTS, f"{path}: collision_verdicts.all")
    return data


# train.collision_verdicts: the training collisions split by the ego-avoidable verdict (rules.avoidable)
VERDICT_COUNTS = {"collisions": "count", "ego_avoidable": "count", "unavoidable": "count", "not_judged": "count"}


ESTIMATE = {"value": "number", "low": "number", "high": "number"}
RATE = {"value": "fraction", "low": "fraction", "high": "fraction"}


def read_eval(path: Path) -> dict:
    """An evaluation's JSON (evaluate.evaluate_run's report), every level's estimates checked."""
    data = check_fields(read_json(path), {"method": "text", "scenario": "text", "episodes_per_level": "count"}, str(path))
    if not isinstance(data.get("levels"), dict) or not data["levels"]:
        raise ValueError(f"{path}: levels must be a non-empty JSON object, got {_shown(data.get('levels'))}")
    if data.get("trained_seeds") is not None:  # optional: evaluations of runs written before it existed
        check_lists(data, {"trained_seeds": "count"}, str(path))
    for level, values in data["levels"].items():
        check_level(values, f"{path}: levels.{level}")
        per_seed = values.get("per_seed")
        if per_seed is not None and not isinstance(per_seed, dict):
            raise ValueError(f"{path}: levels.{level}.per_seed must be a JSON object or null, got {_shown(per_seed)}")
        for seed, part in seed_keyed(per_seed or {}, f"{path}: levels.{level}.per_seed").items():
            check_level(part, f"{path}: levels.{level}.per_seed.{seed}")
    return data


def seed_keyed(mapping: dict, where: str) -> dict:
    """mapping, whose keys name seeds ("0", "1", ...); ValueError naming the first key that does not."""
    for key in mapping:
        if not key.isdigit():
            raise ValueError(f"{where}: {_shown(key)} is not a seed (a non-negative integer)")
    return mapping


def check_level(values, where: str) -> None:
    """One level of an evaluation: episodes, C_r (a rate), avg_speed, R_r and, where reported, R_s."""
    check_fields(values, {"episodes": "count"}, where)
    for name, spec in (("C_r", RATE), ("avg_speed", ESTIMATE), ("R_r", ESTIMATE), ("R_s", RATE)):
        if name != "R_s" or name in values:
            check_fields(values.get(name), spec, f"{where}.{name}")
    if values.get("collisions") is not None:  # the census; its verdicts since they were judged
        check_fields(values["collisions"], CENSUS_COUNTS, f"{where}.collisions", ("ego_avoidable", "unavoidable"))


CENSUS_COUNTS = {"collisions": "count", "ego_avoidable": "count", "unavoidable": "count"}
