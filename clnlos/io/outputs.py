"""Output files: checked before any work, written together and atomically, never over an input.

* :func:`check_outputs` -- each output path: not a directory, its folder exists (or can be
  created) and is writable, not one of the inputs, no two outputs the same file, and the
  suffix its format needs (an HDF5 output named ``.png`` would be overwritten by its own
  figure), and no existing file at an *implied* path (one the user did not name: the PNG
  beside an output, the files of an output folder) unless clnlos wrote it
  (:func:`written_by_clnlos`) or ``force`` is given. Every failure is an
  :class:`~clnlos.errors.OutputFileError` naming the path.
* :func:`write_group` -- files written in a group (HDF5 + PNG) go to temporary files beside
  their targets first; only when all are complete are they renamed into place, so no half
  group is left. Files get the mode the umask gives a new file (0644 under umask 022). A
  failure to write (a full disk) is one error naming the user's path, not the temporary.
* Temporaries being written are registered (:data:`_LIVE`): they are removed when the block
  fails, on Ctrl-C, on SIGTERM (:func:`install_sigterm_cleanup`, installed by the CLI) and
  at interpreter exit (``atexit``), so no ``.tmp`` is left behind.
* :func:`provenance` -- what every output records about how it was made.
"""

from __future__ import annotations

import atexit
import contextlib
import datetime
import os
import signal
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path

import h5py

from clnlos.errors import OutputFileError
from clnlos.runtime.filemode import file_mode
from clnlos.version import __version__

HDF5_SUFFIXES = (".h5", ".hdf5", ".he5")

# what marks a file as clnlos's own output (see written_by_clnlos)
PNG_SOFTWARE = "clnlos"        # PNG tEXt "Software" of every figure clnlos saves
VERSION_KEY = "clnlos_version"  # HDF5 attribute / first JSON key of every clnlos output
HTML_GENERATOR = "<meta name='generator' content='clnlos'>"  # in the <head> of its reports
MARKER_BYTES = 4096  # the head of a file searched for the marker (bytes)


def _existing_parent(p: Path) -> Path:
    q = p.parent if str(p.parent) else Path(".")
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def png_metadata() -> dict:
    """PNG text chunks of a figure clnlos saves (what :func:`written_by_clnlos` looks for)."""
    return {"Software": f"{PNG_SOFTWARE} {__version__}"}


def stamp(doc: dict) -> dict:
    """A JSON document with the clnlos version as its first key (its marker)."""
    return {VERSION_KEY: __version__, **{k: v for k, v in doc.items() if k != VERSION_KEY}}


def _png_software(head: bytes) -> str | None:
    """The tEXt "Software" value among the first chunks of a PNG (``head``: its first bytes)."""
    pos = 8
    while pos + 8 <= len(head):
        n = int.from_bytes(head[pos:pos + 4], "big")
        kind, data = head[pos + 4:pos + 8], head[pos + 8:pos + 8 + n]
        if kind == b"tEXt" and data.startswith(b"Software\0"):
            return data[len(b"Software\0"):].decode("latin-1")
        if kind == b"IDAT":
            return None
        pos += 12 + n
    return None


def _h5_is_clnlos(path: Path) -> bool:
    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format", b"")
            fmt = fmt.decode() if isinstance(fmt, bytes) else str(fmt)
            return VERSION_KEY in f.attrs or fmt.startswith("clnlos")
    except (OSError, ValueError):
        return False


def written_by_clnlos(path: Path) -> bool:
    """Whether the file at ``path`` is one clnlos wrote (so that a rerun may replace it): a
    PNG with its Software chunk, an HDF5 with its version or format attribute, a JSON
    document starting with its version key, an HTML report with its generator tag."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = f.read(MARKER_BYTES)
    except OSError:
        return False
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return (_png_software(head) or "").startswith(PNG_SOFTWARE)
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return _h5_is_clnlos(p)
    text = head.decode("utf-8", "replace")
    if text.lstrip().startswith("{"):
        return text.lstrip()[1:].lstrip().startswith(f'"{VERSION_KEY}"')
    return HTML_GENERATOR in text


def _check_implied(role: str, p: Path, recognise: Callable[[Path], bool] | None) -> None:
    """An existing file at an implied path must be one clnlos wrote (see check_outputs)."""
    if not (p.exists() and not p.is_dir()):
        return
    if (recognise or written_by_clnlos)(p):
        return
    raise OutputFileError(f"{role} {p}: a file clnlos did not write is in the way (this "
                          "output goes beside or into the one named); move it, or pass "
                          "--force to replace it")


def check_outputs(outputs: dict[str, Path], inputs=(), suffixes: dict | None = None, *,
                  implied: dict | None = None, force: bool = False) -> None:
    """Check output paths before any work (see the module docstring).

    ``outputs`` maps a role (named in messages, e.g. "-o") to a path; ``suffixes`` maps a
    role to its allowed suffixes; ``implied`` maps the roles the user did not name to the
    test that an existing file there is clnlos's own (None: :func:`written_by_clnlos`);
    ``force`` lets them replace any file. Inputs are never outputs, ``force`` or not.
    """
    suffixes = suffixes or {}
    implied = implied or {}
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
    for role, path in outputs.items():
        if role in implied and not force:
            _check_implied(role, Path(path), implied[role])


# ------------------------------------------------------------------ temporaries
# temporary path -> the user's path it becomes; removed at exit if still there
_LIVE: dict[Path, Path] = {}


def remove_live_temporaries() -> None:
    """Remove every temporary still being written (SIGTERM, interpreter exit)."""
    for tmp in list(_LIVE):
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        _LIVE.pop(tmp, None)


atexit.register(remove_live_temporaries)


def user_path(filename) -> str | None:
    """The user's path for ``filename`` when it is a live temporary, else ``filename``."""
    if filename is None:
        return None
    return str(_LIVE.get(Path(os.fsdecode(filename)), filename))


class Terminated(KeyboardInterrupt):
    """SIGTERM as an exception: every ``finally`` and ``with`` block runs (temporaries are
    removed) as on Ctrl-C."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"terminated ({signal.Signals(signum).name})")


def _raise_terminated(signum, frame):
    raise Terminated(signum)


def install_sigterm_cleanup(*, chain: bool = False):
    """Make SIGTERM remove the live temporaries. ``chain=False`` (the CLI's main thread):
    raise :class:`Terminated`, which unwinds like Ctrl-C. ``chain=True`` (a worker process
    whose main thread is not ours, e.g. a Dask worker): remove them in the handler, then do
    what the previous handler did. Returns the previous handler (to restore it), or None
    where no handler can be installed (not the main thread)."""
    previous = signal.getsignal(signal.SIGTERM)
    if not chain:
        handler = _raise_terminated
    else:
        def handler(signum, frame):
            remove_live_temporaries()
            if callable(previous):
                return previous(signum, frame)
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return None
    try:
        signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread of the main interpreter
        return None
    return previous


def _write_error(exc: OSError, tmps: list[Path], targets: list[Path]) -> OutputFileError:
    """One line naming the user's path (not the hidden temporary) and the reason."""
    names = {str(t): str(u) for t, u in zip(tmps, targets, strict=False)}
    fn = os.fsdecode(exc.filename) if exc.filename is not None else None
    for u in targets:  # a temporary that failed while being created
        if fn and Path(fn).parent == u.parent and Path(fn).name.startswith(f".{u.name}.") \
                and fn.endswith(".tmp"):
            names.setdefault(fn, str(u))
    reason = str(exc.strerror or exc)
    if fn:
        where = names.get(fn, fn)
    else:  # a library's message (h5py) may name the temporary instead
        named = [u for t, u in names.items() if t in reason]
        where = named[0] if named else " and ".join(str(t) for t in targets)
    for t, u in names.items():
        reason = reason.replace(t, u)
    lines = reason.strip().splitlines()
    return OutputFileError(f"cannot write {where}: {lines[0] if lines else exc!r}")


@contextlib.contextmanager
def write_group(paths: list[Path]):
    """Yield temporary paths beside ``paths``; when the block ends without error, give them
    the umask's mode and rename all onto their targets; on error remove them all."""
    targets = [Path(p) for p in paths]
    tmps: list[Path] = []

    def remove():
        for tmp in tmps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            _LIVE.pop(tmp, None)

    try:
        for t in targets:
            t.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=t.parent, prefix=f".{t.name}.", suffix=".tmp")
            _LIVE[Path(tmp)] = t
            tmps.append(Path(tmp))
            os.close(fd)
        yield tmps
        mode = file_mode()
        for tmp in tmps:
            os.chmod(tmp, mode)
        for tmp, t in zip(tmps, targets, strict=True):
            os.replace(tmp, t)
            _LIVE.pop(tmp, None)
    except OSError as exc:
        remove()
        raise _write_error(exc, tmps, targets) from None
    except BaseException:
        remove()
        raise


def git_commit() -> str | None:
    """The git commit of a source checkout clnlos runs from (the folder above the package;
    ``.git`` a folder, or a file in a worktree), else None."""
    root = Path(__file__).resolve().parents[2]
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
