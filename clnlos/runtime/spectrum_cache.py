"""Optional on-disk cache of PSF spectra: ``CLNLOS_SPECTRUM_CACHE=DIR``.

A cold reconstruction builds one or two spectra on its padded grid: the slab's F[Phi * Phi]
(:mod:`clnlos.forward.blur`) and, for LCT, the light cone's (:mod:`clnlos.inverse.lct`),
270 MB each at 128 x 128 x 512. With the cache set, each is stored as a raw file named by a
SHA-256 of
everything that shapes it -- its kind, grid, precision and physical parameters, the kernel
sources and Python modules that compute it, and the clnlos version -- and a later process
with the same geometry reads it instead of recomputing it. Off by default (it spends disk);
the folder is kept under ``CLNLOS_SPECTRUM_CACHE_MB`` (default 4096 MiB) by deleting the
least recently used files. Files are written atomically, with the mode the umask gives a
new file (:func:`clnlos.runtime.filemode.file_mode`).

Each entry is a header -- ``MAGIC``, its key, the payload's size in bytes and its checksum
(:func:`payload_checksum`) -- then the spectrum's raw bytes. A read verifies all four; an
entry that fails (truncated, zero-filled, another entry's bytes, a flipped bit, a moved
block) is deleted, recomputed, stored again and reported in one warning that names the
file.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import tempfile
import warnings
from pathlib import Path

import numpy as np

from clnlos.errors import ParameterError
from clnlos.runtime.buffers import host_view
from clnlos.runtime.filemode import file_mode
from clnlos.runtime.programs import code_digest
from clnlos.settings import ENV_SPECTRUM_CACHE, Settings, current, resolve

SUFFIX = ".spectrum"
# entry header: magic, key (KEY_CHARS ASCII hex), payload bytes, the checksum's two lanes
MAGIC = b"CLNLOS-SPECTRUM-2\n"
KEY_CHARS = 40
HEADER = struct.Struct(f"<{len(MAGIC)}s{KEY_CHARS}sQQQ")
CHECK_BLOCK_WORDS = 512  # 4 KiB blocks of the checksum's positional lane
# what computes the spectra (and lays out the entries): a change to any of these
# invalidates every entry. Packages count whole, so a new inversion module is covered.
SOURCE_MODULES = ("clnlos.physics", "clnlos.diffusion", "clnlos.forward.blur",
                  "clnlos.operators", "clnlos.inverse", "clnlos.runtime.fft",
                  "clnlos.runtime.spectrum_cache")
SOURCE_KERNELS = ("diffusion", "lct")


class SpectrumCache:
    """A folder of spectra (see the module docstring); :meth:`from_settings` gives None when
    ``CLNLOS_SPECTRUM_CACHE`` is unset."""

    def __init__(self, root, budget: int | None = None):
        self.root = Path(root)
        self.budget = current().spectrum_cache_bytes if budget is None else int(budget)
        self._code = None

    @classmethod
    def from_settings(cls, settings: Settings | None = None) -> SpectrumCache | None:
        s = resolve(settings)
        if s.spectrum_cache_dir is None:
            return None
        return cls(s.spectrum_cache_dir, s.spectrum_cache_bytes)

    def check(self) -> None:
        """The folder exists (or is created) and is writable: else one ParameterError."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ParameterError(ENV_SPECTRUM_CACHE, str(self.root), "a folder that can be "
                                 f"created ({exc.strerror or exc})") from None
        if not os.access(self.root, os.W_OK | os.X_OK):
            raise ParameterError(ENV_SPECTRUM_CACHE, str(self.root), "a writable folder")

    def key(self, kind: str, **params) -> str:
        """The entry name of a spectrum of ``kind`` with these parameters (JSON-able)."""
        if self._code is None:
            self._code = code_digest(SOURCE_MODULES, SOURCE_KERNELS)
        text = json.dumps({"kind": kind, "code": self._code, **params}, sort_keys=True,
                          default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:KEY_CHARS]

    def _path(self, key: str) -> Path:
        return self.root / f"{key}{SUFFIX}"

    def load(self, key: str, out_g) -> bool:
        """Read entry ``key`` into the device array ``out_g``: True when it is there and
        verified (header and checksum, see the module docstring); False when it is missing,
        or bad -- then it is deleted, with one warning naming the file."""
        path = self._path(key)
        try:
            f = open(path, "rb")
        except OSError:
            return False
        with f:
            try:
                size = os.fstat(f.fileno()).st_size
                problem, check = _header_problem(f.read(HEADER.size), size, key,
                                                 out_g.nbytes)
                if problem is None:
                    with host_view(out_g, write=True, read=False) as a:
                        data = memoryview(a).cast("B")
                        if f.readinto(data) != data.nbytes:
                            problem = "ends early (truncated)"
                        elif payload_checksum(data) != check:
                            problem = "fails its checksum (corrupt)"
            except OSError as exc:
                problem = f"unreadable ({exc.strerror or exc})"
        if problem is not None:
            self._discard(path, problem)
            return False
        try:
            os.utime(path)  # least recently used = oldest access
        except OSError:
            pass
        return True

    def _discard(self, path: Path, problem: str) -> None:
        """Delete a bad entry and say so in one warning line naming the file."""
        path.unlink(missing_ok=True)
        warnings.warn(f"spectrum cache entry {path} {problem}: deleted; the spectrum is "
                      "recomputed and stored again", UserWarning, stacklevel=4)

    def store(self, key: str, spec_g) -> None:
        """Write ``spec_g`` as entry ``key`` (header, then the bytes; atomically, with the
        umask's mode), then prune to the budget. A failure to write (disk full) leaves no
        file and is not an error of the reconstruction."""
        if HEADER.size + spec_g.nbytes > self.budget:
            return
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.root, prefix=".", suffix=".tmp")
            try:
                with os.fdopen(fd, "wb") as f, host_view(spec_g) as a:
                    data = memoryview(np.ascontiguousarray(a)).cast("B")
                    f.write(HEADER.pack(MAGIC, key.encode("ascii"), data.nbytes,
                                        *payload_checksum(data)))
                    f.write(data)
                os.chmod(tmp, file_mode())
                os.replace(tmp, self._path(key))
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError:
            return
        self.prune()

    def prune(self) -> None:
        """Delete the least recently used entries until the folder fits the budget."""
        entries = []
        for p in self.root.glob(f"*{SUFFIX}"):
            try:
                st = p.stat()
            except OSError:
                continue
            entries.append((st.st_mtime, st.st_size, p))
        total = sum(e[1] for e in entries)
        for _, size, p in sorted(entries):
            if total <= self.budget:
                break
            p.unlink(missing_ok=True)
            total -= size


def payload_checksum(data: memoryview) -> tuple[int, int]:
    """A Fletcher-style checksum of bytes at memory speed (numpy; a CRC or SHA would cost
    most of what a cache hit saves): (the sum of the 64-bit words, the sum of the
    CHECK_BLOCK_WORDS-word block sums weighted by their 1-based index), both mod 2^64.
    Not cryptographic: it catches truncation, zero fills, overwritten or flipped bytes and
    moved blocks."""
    b = np.frombuffer(data, np.uint8)
    n8 = b.size // 8
    words = b[:n8 * 8].view(np.uint64)
    nb = n8 // CHECK_BLOCK_WORDS
    sums = np.add.reduce(words[:nb * CHECK_BLOCK_WORDS].reshape(nb, CHECK_BLOCK_WORDS),
                         axis=1, dtype=np.uint64)
    last = (int(np.add.reduce(words[nb * CHECK_BLOCK_WORDS:], dtype=np.uint64))
            + int.from_bytes(b[n8 * 8:].tobytes(), "little")) % 2**64
    sums = np.append(sums, np.uint64(last))
    weights = np.arange(1, sums.size + 1, dtype=np.uint64)
    return (int(np.add.reduce(sums, dtype=np.uint64)),
            int(np.add.reduce(sums * weights, dtype=np.uint64)))


def _header_problem(head: bytes, size: int, key: str, nbytes: int
                    ) -> tuple[str | None, tuple[int, int]]:
    """(why an entry's header and file size do not describe a spectrum of ``nbytes`` bytes
    for ``key``, or None; the checksum the header records)."""
    if len(head) < HEADER.size or not head.startswith(MAGIC):
        return "is not a clnlos spectrum entry (bad header)", (0, 0)
    _, k, n, lane_a, lane_b = HEADER.unpack(head)
    if k.decode("ascii", "replace") != key:
        return "holds another entry's key", (lane_a, lane_b)
    if n != nbytes:
        return f"holds {n} bytes, {nbytes} expected", (lane_a, lane_b)
    if size != HEADER.size + nbytes:
        return (f"is {size} bytes long, {HEADER.size + nbytes} expected (truncated)",
                (lane_a, lane_b))
    return None, (lane_a, lane_b)
