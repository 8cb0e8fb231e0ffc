"""Local-file helpers shared by the blocking and asyncio clients.

Downloads never leave a half-written file: data goes to a temporary file in the target
folder, which is renamed over the target only when the transfer succeeded.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from types import TracebackType

from opendnc.atomicfile import AtomicWriter
from opendnc.errors import InputError
from opendnc.lsv2.constants import BINARY_EXTENSIONS

__all__ = ["AtomicFile", "image_bytes", "is_binary_name", "read_local"]

_WRITE_BUFFER = 1 << 20


def is_binary_name(name: str) -> bool:
    """True if files named like ``name`` travel in binary mode by default."""
    suffix = os.path.splitext(name.replace("\\", "/"))[1].lower()
    return suffix in BINARY_EXTENSIONS


def read_local(path: str | os.PathLike[str]) -> bytes:
    """Read a local file, mapping OS errors to :class:`InputError`."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc


class AtomicFile:
    """Write to a temp file beside ``target``; rename on success, delete on failure.

    A thin layer over :class:`opendnc.atomicfile.AtomicWriter` that maps OS errors to
    :class:`InputError` naming the local file.
    """

    def __init__(self, target: str | os.PathLike[str]) -> None:
        self.target = Path(target)
        self._writer: AtomicWriter | None = None

    def __enter__(self) -> AtomicFile:
        try:
            # A large buffer turns one write syscall per received block into one per MiB: on a
            # fast link that syscall was a fifth of the client's time per block.
            self._writer = AtomicWriter(self.target, buffering=_WRITE_BUFFER)
        except OSError as exc:
            folder = self.target.parent
            raise InputError(f"cannot write into {folder}: {exc.strerror or exc}") from exc
        return self

    def write(self, data: bytes) -> None:
        """Append ``data``."""
        assert self._writer is not None
        try:
            self._writer.handle.write(data)
        except OSError as exc:
            raise InputError(f"cannot write {self.target}: {exc.strerror or exc}") from exc

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._writer is not None
        if exc_type is not None:
            self._writer.discard()
            return
        try:
            self._writer.commit()
        except OSError as err:
            raise InputError(f"cannot store {self.target}: {err.strerror or err}") from err


def image_bytes(bmp: bytes, target: str | os.PathLike[str]) -> bytes:
    """The screen dump in the format the target's suffix asks for (BMP as is, PNG via Pillow)."""
    suffix = Path(target).suffix.lower()
    if suffix in ("", ".bmp"):
        return bmp
    try:
        from PIL import Image, UnidentifiedImageError  # optional dependency ([image] extra)
    except ImportError as exc:
        raise InputError("saving screen dumps as PNG needs Pillow (opendnc[image])") from exc
    try:
        with Image.open(io.BytesIO(bmp)) as image:
            out = io.BytesIO()
            image.save(out, format=suffix.lstrip(".").upper().replace("JPG", "JPEG"))
    except (UnidentifiedImageError, OSError, ValueError, KeyError) as exc:
        raise InputError(f"cannot convert the screen dump to {suffix}: {exc}") from exc
    return out.getvalue()
