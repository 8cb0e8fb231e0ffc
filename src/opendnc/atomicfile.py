"""Write a file so that readers see either the old content or the whole new one, never a part.

Every download, receive and store in opendnc goes through here: the bytes go to a hidden
temporary file *beside* the target (same folder, so the final :func:`os.replace` is an atomic
rename on one file system), and that file takes the target's name only when the writer finished
without error. On any exception, including :class:`KeyboardInterrupt`, the temporary file is
removed and an existing target is left untouched.

The temporary file gets the permissions an ordinary ``open(path, "w")`` would give
(``0o666`` minus the process umask) instead of :func:`tempfile.mkstemp`'s private ``0600``:
a program downloaded by one shop user must stay readable by the others and by the control.

Three levels, pick the smallest that fits:

- :func:`atomic_write` — context manager yielding a binary handle; the common case.
- :class:`AtomicWriter` — the same as an object, for writers that keep the handle open across
  many calls or decide the final name late (``writer.target = ...`` before the commit).
- :func:`create_temp` — only the hidden temp file with the right mode, for callers that keep
  partial files elsewhere and rename them themselves (the simulator's upload area).

OS errors propagate as :class:`OSError`; callers map them to their own typed errors.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

__all__ = ["AtomicWriter", "atomic_write", "create_temp", "file_mode"]

StrPath = str | os.PathLike[str]


def _current_umask() -> int:
    # Linux exposes the umask read-only; the os.umask() set-and-restore fallback briefly changes
    # it for every thread of the process, so it is only used where /proc is missing.
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode a newly created regular file gets: ``0o666`` minus the process umask."""
    return 0o666 & ~_current_umask()


def create_temp(folder: StrPath, name: str = "", *, suffix: str = ".part") -> tuple[int, Path]:
    """Create a hidden, uniquely named file in ``folder`` with :func:`file_mode` permissions.

    The name is ``.<name>.<random><suffix>`` (``.<random><suffix>`` without ``name``). Returns
    the open file descriptor (the caller owns it) and the path. Raises :class:`OSError`.
    """
    prefix = f".{name}." if name else "."
    fd, path = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=folder)
    try:
        os.fchmod(fd, file_mode())
    except BaseException:
        os.close(fd)
        os.unlink(path)
        raise
    return fd, Path(path)


class AtomicWriter:
    """A temp file beside ``target``: :meth:`commit` renames it over the target, :meth:`discard`
    removes it. As a context manager it commits on a clean exit and discards on any exception.

    ``target`` may be reassigned before the commit (e.g. once a received program's number is
    known); it must stay in the same folder. ``buffering`` is passed to :func:`os.fdopen`;
    ``fsync=True`` forces the data to disk before the rename (crash safety at a speed cost).
    """

    def __init__(self, target: StrPath, *, buffering: int = -1, fsync: bool = False) -> None:
        self.target = Path(target)
        self._fsync = fsync
        fd, self.temp = create_temp(self.target.parent, self.target.name)
        try:
            self.handle: BinaryIO = os.fdopen(fd, "wb", buffering=buffering)
        except BaseException:
            os.close(fd)
            self.temp.unlink(missing_ok=True)
            raise
        self.done = False

    def write(self, data: bytes) -> int:
        """Append ``data`` to the temp file."""
        return self.handle.write(data)

    def commit(self) -> None:
        """Flush, close and rename onto ``target``; on failure the temp file is removed."""
        if self.done:
            return
        self.done = True
        try:
            self.handle.flush()
            if self._fsync:
                os.fsync(self.handle.fileno())
            self.handle.close()
            os.replace(self.temp, self.target)
        except BaseException:
            self._remove()
            raise

    def discard(self) -> None:
        """Close and remove the temp file; the target is not touched."""
        if self.done:
            return
        self.done = True
        self._remove()

    def _remove(self) -> None:
        # Closing can fail too (a full disk on the last flush); the file must go regardless.
        try:
            self.handle.close()
        except OSError:
            pass
        finally:
            with contextlib.suppress(FileNotFoundError):
                self.temp.unlink()

    def __enter__(self) -> AtomicWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


@contextlib.contextmanager
def atomic_write(
    target: StrPath, *, buffering: int = -1, fsync: bool = False
) -> Iterator[BinaryIO]:
    """Yield a binary handle whose content replaces ``target`` only if the block succeeds.

    >>> with atomic_write("O1000.nc") as out:  # doctest: +SKIP
    ...     out.write(program)
    """
    with AtomicWriter(target, buffering=buffering, fsync=fsync) as writer:
        yield writer.handle
