"""Atomic writes of a set of text files into one folder."""

from __future__ import annotations

import os
import tempfile
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
