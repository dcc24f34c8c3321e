"""Files a reader may see are written whole or not at all.

``write_atomic`` writes through a temporary name beside the final one (``.<name>.tmp-<pid>-<thread>``,
hidden from pyarrow and from globs of the final names; or ``<prefix><hex>-<name>`` where the caller
names a prefix its cleaner looks for), flushes it to disk and renames it into place; a failure
removes the temporary and raises ``OSError`` naming the file, so the previous version stays whole.
``savefig_atomic`` does the same for a matplotlib figure.
"""

from __future__ import annotations

import os
import threading
import uuid
from pathlib import Path
from typing import Any, Callable

#: ``os.write``, named here so that a test can make the disk full (nothing else can without root).
_os_write = os.write


def temporary_name(path: Path, prefix: str | None = None) -> Path:
    """The temporary beside ``path`` that this process and thread writes (its suffix kept, so a
    writer that picks its format from the suffix still can); with ``prefix``, ``<prefix><12 random
    hex>-<name>``."""
    if prefix is not None:
        return path.with_name(f"{prefix}{uuid.uuid4().hex[:12]}-{path.name}")
    return path.with_name(f".{path.name}.tmp-{os.getpid()}-{threading.get_ident()}{path.suffix}")


def _replace_with(path: str | os.PathLike, write: Callable[[Path], None], prefix: str | None = None) -> Path:
    path = Path(path)
    tmp = temporary_name(path, prefix)
    if tmp.is_symlink() or tmp.exists():  # this thread's name: a link planted there, or a dead writer's, goes
        tmp.unlink()
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise OSError(err.errno, f"cannot write {path}: {err.strerror or err}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_atomic(path: str | os.PathLike, data: bytes | str, *, prefix: str | None = None) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` whole, or leave what was there; returns the path.
    The temporary (``temporary_name``, ``prefix`` as there) is made new (never an existing file,
    never through a link planted at its name)."""
    payload = data.encode() if isinstance(data, str) else data

    def write(tmp: Path) -> None:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
        try:
            view = memoryview(payload)
            while view:
                view = view[_os_write(fd, view):]
        finally:
            os.close(fd)

    return _replace_with(path, write, prefix)


def savefig_atomic(fig: Any, path: str | os.PathLike, **kwargs: Any) -> Path:
    """``fig.savefig(path)`` whole, or leave what was there; returns the path."""
    return _replace_with(path, lambda tmp: fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or None, **kwargs))
