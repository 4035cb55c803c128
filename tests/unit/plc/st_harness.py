"""A PLC runtime over a real IOImage, with a recording NC (the NC port is ncgate's own
interface, not a protocol): programs are run scan by scan at chosen times."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ncgate.errors import InputRefused, Reason
from ncgate.plc.image import IOImage
from ncgate.plc.scan import NcSnapshot, PlcRuntime
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.parser import parse_source

IDLE: NcSnapshot = (0, 0, 0, False, False, 0, True, False)


@dataclass
class RecordingNc:
    processes: list[NcSnapshot] = field(default_factory=lambda: [IDLE] * 5)
    event_count: int = 0
    last: tuple[int, int, int] = (0, 0, 0)
    commands: list[int | tuple[int, int]] = field(default_factory=list)
    overrides: list[tuple[int, int | None]] = field(default_factory=list)
    where: list[str] = field(default_factory=list)  # FILE:LINE of each command
    sends: list[tuple[int, int]] = field(default_factory=list)
    faults: list[str] = field(default_factory=list)
    hazards: list[str] = field(default_factory=list)
    refuse_sends: bool = False

    def snapshot(self) -> list[NcSnapshot]:
        return list(self.processes)

    def events(self) -> int:
        return self.event_count

    def last_snd(self) -> tuple[int, int, int]:
        return self.last

    def command(self, word: int, where: str = "", process: int | None = None) -> None:
        self.commands.append(word if process is None else (word, process))
        self.where.append(where)

    def override(self, feed: int, where: str = "", process: int | None = None) -> None:
        self.overrides.append((feed, process))

    def send(self, sender: int, target: int, where: str = "") -> None:
        if self.refuse_sends:
            raise InputRefused(Reason.NOT_RUNNING, f"process {target} runs no program")
        self.sends.append((sender, target))

    def fault(self, message: str) -> None:
        self.faults.append(message)

    def hazard(self, message: str) -> None:
        self.hazards.append(message)


class Plc:
    def __init__(self, source: str, *, context: Context | None = None,
                 loop_limit: int = 100_000) -> None:
        self.image = IOImage(64, 16, 8)
        ctx = context or Context(64, 16, 8, 5, frozenset({4, 5}))
        self.logic = compile_logic([parse_source(source, "test.st")], ctx)
        self.nc = RecordingNc()
        self.writes: list[tuple[list[Any], str]] = []
        self.image.subscribe(lambda changes, who: self.writes.append((list(changes), who)))
        self.runtime = PlcRuntime(self.logic, self.image, self.nc, list(self.logic.programs),
                                  loop_limit)
        self.now_ms = 0

    def scan(self, times: int = 1, every_ms: int = 10) -> Plc:
        for _ in range(times):
            self.runtime.scan(self.now_ms)
            self.now_ms += every_ms
        return self

    def __getitem__(self, path: str) -> Any:
        return self.runtime.read(path)


def program(body: str, decls: str = "") -> str:
    return f"PROGRAM main\nVAR\n{decls}\nEND_VAR\n{body}\nEND_PROGRAM\n"
