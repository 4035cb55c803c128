"""Builds the runtime from a config: the image, the program store, the engine, and the
conversions between the config's and the interpreter's names for things."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from ncgate.config import Config
from ncgate.errors import InputRefused
from ncgate.gateway.programs import ProgramStore, dialect_options
from ncgate.gateway.programs import external_bindings as external_bindings
from ncgate.inputs import Input, PlcVar, Var
from ncgate.inputs import var_name as variable_name
from ncgate.interpreter.dialect import DialectFrontEnd
from ncgate.interpreter.dialects import ImageVar as ImageVar
from ncgate.interpreter.dialects import dialect_of
from ncgate.interpreter.dialects import parse_assignment as parse_assignment
from ncgate.interpreter.dialects import parse_condition as parse_condition
from ncgate.interpreter.engine import Engine
from ncgate.interpreter.engine.trace import Trace
from ncgate.interpreter.settings import RuntimeSettings
from ncgate.plc.image import Change, IOImage
from ncgate.plc.scan import PlcRuntime, PlcStatus

if TYPE_CHECKING:
    from ncgate.gateway.plant import Plant
    from ncgate.gateway.view import CellView, ViewPublisher


def runtime_settings(config: Config, closed: bool) -> RuntimeSettings:
    """The engine's settings: every one of them that ``[nc]`` holds, by the same name; the
    dialect adds what it needs of the engine (ISG: the buffer effect, spec 5.4)."""
    nc = config.nc
    names = {f.name for f in dataclasses.fields(RuntimeSettings)} & set(dir(nc))
    dialect = dialect_of(nc.dialect)
    symbols = tuple((image_var(text).address, name) for name, text in config.symbols.items())
    return RuntimeSettings(**{name: getattr(nc, name) for name in names}, closed=closed,
                           buffered=dialect.buffered, names=symbols)


def front_end_of(config: Config) -> DialectFrontEnd:
    return dialect_of(config.nc.dialect).front_end(dialect_options(config))


@dataclass
class Runtime:
    config: Config
    image: IOImage
    store: ProgramStore
    engine: Engine
    trace: Trace
    plc: PlcRuntime | None = None  # the PLC logic, when [plc] logic names any
    plant: Plant | None = None  # the plant's models and faults (start_plant)
    # The PLC's interlock inputs, levels ("feed hold", nc.feed_hold_input; "cycle start
    # inhibit"): while one is set, a cycle start is refused (the door asks).
    interlocks: tuple[tuple[str, Var], ...] = ()
    # The I/O names of [symbols]: NAME (upper case) -> its variable.
    symbols: dict[str, Var] = dataclasses.field(default_factory=dict)

    def var(self, text: str) -> Var:
        """A variable named as a user names it: an I/O name (``door_closed``) or an image
        variable (``SA10``); InputRefused (UNKNOWN_VARIABLE) otherwise."""
        found = self.symbols.get(text.strip().upper()) if isinstance(text, str) else None
        return found if found is not None else Var.parse(text)

    def force_target(self, text: str) -> Var | PlcVar:
        """What a force names: an I/O name or an image variable (:meth:`var`), else a PLC
        variable's path (``main.n``); InputRefused (UNKNOWN_VARIABLE) for neither."""
        try:
            return self.var(text)
        except InputRefused:
            return PlcVar(text)

    def resolve(self, text: str) -> str:
        """An assignment or condition with an I/O name on its left put back as the image
        variable it names (``door_closed=1`` -> ``SA10=1``), for the image's parser."""
        for i, ch in enumerate(text):
            if ch in "=#<>":
                name = text[:i].strip()
                found = self.symbols.get(name.upper())
                return f"{found}{text[i:]}" if found is not None else text
        return text


def build_runtime(config: Config, closed: bool, trace: Trace | None = None) -> Runtime:
    image = IOImage(config.plc.sa_bits, config.plc.k_bytes, config.plc.syvars)
    store = ProgramStore(config)
    trace = trace if trace is not None else Trace()
    front_end = front_end_of(config)
    engine = Engine(runtime_settings(config, closed), image, store, front_end, trace)
    front_end.attach(engine, engine.reset_listeners)
    store.calls = front_end.exe_calls  # what the gateway reads ahead of a program's EXEs

    def on_write(changes: list[Change] | tuple[Change, ...], writer: str) -> None:
        for change in changes:
            engine.note_write(variable_name(change.area, change.index, change.view),
                              change.value, writer)

    image.subscribe(on_write)  # type: ignore[arg-type]

    def on_overridden(changes: list[tuple[str, int, str, int]], writer: str) -> None:
        for area, index, view, value in changes:
            engine.note_forced(variable_name(area, index, view), value, writer)

    image.on_overridden = on_overridden
    interlocks = tuple((what, image_var(text)) for what, text in (
        ("feed hold", config.nc.feed_hold_input),
        ("cycle start inhibit", config.nc.cycle_start_inhibit_input)) if text)
    symbols = {name.upper(): image_var(text) for name, text in config.symbols.items()}
    return Runtime(config, image, store, engine, trace, interlocks=interlocks, symbols=symbols)


def start_plant(runtime: Runtime, apply: Callable[[Input], None], *, closed: bool,
                served: frozenset[str] | None = frozenset(), server: str = "sim") -> Plant:
    """The plant of ``[plant]`` on ``runtime`` (its models at rest, their outputs written,
    the faults of ``[[plant.fault]]`` armed by the caller); faults need it even without
    models.  ``served``: the fieldbuses whose faults act (``modbus``, ``canopen``), and
    ``server`` who serves them: a fault of another is said to have no effect (None: say
    nothing -- a replay, whose record holds what the fault did)."""
    from ncgate.gateway.plant import Plant

    plant = Plant(runtime, apply, closed=closed)
    plant.served, plant.server = served, server
    runtime.plant = plant
    plant.start()
    return plant


@functools.lru_cache(maxsize=4096)  # (a Var is frozen: each sim of a sweep or a scenario
def image_var(text: str) -> Var:    # suite reads the same config's symbols again)
    """An image variable as the config names it (``K12`` is the K packet's byte: SK12)."""
    return Var.parse("S" + text if text.upper().startswith("K") else text)


class Backend(Protocol):
    """What the fieldbus adapters act on (the Gateway): the cell's view (the processes' status
    and why-records, the SND log, the PLC status, the forces, the image, the plant:
    :mod:`ncgate.gateway.view`), the live image, read on the loop, and the one way in
    (:meth:`ncgate.gateway.Gateway.apply`)."""

    @property
    def view(self) -> CellView: ...

    @property
    def views(self) -> ViewPublisher: ...  # one process's view, the last SND, on the loop

    @property
    def image(self) -> IOImage: ...

    @property
    def engine(self) -> Engine: ...

    @property
    def runtime(self) -> Runtime: ...

    def apply(self, item: Input) -> None: ...

    @property
    def lag_s(self) -> float: ...  # machine seconds the engine is behind the clock

    @property
    def plc_status(self) -> PlcStatus | None: ...
