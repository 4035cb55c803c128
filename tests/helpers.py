"""A small harness for engine tests: programs from strings, the real image, the virtual clock."""

from __future__ import annotations

import contextlib
import gc
import types
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ncgate.interpreter.diagnostics import ProgramNotFoundError, ProgramSyntaxError
from ncgate.interpreter.engine import Engine, run_virtual
from ncgate.interpreter.engine.trace import Event, Trace
from ncgate.interpreter.nc110.checker import CheckContext, check_program
from ncgate.interpreter.nc110.compiler import NC110
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.settings import RuntimeSettings
from ncgate.plc.image import IOImage


class DictLoader:
    def __init__(self, programs: dict[str, str], processes: int, external: frozenset[int]):
        self.programs = {name.upper(): (name, text) for name, text in programs.items()}
        self.processes = processes
        self.external = external

    def load(self, name: str, device: str | None, process: int) -> Program:
        found = self.programs.get(name.upper())
        if found is None:
            raise ProgramNotFoundError(f"program {name} is not on MP0")
        real_name, text = found
        program = Program(real_name, f"{real_name}.nc", text)
        errors = [d for d in check_program(program, CheckContext(
            processes=self.processes, external=self.external, runs_in=frozenset({process}),
            find_program=lambda n, d: n.upper() in self.programs)) if d.is_error]
        if errors:
            raise ProgramSyntaxError(errors)
        return program


@dataclass
class Sim:
    engine: Engine
    image: IOImage
    outcome: str = ""
    trace: Trace = field(default_factory=Trace)

    def events(self, *kinds: str) -> list[Event]:
        return [e for e in self.engine.trace.events if not kinds or e["event"] in kinds]

    def first(self, kind: str, **match: Any) -> Event:
        for e in self.events(kind):
            if all(e.get(k) == v for k, v in match.items()):
                return e
        raise AssertionError(f"no {kind} event with {match}: {self.events()}")

    def run(self, until: float | None = None) -> str:
        self.outcome = run_virtual(self.engine, until)
        return self.outcome


def make_sim(programs: dict[str, str], **settings: Any) -> Sim:
    settings.setdefault("processes", 5)
    rs = RuntimeSettings(**settings)
    image = IOImage()
    engine = Engine(rs, image, DictLoader(programs, rs.processes, rs.external), NC110())
    image.subscribe(lambda changes, who: [
        engine.note_write(_name(c.area, c.index, c.view), c.value, who) for c in changes])
    return Sim(engine, image)


def _name(area: str, index: int, view: str) -> str:
    if area == "SYVAR" or (area == "SA" and view == "bit") or (area == "SK" and view == "BY"):
        return f"{area}{index}"
    return f"{area}{index}.{view}"


def simulate(programs: dict[str, str], main: str = "A", until: float | None = None,
             **settings: Any) -> Sim:
    sim = make_sim(programs, **settings)
    sim.engine.start(main)
    sim.run(until)
    return sim


def write_cell(folder: Path, config_text: str, programs: dict[str, str]) -> Path:
    """A cell on disk: ncgate.toml and its programs (NAME.nc) in one folder."""
    (folder / "ncgate.toml").write_text(config_text)
    for name, text in programs.items():
        (folder / f"{name}.nc").write_text(text)
    return folder


def _ncgate_owned(obj: object) -> str | None:
    """What an object is, if it is ncgate's: an instance of one of its classes, one of its
    functions or a method bound to one (else None)."""
    if isinstance(obj, types.MethodType):
        obj = obj.__func__
    if isinstance(obj, types.FunctionType):
        return f"{obj.__module__}.{obj.__qualname__}" if obj.__module__.startswith(
            "ncgate.") else None
    kind = type(obj)
    if kind.__module__.startswith("ncgate."):
        return f"{kind.__module__}.{kind.__qualname__}"
    return None


@contextlib.contextmanager
def cyclic_garbage() -> Iterator[list[str]]:
    """What of ncgate's became garbage only the cyclic collector could free, in the body:
    the list is filled when the body ends.  The collector stands still meanwhile, so nothing
    is freed behind the test's back; what the test's own clients leave (a canopen master,
    pytest's loop) is not counted."""
    gc.collect()
    flags, enabled = gc.get_debug(), gc.isenabled()
    gc.disable()
    gc.set_debug(flags | gc.DEBUG_SAVEALL)
    found: list[str] = []
    try:
        yield found
        gc.collect()
        found.extend(sorted({name for o in gc.garbage if (name := _ncgate_owned(o))}))
    finally:
        gc.garbage.clear()
        gc.set_debug(flags)
        if enabled:
            gc.enable()
