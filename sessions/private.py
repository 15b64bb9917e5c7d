"""Patients' data on disk: folders 0700 and files 0600, whatever the umask says.

The server (its data directory, database, uploads) and the home station (its spool of
recorded sessions, the cached prescriptions) both keep patients' data; only the account that
runs them reads it. Both import these from here, below both.
"""

from __future__ import annotations

import os
from pathlib import Path

PRIVATE_DIR = 0o700
PRIVATE_FILE = 0o600


def private_data_dir(path: Path) -> None:
    """Create ``path`` (and missing parents) readable by the owner only. A directory that
    exists already keeps its mode: an administrator may have chosen it."""
    if not path.exists():
        path.mkdir(mode=PRIVATE_DIR, parents=True, exist_ok=True)
        os.chmod(path, PRIVATE_DIR)  # mkdir's mode is masked by the umask


def write_private(path: os.PathLike[str] | str, text: str) -> None:
    """Replace ``path`` with ``text`` at once (a crash leaves the old file or the new one),
    mode 0600 and on the disk before it takes the old one's place."""
    tmp = f"{os.fspath(path)}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, PRIVATE_FILE)
    with os.fdopen(fd, "w") as f:
        os.fchmod(f.fileno(), PRIVATE_FILE)  # whatever the umask, or a leftover file, said
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def fsync_dir(directory: Path) -> None:
    """Put a directory's entries (a file created, renamed or moved in it) on the disk."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
