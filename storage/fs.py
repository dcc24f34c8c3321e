"""One run root on a local disk or any fsspec location (``memory://run``, ``s3://bucket/run``).

Everything in ``storage`` goes through :class:`Location`, which holds an fsspec filesystem and the
root path inside it, and speaks in paths relative to the root. On a local disk no path below the
root may pass through a symbolic link: every path is checked (``LinkError`` names the link), walks
list a link as an entry and never descend into it, and nothing is ever removed or moved through
one, so a run dir copied from someone else cannot make a command touch files outside it. Bytes
are written under a temporary name starting with ``_tmp-`` (ignored by pyarrow datasets) and
then renamed into place. On a local
disk that rename is ``os.replace`` (atomic); on object stores a "rename" is copy + delete, which is
why the round manifest, written last, is the commit point.
"""

from __future__ import annotations

import hashlib
import os
import posixpath
import stat
import uuid
from dataclasses import dataclass
from typing import Iterable

import fsspec
from fsspec.implementations.local import LocalFileSystem

from gpl_dist.errors import RunDirError
from storage.layout import TMP_PREFIX


def sha256_hex(data: bytes | memoryview) -> str:
    """The hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


@dataclass(frozen=True)
class Location:
    """A run root: ``fs`` (fsspec filesystem) and ``root`` (path inside it, no trailing slash)."""

    fs: fsspec.AbstractFileSystem
    root: str
    url: str

    @property
    def is_local(self) -> bool:
        return isinstance(self.fs, LocalFileSystem)

    def path(self, rel: str) -> str:
        """The full path of ``rel``; ``BufferIntegrityError`` for a path that would leave the root
        (absolute, or with ``..``: manifests and journals are files a person can edit)."""
        if not rel:
            return self.root
        if rel.startswith("/") or ".." in rel.split("/"):
            from storage.errors import BufferIntegrityError

            raise BufferIntegrityError(f"{rel[:200]!r} is not a path inside {self.url}", rel)
        if self.is_local:
            link = self._first_link(rel)
            if link is not None:
                raise link_error(self, link)
        return posixpath.join(self.root, rel)

    def _first_link(self, rel: str) -> str | None:
        """The first component of ``rel`` (below the root) that is a symbolic link, as a relative path."""
        p = self.root
        for part in rel.split("/"):
            if not part or part == ".":
                continue
            p = os.path.join(p, part)
            try:
                mode = os.lstat(p).st_mode
            except OSError:  # absent (or under a file): nothing further down exists either
                return None
            if stat.S_ISLNK(mode):
                return self.rel(p)
        return None

    def links(self, rel: str = "") -> list[str]:
        """Relative paths of the symbolic links at or under ``rel``, never following one; [] on an
        object store (which has none)."""
        if not self.is_local:
            return []
        link = self._first_link(rel)
        if link is not None:
            return [link]
        top = self.path(rel)
        out = []
        for dirpath, dirnames, filenames in os.walk(top, followlinks=False):
            for name in (*dirnames, *filenames):
                full = os.path.join(dirpath, name)
                if os.path.islink(full):
                    out.append(self.rel(full))
        return sorted(out)

    def rel(self, path: str) -> str:
        path = path.rstrip("/")
        root = self.root.rstrip("/")
        if path == root:
            return ""
        if not path.startswith(root + "/"):
            raise ValueError(f"{path!r} is not under {root!r}")
        return path[len(root) + 1 :]

    def full_url(self, rel: str = "") -> str:
        """URL or local path that zarr/pyarrow/duckdb can open."""
        p = self.path(rel)
        return p if self.is_local else self.fs.unstrip_protocol(p)

    # -- reading ---------------------------------------------------------------------------------
    def exists(self, rel: str) -> bool:
        return self.fs.exists(self.path(rel))

    def read_bytes(self, rel: str) -> bytes:
        return self.fs.cat_file(self.path(rel))

    def size(self, rel: str) -> int:
        return int(self.fs.size(self.path(rel)))

    def listdir(self, rel: str) -> list[str]:
        """Names (not paths) of the entries of directory ``rel``; [] when it does not exist."""
        p = self.path(rel)
        if not self.fs.isdir(p):
            return []
        return sorted(posixpath.basename(e.rstrip("/")) for e in self.fs.ls(p, detail=False))

    def isdir(self, rel: str) -> bool:
        return self.fs.isdir(self.path(rel))

    def find(self, rel: str) -> list[str]:
        """Relative paths of every file under ``rel`` (recursively); [] when absent."""
        p = self.path(rel)
        if not self.fs.exists(p):
            return []
        if not self.fs.isdir(p):
            return [rel]
        if self.is_local:  # fsspec's local find descends into linked folders; os.walk does not
            out: list[str] = []
            for dirpath, dirnames, filenames in os.walk(p, followlinks=False):
                out.extend(os.path.join(dirpath, d) for d in dirnames if os.path.islink(os.path.join(dirpath, d)))
                out.extend(os.path.join(dirpath, f) for f in filenames)
            return sorted(self.rel(f) for f in out)
        return sorted(self.rel(f) for f in self.fs.find(p))

    def mtime(self, rel: str) -> float | None:
        try:
            return self.fs.modified(self.path(rel)).timestamp()
        except Exception:  # noqa: BLE001 - not every filesystem knows modification times
            return None

    # -- writing ---------------------------------------------------------------------------------
    def makedirs(self, rel: str) -> None:
        self.fs.makedirs(self.path(rel), exist_ok=True)

    def write_bytes(self, rel: str, data: bytes | memoryview) -> None:
        """Write ``data`` to ``rel`` (not atomic; use inside a temporary directory)."""
        p = self.path(rel)
        self.fs.makedirs(posixpath.dirname(p), exist_ok=True)
        if self.is_local:
            with open(p, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        else:
            self.fs.pipe_file(p, bytes(data))

    def write_bytes_atomic(self, rel: str, data: bytes | memoryview) -> None:
        """Write ``data`` under a ``_tmp-`` name beside ``rel``, then rename it to ``rel``."""
        tmp = posixpath.join(posixpath.dirname(rel), f"{TMP_PREFIX}{uuid.uuid4().hex[:12]}-{posixpath.basename(rel)}")
        self.write_bytes(tmp, data)
        self.move(tmp, rel)

    def move(self, src: str, dst: str) -> None:
        """Rename file or directory ``src`` to ``dst`` (replacing a file ``dst``)."""
        s, d = self.path(src), self.path(dst)
        self.fs.makedirs(posixpath.dirname(d), exist_ok=True)
        if self.is_local:
            os.replace(s, d)
        else:
            self.fs.mv(s, d, recursive=self.fs.isdir(s))

    def remove(self, rel: str) -> None:
        p = self.path(rel)
        if self.fs.exists(p):
            self.fs.rm(p, recursive=self.fs.isdir(p))

    def remove_empty_dirs(self, rel: str) -> None:
        """Remove empty directories under ``rel`` (bottom-up), keeping ``rel`` itself."""
        if not self.is_local:
            return  # object stores have no empty directories worth removing
        top = self.path(rel)
        if not os.path.isdir(top):
            return
        for dirpath, dirnames, _ in os.walk(top, topdown=False, followlinks=False):
            for name in dirnames:
                d = os.path.join(dirpath, name)
                if os.path.islink(d):
                    continue  # a link is never removed, nor what it points at
                try:
                    os.rmdir(d)
                except OSError:
                    pass

    def du(self, rels: Iterable[str] = ("",)) -> int:
        total = 0
        for rel in rels:
            p = self.path(rel)
            if self.fs.exists(p):
                total += int(self.fs.du(p, total=True))
        return total


def link_error(loc: Location, rel: str) -> Exception:
    """The one-line ``LinkError`` for the symbolic link ``rel`` under ``loc``."""
    from storage.errors import LinkError

    try:
        target = os.readlink(posixpath.join(loc.root, rel))
    except OSError:
        target = "?"
    return LinkError(f"{rel} in {loc.url} is a symbolic link (to {target[:200]!r}); gpl-dist never follows a link "
                     "inside a run: replace it with the real files, or remove it", rel)


def resolve(root: "str | os.PathLike[str] | Location") -> Location:
    """The :class:`Location` of a local directory or fsspec URL."""
    if isinstance(root, Location):
        return root
    url = os.fspath(root)
    try:
        fs, path = fsspec.core.url_to_fs(url)
    except ImportError as err:  # e.g. s3:// without s3fs
        raise RunDirError(f"cannot open {url}: {err}") from None
    except ValueError as err:  # an unknown protocol
        raise RunDirError(f"cannot open {url}: {err}") from None
    if isinstance(fs, LocalFileSystem):
        path = os.path.abspath(path)
    return Location(fs=fs, root=path.rstrip("/") or "/", url=url)
