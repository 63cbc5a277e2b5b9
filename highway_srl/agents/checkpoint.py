"""Checkpoints as a folder: `model.safetensors` (tensors) and `meta.json` (everything else).

No pickle anywhere: a checkpoint can be loaded without executing code from it. Both files are
written atomically (temporary file in the same folder, fsync, os.replace), so an interrupted
save leaves the previous checkpoint intact rather than a half-written one.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file
from safetensors.torch import save as safetensors_bytes

MODEL_FILE = "model.safetensors"
META_FILE = "meta.json"


class CheckpointError(ValueError):
    """A checkpoint folder is missing, unreadable, or belongs to a different run setup."""


def _umask() -> int:
    """The process umask, read without changing it where /proc allows (os.umask is set-and-get)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_atomic(path: Path, data: bytes, replace: bool = True) -> None:
    """Write bytes so that a reader sees the old file or the new one, never a torn one.

    The file gets the mode a plain open() would give (0666 minus the umask, usually 0644): mkstemp's
    0600 would hide results from colleagues on a shared machine. replace=False: never over a file that
    exists (publish), a FileExistsError instead.
    """
    with naming(path):
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            os.fchmod(fd, 0o666 & ~_umask())
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            publish(Path(tmp), path, replace)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise


@contextmanager
def naming(path: Path):
    """An OSError in the block (a full disk, a size limit, no permission) names `path`, the file being
    written: not a temporary name, and not nothing (a write() that fails names no file)."""
    try:
        yield
    except OSError as err:
        if err.errno is None:  # raised with its own message (publish's FileExistsError): keep it
            raise
        raise OSError(err.errno, err.strerror, str(path)) from None


def temp_beside(path: Path) -> Path:
    """A hidden temporary name in path's folder with path's suffix (writers that pick the format by it)."""
    return path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")


def publish(tmp: Path, path: Path, replace: bool = True) -> None:
    """Move a finished temporary file (in path's folder) onto path in one step: os.replace, or with
    replace=False a hard link that fails if path exists (O_EXCL's rule: a file another process wrote
    meanwhile is kept, FileExistsError). tmp is gone afterwards either way."""
    try:
        if replace:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)
            except FileExistsError:
                raise FileExistsError(f"{path} was written by another process meanwhile; it is kept, this "
                                      "result is not written (pass --overwrite to replace it)") from None
    finally:
        tmp.unlink(missing_ok=True)


def _fsync_dir(path: Path) -> None:
    # Makes the renames themselves durable; not every platform can open a directory.
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def save_checkpoint(path_dir: str | os.PathLike, tensors: dict[str, torch.Tensor], meta: dict[str, Any]) -> None:
    """Write tensors to path_dir/model.safetensors and meta (JSON-serialisable) to path_dir/meta.json.

    Tensors are moved to the CPU and made contiguous; two entries must not share memory.
    The tensors are written first, so a meta.json on disk always describes a complete model file.
    """
    folder = Path(path_dir)
    folder.mkdir(parents=True, exist_ok=True)
    cpu = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    meta_text = json.dumps(meta, indent=2, sort_keys=True)  # fails here, before anything is written
    write_atomic(folder / MODEL_FILE, safetensors_bytes(cpu))
    write_atomic(folder / META_FILE, (meta_text + "\n").encode())
    _fsync_dir(folder)


def load_checkpoint(
    path_dir: str | os.PathLike, expect: dict[str, Any] | None = None, device: torch.device | str = "cpu"
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Read (tensors, meta) from a folder written by `save_checkpoint`.

    expect: keys whose meta values must match, e.g. {"method": "moe-rm-srl", "scenario": "merge"}.
    Raises CheckpointError with a one-line message naming the file and the problem.
    """
    folder = Path(path_dir)
    if not folder.is_dir():
        raise CheckpointError(f"checkpoint folder {folder} does not exist")
    meta_path, model_path = folder / META_FILE, folder / MODEL_FILE
    for path in (meta_path, model_path):
        if not path.is_file():
            raise CheckpointError(f"checkpoint {folder} has no {path.name} ({path} is missing)")
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise CheckpointError(f"{meta_path} is not valid JSON: {err}") from None
    if not isinstance(meta, dict):
        raise CheckpointError(f"{meta_path} holds a {type(meta).__name__}, expected a JSON object")
    for key, want in (expect or {}).items():
        if key not in meta:
            raise CheckpointError(f"checkpoint {folder} has no {key!r} in {META_FILE} (expected {want!r})")
        if meta[key] != want:
            raise CheckpointError(f"checkpoint {folder} was trained with {key} {meta[key]!r}, not {want!r}")
    try:
        tensors = load_file(model_path, device=str(device))
    except Exception as err:  # safetensors raises its own SafetensorError, OSError, or others
        first_line = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise CheckpointError(f"{model_path} is truncated or corrupt: {first_line}") from None
    return tensors, meta


def first_non_finite(tensors: dict[str, torch.Tensor], nan_only: tuple[str, ...] = ()) -> str | None:
    """The first key whose floating-point tensor holds a NaN or an infinity (for keys starting with one of
    nan_only: a NaN; there an infinity can be a value); None if every one is finite. One host read per tensor."""
    for key, value in tensors.items():
        if value.is_floating_point():
            bad = value.isnan() if key.startswith(nan_only) else ~value.isfinite()
            if bool(bad.any()):
                return key
    return None


# One key scheme for a trained policy's tensors, in the final model/ and in resume/ alike:
# "learner.<name>" (the networks: weights, targets, Adam moments) and "method.<name>" (a method's own
# state, e.g. LM-RL's λ). Only the two functions below build or read these keys.
LEARNER_PREFIX, METHOD_PREFIX = "learner.", "method."


def policy_tensors(learner, method) -> dict[str, torch.Tensor]:
    """The tensors of a policy (a DQNLearner and a Method) under the checkpoint key scheme."""
    state = {LEARNER_PREFIX + k: v for k, v in learner.state_dict().items()}
    state.update({METHOD_PREFIX + k: v for k, v in method.state_dict().items()})
    return state


def split_policy_tensors(tensors: dict[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """(learner state, method state) with their prefixes removed; keys of neither part are ignored."""
    part = lambda prefix: {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}  # noqa: E731
    return part(LEARNER_PREFIX), part(METHOD_PREFIX)
