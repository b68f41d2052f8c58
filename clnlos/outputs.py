"""Output files: checked before any work, written together and atomically, never over an input.

* :func:`check_outputs` -- each output path: not a directory, its folder exists (or can be
  created) and is writable, not one of the inputs, no two outputs the same file, and the
  suffix its format needs (an HDF5 output named ``.png`` would be overwritten by its own
  figure). Every failure is an :class:`~clnlos.errors.OutputFileError` naming the path.
* :func:`write_group` -- files written in a group (HDF5 + PNG) go to temporary files beside
  their targets first; only when all are complete are they renamed into place, so no half
  group is left. Files get the mode the umask gives a new file (0644 under umask 022).
* :func:`provenance` -- what every output records about how it was made.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import subprocess
import tempfile
from pathlib import Path

from .errors import OutputFileError

HDF5_SUFFIXES = (".h5", ".hdf5", ".he5")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new regular file under the current umask."""
    return 0o666 & ~_umask()


def _existing_parent(p: Path) -> Path:
    q = p.parent if str(p.parent) else Path(".")
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def check_outputs(outputs: dict[str, Path], inputs=(), suffixes: dict | None = None) -> None:
    """Check output paths before any work (see the module docstring).

    ``outputs`` maps a role (named in messages, e.g. "-o") to a path; ``suffixes`` maps a
    role to its allowed suffixes.
    """
    suffixes = suffixes or {}
    seen: dict[Path, str] = {}
    ins = [Path(i) for i in inputs if i is not None]
    for role, path in outputs.items():
        p = Path(path)
        allowed = suffixes.get(role)
        if allowed and p.suffix.lower() not in allowed:
            raise OutputFileError(f"{role} {p}: the file name must end with "
                                  + " or ".join(allowed))
        if p.is_dir():
            raise OutputFileError(f"{role} {p}: is a directory; give a file name")
        parent = _existing_parent(p)
        if not parent.is_dir():
            raise OutputFileError(f"{role} {p}: {parent} is not a directory")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputFileError(f"{role} {p}: cannot write in {parent} (permission denied)")
        key = p.resolve()
        if key in seen:
            raise OutputFileError(f"{role} {p}: the same file as {seen[key]}")
        seen[key] = f"{role} {p}"
        for i in ins:
            same = i.resolve() == key or (i.exists() and p.exists() and os.path.samefile(i, p))
            if same:
                raise OutputFileError(f"{role} {p}: is an input of this command; choose "
                                      "another name (inputs are never overwritten)")


@contextlib.contextmanager
def write_group(paths: list[Path]):
    """Yield temporary paths beside ``paths``; when the block ends without error, give them
    the umask's mode and rename all onto their targets; on error remove them all."""
    targets = [Path(p) for p in paths]
    tmps = []
    try:
        for t in targets:
            t.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=t.parent, prefix=f".{t.name}.", suffix=".tmp")
            os.close(fd)
            tmps.append(Path(tmp))
        yield tmps
        mode = file_mode()
        for tmp in tmps:
            os.chmod(tmp, mode)
        for tmp, t in zip(tmps, targets, strict=True):
            os.replace(tmp, t)
    except OSError as exc:
        for tmp in tmps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise OutputFileError(f"cannot write {exc.filename or targets[0]}: "
                              f"{exc.strerror or exc}") from None
    except BaseException:
        for tmp in tmps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise


def git_commit() -> str | None:
    """The git commit of a source checkout clnlos runs from, else None."""
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():
        return None
    try:
        r = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                           text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() or None if r.returncode == 0 else None


def provenance(*, capture=None, device: str | None = None) -> dict:
    """clnlos version, git commit (in a checkout), absolute input path, device, UTC time."""
    from . import __version__

    p = {"clnlos_version": __version__,
         "created_utc": datetime.datetime.now(datetime.UTC).isoformat(
             timespec="seconds")}
    commit = git_commit()
    if commit:
        p["clnlos_git_commit"] = commit
    if capture is not None:
        p["capture"] = str(Path(capture).resolve())
    if device is not None:
        p["device"] = device
    return p
