"""A content-addressed on-disk cache with atomic writes.

Entries are ``.npz`` files named by the SHA-256 of a JSON key (everything that affects the
content). Writes go to a temporary file in the same folder and are renamed into place, so an
interrupted run never leaves a half-written entry; an entry that fails to load is treated as
missing and rebuilt, never trusted. An ``.npz`` is a zip archive holding each array's CRC-32,
which reading the array checks (a flipped byte anywhere in an array fails its load), so the
cache adds no checksum of its own: a SHA-256 of every array, checked on every load, took 6 s
(summed over the threads that loaded) of a 100 s run that read its pass's tiles again for every
fit (bundled urban_canyon_survey, 2026-12-05), and caught nothing the CRC does not.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from framework.errors import ConfigError


def key_digest(key: dict) -> str:
    """Stable hex digest of a JSON-able key (sorted keys)."""
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:24]


@functools.cache
def code_version(*modules: str) -> str:
    """Digest of the code that makes a cache entry: the bytes of every ``.py`` file of
    ``modules`` (dotted names; a package counts with everything below it) and the installed
    Mitsuba and Dr.Jit versions.

    Put in a key, it makes an entry written by other code a miss: a pass cached before an edit of
    its sampling was otherwise read back by the edited code (measured: the 296-weight street's
    solve timed 79.4 s against 70.7 s on passes of an older commit). Any edit counts, a comment's
    too: a needless render is cheaper than a stale one.
    """
    h = hashlib.sha256()
    for name in modules:
        for relative, path in _source_files(name):
            h.update(f"{name}/{relative}".encode())
            h.update(hashlib.sha256(path.read_bytes()).digest())
    for dist in ("mitsuba", "drjit"):
        h.update(f"{dist}=={importlib.metadata.version(dist)}".encode())
    return h.hexdigest()[:16]


def _source_files(name: str) -> list[tuple[str, Path]]:
    """``(path relative to the package, path)`` of the ``.py`` files of module or package ``name``."""
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise ValueError(f"code_version: {name!r} is not a module with source files")
    if not spec.submodule_search_locations:
        return [(Path(spec.origin).name, Path(spec.origin))]
    root = Path(spec.origin).parent
    return sorted((f.relative_to(root).as_posix(), f) for f in root.rglob("*.py"))


#: the member earlier versions stored their own SHA-256 in: read past, never written
_OLD_CHECKSUM = "__checksum__"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    atomic_write(path, lambda f: f.write(data))


def current_umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write) -> None:
    """Call ``write(f)`` on a temporary file in ``path``'s folder, then rename it to ``path``: an
    interrupted write never leaves a partial ``path``. The file gets the mode a plain ``open``
    would give it (0666 less the umask; ``mkstemp``'s own is 0600)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.chmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class Cache:
    """``Cache(dir).load(kind, key)`` / ``.store(kind, key, arrays)``; ``dir=None`` disables it."""

    def __init__(self, directory: str | os.PathLike | None):
        self.dir = Path(directory).expanduser().resolve() if directory else None

    def check_writable(self) -> None:
        """Create the cache folder (and its parents) if missing and write a probe file in it.

        Checked up front because a cache that cannot be written would fail only after the first
        rendering.

        Raises
        ------
        ConfigError
            If the folder is a file, cannot be created or is not writable (the OS reason given).
        """
        if self.dir is None:
            return
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=self.dir, prefix=".probe."):
                pass
        except OSError as exc:
            reason = "it is a file" if self.dir.is_file() else exc.strerror
            raise ConfigError(f"cache.dir={self.dir} is not a writable folder ({reason}): choose "
                              "another cache.dir, or cache.dir=null to run without a cache") from None

    def path(self, kind: str, key: dict) -> Path | None:
        return None if self.dir is None else self.dir / kind / f"{key_digest(key)}.npz"

    def load(self, kind: str, key: dict, *, keep=None) -> dict[str, np.ndarray] | None:
        """The arrays of the entry (those whose name ``keep(name)`` accepts, when given: the others
        are not read), or None when it is missing or damaged."""
        path = self.path(kind, key)
        if path is None or not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:      # each array's CRC-32 checked as it is read
                return {k: z[k] for k in z.files if k != _OLD_CHECKSUM and (keep is None or keep(k))}
        except Exception:
            return None  # corrupt: rebuilt by the caller

    def store(self, kind: str, key: dict, arrays: dict[str, np.ndarray]) -> None:
        path = self.path(kind, key)
        if path is None:
            return
        atomic_write(path, lambda f: np.savez(f, **arrays))
