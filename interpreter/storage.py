"""Storage devices MP0..MP3: where programs are found by name (spec 1.1).

A device is a directory.  A program name matches a file name without its extension (``.nc``,
``.txt`` or none), case-insensitively.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from ncgate.interpreter.diagnostics import ProgramNotFoundError

PROGRAM_SUFFIXES = ("", ".nc", ".txt")


class Storage:
    """The configured storage devices and the default one (the manual's PGCFIL)."""

    def __init__(self, devices: Mapping[str, Path], default: str) -> None:
        self.devices = {name.upper(): Path(path) for name, path in devices.items()}
        self.default = default.upper()

    def has_device(self, device: str | None) -> bool:
        return (device or self.default).upper() in self.devices

    def find(self, name: str, device: str | None = None) -> Path | None:
        """The file holding program ``name`` on ``device`` (default device if None)."""
        folder = self.devices.get((device or self.default).upper())
        if folder is None or not folder.is_dir():
            return None
        wanted = name.upper()
        for suffix in PROGRAM_SUFFIXES:
            exact = folder / f"{name}{suffix}"
            if exact.is_file():
                return exact
        for entry in sorted(folder.iterdir()):
            if (entry.is_file() and entry.suffix.lower() in PROGRAM_SUFFIXES
                    and program_name(entry).upper() == wanted):
                return entry
        return None

    def locate(self, name: str, device: str | None = None) -> Path:
        found = self.find(name, device)
        if found is None:
            where = (device or self.default).upper()
            raise ProgramNotFoundError(f"program {name} is not on {where}")
        return found


def program_name(path: Path) -> str:
    """Program name = file name without its extension (spec 1.1)."""
    return path.stem if path.suffix.lower() in (".nc", ".txt") else path.name


def file_version(path: Path) -> tuple[int, int]:
    """A file's (mtime_ns, size): a program is read and checked once per version."""
    stat = path.stat()
    return stat.st_mtime_ns, stat.st_size
