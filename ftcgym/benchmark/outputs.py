"""Output folders one run at a time: a lock held for the run's life, results published whole.

- `OutputFolder(path)` (a context manager) takes an exclusive `flock` on `path/.ftcgym.lock` without waiting:
  a second run into a folder in use gets `FolderInUse` (the CLI: one line, exit status 2). The OS drops the
  lock when the holder's file is closed or its process dies, so a killed run leaves no stale lock. Entering
  it again in the process that holds it is a no-op, so a library call and the CLI around it can both lock.
- Results are written into `path/.ftcgym-new/` and `publish()` renames them into place (`os.replace`). It
  also removes what the folder's previous run wrote and this one does not (listed in `.ftcgym-files.json`),
  so the folder never mixes two runs' results.
- `atomic_write_text(path, text)`: one file, written to a temporary name beside it and renamed.
"""
from __future__ import annotations

import fcntl
import json
import os
import secrets
import shutil
from pathlib import Path

LOCK_FILE, STAGING_DIR, MANIFEST_FILE = ".ftcgym.lock", ".ftcgym-new", ".ftcgym-files.json"
_held: dict[Path, tuple[int, int]] = {}  # resolved folder -> (lock fd, nesting depth) in this process


class FolderInUse(RuntimeError):
    """Another run holds the output folder's lock."""

    def __init__(self, folder: Path, pid: str | None):
        holder = f"ftcgym run (pid {pid})" if pid else "ftcgym run"
        super().__init__(f"{folder} is in use by another {holder}; wait for it to finish or choose another --out")
        self.folder, self.pid = folder, pid


class OutputFolder:
    """An output folder locked for the `with` block; stage files with `staged(name)`, then `publish()`."""

    def __init__(self, path):
        self.path = Path(path)
        self.staging = self.path / STAGING_DIR

    def __enter__(self) -> OutputFolder:
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise ValueError(f"--out {self.path}: a file is in the way; the output folder must be a folder, or "
                             f"not exist yet") from None
        key = self._key = self.path.resolve()   # kept: the block may change the working directory
        if key in _held:
            fd, depth = _held[key]
            _held[key] = (fd, depth + 1)
            return self
        _held[key] = (_lock(self.path), 1)
        shutil.rmtree(self.staging, ignore_errors=True)  # left by a killed run; nobody else writes here now
        return self

    def __exit__(self, *exc) -> None:
        key = self._key
        fd, depth = _held.pop(key)
        if depth > 1:
            _held[key] = (fd, depth - 1)
            return
        shutil.rmtree(self.staging, ignore_errors=True)  # a run that failed before publishing
        os.close(fd)  # releases the lock

    def staged(self, name: str) -> Path:
        """Where to write the result file `name` before `publish`."""
        self.staging.mkdir(exist_ok=True)
        return self.staging / name

    def publish(self, also: tuple[str, ...] = ()) -> list[str]:
        """Rename the staged files into place and remove the files of the folder's previous run that this run
        did not write; `also`: names this run wrote in place (journals), which count as this run's. Returns the
        names this run owns, as the manifest records them."""
        staged = sorted(p.name for p in self.staging.iterdir()) if self.staging.exists() else []
        names = sorted({*staged, *also})
        previous = self._manifest()
        # Listing both runs first means a crash part-way still tells the next run everything to replace.
        atomic_write_text(self.path / MANIFEST_FILE, json.dumps(sorted({*previous, *names}), indent=1) + "\n")
        for name in staged:
            os.replace(self.staging / name, self.path / name)
        for name in set(previous) - set(names):
            _remove(self.path / name)
        atomic_write_text(self.path / MANIFEST_FILE, json.dumps(names, indent=1) + "\n")
        shutil.rmtree(self.staging, ignore_errors=True)
        return names

    def _manifest(self) -> list[str]:
        """Names the previous run wrote; only plain names, so a tampered manifest cannot reach outside."""
        try:
            names = json.loads((self.path / MANIFEST_FILE).read_text())
        except (OSError, ValueError):
            return []
        reserved = {LOCK_FILE, STAGING_DIR, MANIFEST_FILE, "", ".", ".."}
        return [n for n in names if isinstance(n, str) and n not in reserved and Path(n).name == n] \
            if isinstance(names, list) else []


def _lock(folder: Path) -> int:
    """An fd of `folder`'s lock file holding its exclusive lock, with our pid in it; FolderInUse if taken."""
    fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        pid = os.read(fd, 32).decode(errors="replace").strip() or None  # empty if its holder just took it
        os.close(fd)
        raise FolderInUse(folder, pid) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def atomic_write_text(path, text: str) -> Path:
    """Write `text` to `path` through a temporary file in the same folder, synced and renamed over it, so
    readers see the old file or the new one, never part of one, and no temporary file is left behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    try:
        with open(temporary, "x") as file:  # "x": a new file with the umask's permissions, as a plain write
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path
