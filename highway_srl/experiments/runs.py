"""Run folders: config, logs, checkpoints and metrics, written atomically; provenance recorded."""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import subprocess
import tomllib
from pathlib import Path

from highway_srl import __version__
from highway_srl.agents.checkpoint import naming, write_atomic
from highway_srl.agents.train_config import TrainConfig


def _git(folder: Path, *args: str) -> str | None:
    """git's output in folder (stripped), None if git is missing, fails or the folder is no checkout.
    GIT_OPTIONAL_LOCKS=0: `git status` reads the checkout without refreshing its index, so it never takes
    index.lock (which a git command of the user's would then find, and which a full disk would leave)."""
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    try:
        out = subprocess.run(["git", "-C", str(folder), *args], capture_output=True, text=True, timeout=5, env=env)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def is_own_checkout(top: Path, package: Path) -> bool:
    """Whether the git top level `top` is a highway-srl source tree holding the imported `package` itself:
    its pyproject.toml names highway-srl and the package lies at top/highway_srl. A wheel installed into a
    user's own repository (a virtual environment inside it) is no such tree: that HEAD is not our code."""
    try:
        name = tomllib.loads((top / "pyproject.toml").read_text()).get("project", {}).get("name")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return name == "highway-srl" and (top / "highway_srl").resolve() == package


def commit(package: Path | None = None) -> str | None:
    """The git commit of the highway-srl checkout the package (default: the imported one) was loaded from,
    "-dirty" appended if tracked files differ from it; None when it was not loaded from one (is_own_checkout)."""
    package = (package or Path(__file__).resolve().parents[1]).resolve()
    top = _git(package, "rev-parse", "--show-toplevel")
    if top is None or not is_own_checkout(Path(top), package):
        return None
    head = _git(package, "rev-parse", "HEAD")
    if head is None:
        return None
    dirty = _git(package, "status", "--porcelain", "--untracked-files=no")
    return head + ("-dirty" if dirty else "")


def provenance() -> dict:
    """The version, and the commit where the code runs from a highway-srl checkout (else null: commit)."""
    return {"version": __version__, "commit": commit()}


def default_threads(requested: int | None = None) -> int:
    """Intra-op threads for a process that steps the simulator or trains: `requested` (--threads), else
    OMP_NUM_THREADS, else one. Why one: the CPU step is ~1,500 small operations, each an OpenMP region that
    waits for its slowest thread; with a second thread and another process busy on the cores, bench sim at
    4,096 envs fell 20-35x (docs/benchmarks.md), while one thread loses only ~1.1x on an idle machine.
    Parallelism comes from processes (--jobs, --processes), each with this many threads."""
    if requested is not None:
        return requested
    env = os.environ.get("OMP_NUM_THREADS", "")
    return int(env) if env.isdigit() and int(env) > 0 else 1


def write_json(path: Path, data, replace: bool = True) -> None:
    """Write JSON atomically (temp file in the same folder, fsync, rename; replace=False: never over a file
    that exists, checkpoint.publish)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, (json.dumps(data, indent=2, default=str) + "\n").encode(), replace)


def is_int(value) -> bool:
    """A JSON integer (a bool is not one)."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_finite_number(value) -> bool:
    """A JSON number that is neither NaN nor infinite (a bool is not one)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def read_json(path: Path) -> dict:
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    try:
        return json.loads(read_text(path))
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not valid JSON ({err.msg} at line {err.lineno})") from None


def read_text(path: Path) -> str:
    """A file's text; ValueError naming the file if it is not UTF-8."""
    try:
        return path.read_text()
    except UnicodeDecodeError as err:
        raise ValueError(f"{path} is not UTF-8 text (byte {err.start})") from None


def open_state(root: Path, name: str, what: str) -> dict | None:
    """The state file `name` of a study folder, None if the folder is new (missing, or empty but for a lock
    file: lock_run); one-line
    errors for a damaged file or a folder that holds something else."""
    path = root / name
    if path.exists():
        try:
            state = read_json(path)
        except ValueError as err:
            raise ValueError(f"{err}; move it away to start afresh") from None  # err names the file
        if not isinstance(state, dict):  # a null would read as a new study and be written over
            raise ValueError(f"{path} is damaged (not a JSON object: {json.dumps(state)[:40]}); move it away "
                             "to start afresh")
        return state
    if root.exists() and (not root.is_dir() or holds_other_files(root)):
        raise ValueError(f"--out {str(root)!r} exists and holds no {what} ({name}); choose an empty or new folder")
    return None


LOCK_FILE = ".lock"
CONFIG_KEYS = ("method", "scenario", "traffic", "steps", "envs", "seeds")  # what every run's config must name


def run_folder(path: str | Path) -> Path:
    """A run folder whose config.json is readable and names a run; one-line errors otherwise."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{str(p)!r} is a file, not a run folder")
    if not p.is_dir():
        raise FileNotFoundError(f"run folder {str(p)!r} does not exist")
    if not (p / "config.json").exists():
        raise ValueError(f"{str(p)!r} is not a run folder (no config.json)")
    train_config(p)
    return p


def run_config(folder: str | Path) -> dict:
    """config.json of a run folder, checked to be {"config": {...the TrainConfig...}, ...}."""
    path = Path(folder) / "config.json"
    data = read_json(path)
    config = data.get("config") if isinstance(data, dict) else None
    if not isinstance(config, dict):
        raise ValueError(f"{path} is damaged (no \"config\" object); it cannot be used as a run's settings")
    missing = [k for k in CONFIG_KEYS if k not in config]
    if missing:
        raise ValueError(f"{path} is damaged (its config lacks {', '.join(missing)})")
    return data


def train_config(folder: str | Path) -> TrainConfig:
    """The TrainConfig of a run folder's config.json, every setting checked (types, finite numbers, ranges);
    one line naming the file and the setting otherwise."""
    path, settings = Path(folder) / "config.json", run_config(folder)["config"]
    try:
        return TrainConfig.from_dict(settings)
    except (TypeError, ValueError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(f"{path} is damaged ({first})") from None


def check_output_folder(path: Path, flag: str = "--out") -> None:
    """Refuse, before any work, a folder path that is a file or lies under one."""
    for p in (path, *path.parents):
        if p.exists():
            if not p.is_dir():
                raise ValueError(f"{flag} {str(path)!r}: {str(p)!r} is a file, not a folder")
            return


def check_output_file(path: str | Path, overwrite: bool = False, flag: str = "--out", force_flag: str = "--overwrite") -> None:
    """Refuse, before any work, an output file path that is a folder (or ends in a slash, as a folder's
    name does), lies under a file, or exists (unless overwrite)."""
    if str(path).endswith(("/", os.sep)) or Path(path).is_dir():
        raise ValueError(f"{flag} {str(path)!r} is a folder; give a file name")
    path = Path(path)
    check_output_folder(path.parent, flag)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{str(path)} exists; pass {force_flag} to replace it or {flag} to write elsewhere")


@contextlib.contextmanager
def claim_outputs(paths: list[Path], overwrite: bool = False, flag: str = "--out"):
    """Check output files (check_output_file) and hold a lock on them from the check until the block ends,
    where they are written (write_atomic / publish with replace=overwrite): a second process that writes
    the same output is refused at once. The lock is a flock on a hidden file beside the first output,
    which the kernel drops when a process dies, so a killed writer never blocks the next one."""
    for path in paths:
        check_output_file(path, overwrite, flag)
    first = Path(paths[0])
    first.parent.mkdir(parents=True, exist_ok=True)
    lock = first.parent / f".{first.name}.lock"
    fd = _flock(lock)
    if fd is None:
        raise ValueError(f"{flag} {str(first)!r} is being written by another process; wait for it or choose another {flag}")
    try:
        for path in paths:  # again, under the lock: the other process may have written it meanwhile
            check_output_file(path, overwrite, flag)
        yield
    finally:
        lock.unlink(missing_ok=True)  # while held: a process that opened it before will find it replaced
        os.close(fd)


def _flock(lock: Path) -> int | None:
    """A descriptor holding an exclusive flock on the file lock (created), None if another process holds it."""
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        try:
            current = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            current = False
        if current:
            return fd
        os.close(fd)  # the holder removed the file between our open and our lock: lock the new one


def holds_other_files(folder: Path, ignore: tuple[str, ...] = ()) -> bool:
    """True if the folder exists and holds anything besides a run lock (and the names in ignore)."""
    return folder.is_dir() and any(p.name != LOCK_FILE and p.name not in ignore for p in folder.iterdir())


@contextlib.contextmanager
def lock_run(folder: Path, in_use: str | None = None):
    """Hold an advisory lock on a run folder (or a study folder) while a process writes in it.

    flock: the kernel drops it when the process dies, so a lock left by a killed run never blocks a resume.
    The lock file itself stays (empty but for the holder's pid) and is ignored by the folder checks.
    in_use: the one-line refusal when another process holds it, {pid} standing for the holder's pid.
    """
    if in_use is None:
        in_use = (f"run folder {str(folder)!r} is in use by another process (pid {{pid}}); "
                  "wait for it to finish or choose another --out")
    path = folder / LOCK_FILE
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise ValueError(in_use.replace("{pid}", holder)) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def progress_bar(total: int, desc: str, unit: str = "step", enabled: bool = True, initial: int = 0):
    """A tqdm bar that refreshes on the clock (at most every 0.5 s, at least whenever update() is called
    after 0.5 s), with an ETA; None when disabled."""
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, dynamic_ncols=True, mininterval=0.5, miniters=1)


class Named:
    """obj, whose method calls name `path` in the OSErrors they raise (checkpoint.naming): a TensorBoard
    writer, whose full disk names no file."""

    def __init__(self, obj, path: Path):
        self.obj, self.path = obj, path

    def __getattr__(self, name: str):
        attr = getattr(self.obj, name)
        if not callable(attr):
            return attr

        def call(*args, **kwargs):
            with naming(self.path):
                return attr(*args, **kwargs)

        return call


def append_jsonl(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    with naming(path), open(path, "a") as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_jsonl(path: Path) -> list[dict]:
    """The JSON objects of a JSON-lines file, one a line; ValueError naming the first line that is not one
    (a damaged line is never skipped: records.read_episode_log checks a training log's rows too)."""
    if not path.exists():
        return []
    rows = []
    for n, line in enumerate(read_text(path).splitlines(), 1):
        try:
            row = json.loads(line)
        except json.JSONDecodeError as err:
            raise ValueError(f"{path} line {n} is damaged (not JSON: {err.msg})") from None
        if not isinstance(row, dict):
            raise ValueError(f"{path} line {n} is damaged (a JSON {type(row).__name__}, not an object)")
        rows.append(row)
    return rows


def write_jsonl(path: Path, rows: list[dict]) -> None:
    """Replace a JSON-lines file with rows, atomically."""
    write_atomic(path, "".join(json.dumps(r) + "\n" for r in rows).encode())
