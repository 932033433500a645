"""Writing files so that a failure never leaves a half-written result on disk."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path


def _umask() -> int:
    # os.umask can only be read by setting it; set it straight back
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _prepare_folder(target: Path) -> None:
    """Create ``target``'s folder, or raise naming ``target`` (not a temporary file)."""
    for parent in (target.parent, *target.parent.parents):
        if parent.exists():
            if not parent.is_dir():
                raise NotADirectoryError(f"cannot write {target}: {parent} is a file, not a folder")
            break
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise type(error)(f"cannot write {target}: {error.strerror or error}") from None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    The temporary file lives in the destination folder, so the final ``os.replace``
    is atomic on POSIX and Windows. On any exception the temporary file is removed
    and ``path`` is left as it was (absent, or its previous content). The file gets
    the permissions of an ordinary new file (``0o666`` less the umask), not the
    ``0o600`` of :func:`tempfile.mkstemp`, so colleagues can read shared results.
    Errors of the file system name ``path``, never the temporary file.
    """
    target = Path(path)
    _prepare_folder(target)
    try:
        handle, temporary_name = tempfile.mkstemp(
            prefix=f".{target.name}.", suffix=".part" + target.suffix, dir=target.parent
        )
    except OSError as error:
        raise type(error)(f"cannot write {target}: {error.strerror or error}") from None
    os.close(handle)
    temporary = Path(temporary_name)
    try:
        yield temporary
        if temporary.exists():
            os.chmod(temporary, 0o666 & ~_umask())
        try:
            os.replace(temporary, target)
        except OSError as error:
            raise type(error)(f"cannot write {target}: {error.strerror or error}") from None
    finally:
        if temporary.exists():
            temporary.unlink()


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], None]) -> Path:
    """Call ``write(temporary_path)`` and move the result onto ``path`` atomically."""
    with atomic_path(path) as temporary:
        write(temporary)
    return Path(path)
