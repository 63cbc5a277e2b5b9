"""Run folders: config, logs, checkpoints and metrics, written atomically; provenance recorded."""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

from highway_srl import __version__
from highway_srl.agents.checkpoint import write_atomic


def commit() -> str | None:
    """The git commit of the installed source tree, if it is a checkout."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True, timeout=5).stdout.strip()
    return out.stdout.strip() + ("-dirty" if dirty else "")


def provenance() -> dict:
    return {"version": __version__, "commit": commit()}


def write_json(path: Path, data) -> None:
    """Write JSON atomically (temp file in the same folder, fsync, rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, (json.dumps(data, indent=2, default=str) + "\n").encode())


def read_json(path: Path) -> dict:
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not valid JSON ({err.msg} at line {err.lineno})") from None


def open_state(root: Path, name: str, what: str) -> dict | None:
    """The state file `name` of a study folder, None if the folder is new (empty or missing); one-line
    errors for a damaged file or a folder that holds something else."""
    path = root / name
    if path.exists():
        try:
            return read_json(path)
        except ValueError as err:
            raise ValueError(f"{path} is damaged ({err}); move it away to start afresh") from None
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise ValueError(f"--out {str(root)!r} exists and holds no {what} ({name}); choose an empty or new folder")
    return None


def run_folder(path: str | Path) -> Path:
    p = Path(path)
    if not p.is_dir():
        raise FileNotFoundError(f"run folder {str(p)!r} does not exist")
    if not (p / "config.json").exists():
        raise ValueError(f"{str(p)!r} is not a run folder (no config.json)")
    return p


def append_jsonl(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    with open(path, "a") as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_jsonl(path: Path) -> list[dict]:
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if line:
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                break  # a torn last line from an interrupted run
    return rows


def truncate_jsonl(path: Path, keep) -> None:
    """Keep only rows for which keep(row) is true (resuming drops episodes logged after the checkpoint)."""
    rows = [r for r in read_jsonl(path) if keep(r)]
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
    os.replace(tmp, path)
