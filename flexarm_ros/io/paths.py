"""Output paths checked before the work: a run that takes minutes must not fail at the end
because its ``--out``, ``--record``, ``--png``, ``--report`` or ``--rerun`` cannot be
written. Each check raises :class:`~flexarm_ros.errors.InputError` (exit 2) naming the
option, the path and what is expected; nothing is created or changed by a check (the
writability probe is a temporary file, removed at once).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from flexarm_ros.errors import InputError


def _probe_directory(flag: str, given, directory: Path) -> None:
    """InputError unless a file can be created in ``directory`` (an existing directory)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".flexarm_probe_", dir=directory)
    except OSError as exc:
        raise InputError(f"{flag}: got {str(given)!r}, expected a path in a writable "
                         f"directory (cannot create a file in {directory}: "
                         f"{exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(flag: str, path, suffixes: tuple[str, ...] | None = None) -> Path:
    """A file the command will write: not an existing directory, in an existing writable
    directory, writable if it exists, with one of ``suffixes`` (lower case, with the dot)
    when given. Returns the path."""
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise InputError(f"{flag}: got {str(path)!r}, expected a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise InputError(f"{flag}: got {str(path)!r}, expected a "
                         f"{' or '.join(suffixes)} file name")
    if p.is_dir():
        raise InputError(f"{flag}: got {str(path)!r}, an existing directory, expected a file "
                         f"name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise InputError(f"{flag}: got {str(path)!r}, expected a path in an existing "
                         f"directory ({parent} {what})")
    if p.exists():
        try:
            with open(p, "ab"):
                pass
        except OSError as exc:
            raise InputError(f"{flag}: got {str(path)!r}, expected a writable file "
                             f"({exc.strerror or exc})") from None
    _probe_directory(flag, path, parent)
    return p


def check_output_dir(flag: str, path) -> Path:
    """A directory the command will create (with its parents) or write into: not an
    existing file, and writable where it exists or where it would be created."""
    p = Path(path)
    if str(path) == "":
        raise InputError(f"{flag}: got '', expected a directory name")
    if p.exists() and not p.is_dir():
        raise InputError(f"{flag}: got {str(path)!r}, an existing file, expected a "
                         f"directory")
    existing = p
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise InputError(f"{flag}: got {str(path)!r}, expected a directory path "
                         f"({existing} is a file)")
    _probe_directory(flag, path, existing if existing.exists() else Path("."))
    return p


#: the outputs this process has written whole (a table renamed into place, its meta file),
#: in order: what an interrupted command says it kept (:func:`flexarm_ros.cli.interrupted`)
_WRITTEN: list[str] = []


def note_written(path) -> None:
    """Record that ``path`` has been written whole."""
    _WRITTEN.append(str(path))


def written() -> list[str]:
    """The outputs recorded by :func:`note_written` since the last :func:`forget_written`."""
    return list(_WRITTEN)


def forget_written() -> None:
    """Start a new record (each command of :func:`flexarm_ros.cli.main`)."""
    _WRITTEN.clear()
