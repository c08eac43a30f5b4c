"""Atomic writes of a set of text files into one folder, and of a whole folder."""

from __future__ import annotations

import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path

from stereogeo_cli.errors import StereoGeoError


def write_files_atomically(out_dir: str | os.PathLike, files: dict[str, str | bytes]) -> list[Path]:
    """Write ``{file name: text or bytes}`` into ``out_dir`` (created if needed); return the paths in order.

    Every file goes to a temporary file in ``out_dir`` first, is flushed and fsynced; only when all of them
    are on disk are they renamed over their targets with ``os.replace``. An interrupted or failing run
    leaves each target either as it was or complete, never half written, and no temporary files behind.
    A folder that cannot be made or written raises :class:`StereoGeoError` (exit code 2) before any target
    is touched.
    """
    folder = Path(out_dir)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise StereoGeoError(f"output folder {folder} is not a folder") from None
    except OSError as exc:
        raise StereoGeoError(f"cannot create output folder {folder}: {exc.strerror or exc}") from None

    for name in files:
        if (folder / name).is_dir():
            raise StereoGeoError(f"cannot write {folder / name}: a folder of that name is in the way")
    umask = os.umask(0)
    os.umask(umask)
    pending: list[tuple[Path, Path]] = []  # (temporary, target)
    try:
        for name, text in files.items():
            target = folder / name
            target.parent.mkdir(parents=True, exist_ok=True)  # a name may hold subfolders ("sparse/0/…")
            fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
            pending.append((Path(tmp_name), target))
            binary = isinstance(text, bytes)
            with os.fdopen(
                fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8", "newline": "\n"})
            ) as f:
                if hasattr(os, "fchmod"):  # mkstemp makes 0600; give the file the usual permissions
                    os.fchmod(f.fileno(), 0o666 & ~umask)
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
        for tmp, target in pending:
            os.replace(tmp, target)
        for parent in dict.fromkeys(target.parent for _, target in pending):
            _fsync_folder(parent)
    except OSError as exc:
        for tmp, _ in pending:
            tmp.unlink(missing_ok=True)
        raise StereoGeoError(f"cannot write to output folder {folder}: {exc.strerror or exc}") from None
    except BaseException:
        for tmp, _ in pending:
            tmp.unlink(missing_ok=True)
        raise
    return [target for _, target in pending]


# the temporary files of write_files_atomically: mkstemp's prefix ".<target>.", its 8 random characters
# (lower-case letters, digits, "_") and the suffix ".tmp"
_TEMPORARY = re.compile(r"\.(?P<target>.+)\.[a-z0-9_]{8}\.tmp")


def remove_leftovers(folder: str | os.PathLike, targets: Iterable[str] | None = None) -> list[Path]:
    """Remove what :func:`write_files_atomically` left in ``folder`` when its process was killed mid-write:
    its temporary files (``.<name>.XXXXXXXX.tmp``), only those of the target names ``targets`` where given;
    return them. No other file is touched, nor any folder or link; a folder that is not there holds none."""
    wanted = None if targets is None else set(targets)
    try:
        paths = sorted(Path(folder).iterdir())
    except OSError:
        return []
    removed = []
    for path in paths:
        m = _TEMPORARY.fullmatch(path.name)
        if m is None or (wanted is not None and m["target"] not in wanted):
            continue
        try:
            if stat.S_ISREG(path.lstat().st_mode):
                path.unlink()
                removed.append(path)
        except OSError:
            pass  # gone meanwhile, or not ours to remove
    return removed


def _fsync_folder(folder: Path) -> None:
    # Makes the renames themselves durable; not possible on every platform (e.g. Windows), so best effort.
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def replace_folder_atomically(out_dir: str | os.PathLike, files: dict[str, str | bytes]) -> list[Path]:
    """Make ``out_dir`` hold exactly ``files`` (``{name: text or bytes}``, names may hold subfolders), in
    one step: they are written into a new hidden folder beside it (each file fsynced), which then takes
    ``out_dir``'s place. Where ``out_dir`` already holds something, the two folders' names are exchanged in
    one system call (Linux's ``renameat2``; elsewhere two renames, with ``out_dir`` briefly absent) and the
    old content is removed after. An interrupted or failing run leaves ``out_dir`` as it was and no
    temporary folder behind. Returns the written paths as they lie in ``out_dir``.

    Raises :class:`StereoGeoError` (exit code 2) where the folder cannot be made or written.
    """
    folder = Path(out_dir)
    if folder.exists() and not folder.is_dir():
        raise StereoGeoError(f"output folder {folder} is not a folder")
    parent = folder.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=parent, prefix=f".{folder.name}.", suffix=".tmp"))
    except OSError as exc:
        raise StereoGeoError(f"cannot create output folder {folder}: {exc.strerror or exc}") from None
    old: Path | None = None
    try:
        umask = os.umask(0)
        os.umask(umask)
        staging.chmod(0o777 & ~umask)  # mkdtemp makes 0700; give the folder the usual permissions
        write_files_atomically(staging, files)
        if folder.is_dir() and any(folder.iterdir()):
            if _exchange(staging, folder):
                old = staging  # the new content is in ``folder`` now, the old in ``staging``
            else:
                old = Path(tempfile.mkdtemp(dir=parent, prefix=f".{folder.name}.", suffix=".old.tmp"))
                os.replace(folder, old)  # onto the empty folder just made
                try:
                    os.replace(staging, folder)
                except BaseException:
                    os.replace(old, folder)  # the old content back in its place
                    raise
        else:
            if folder.is_dir():
                folder.rmdir()
            os.replace(staging, folder)
        _fsync_folder(parent)
    except OSError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise StereoGeoError(f"cannot write to output folder {folder}: {exc.strerror or exc}") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return [folder / name for name in files]


def _exchange(a: Path, b: Path) -> bool:
    """Exchange the names of the folders ``a`` and ``b`` in one step; False where the system cannot."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # a C library without renameat2 (glibc before 2.28)
        return False
    at_fdcwd, rename_exchange = -100, 2
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0
