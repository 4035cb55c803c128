"""Builds the runtime from a config: the image, the program store, the engine, and the
conversions between the config's and the interpreter's names for things."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

from ncgate.config import Config
from ncgate.gateway.programs import ProgramStore
from ncgate.inputs import Input
from ncgate.interpreter.diagnostics import LineError, RuntimeAlarm
from ncgate.interpreter.engine import Engine
from ncgate.interpreter.engine.trace import Trace
from ncgate.interpreter.isg.frontend import ExternalBinding, IsgFrontEnd, IsgOptions
from ncgate.interpreter.nc110.compiler import NC110
from ncgate.interpreter.nc110.evaluate import compile_expr
from ncgate.interpreter.nc110.nodes import Assign, CompareOp, VarKind, VarRef, View, WaitCond
from ncgate.interpreter.nc110.parser import parse_block
from ncgate.interpreter.settings import Dialect, RuntimeSettings
from ncgate.plc.image import Change, IOImage
from ncgate.plc.scan import PlcRuntime, PlcStatus


def runtime_settings(config: Config, closed: bool) -> RuntimeSettings:
    """The engine's settings: every one of them that ``[nc]`` holds, by the same name; the
    ISG dialect adds the buffer effect and operator starts in every channel (spec 5)."""
    nc = config.nc
    names = {f.name for f in dataclasses.fields(RuntimeSettings)} & set(dir(nc))
    isg = nc.dialect is Dialect.ISG
    return RuntimeSettings(**{name: getattr(nc, name) for name in names}, closed=closed,
                           buffered=isg, any_process_starts=isg)


def external_bindings(config: Config) -> dict[str, ExternalBinding]:
    """``[nc.ve]`` as the ISG front end reads it: NAME -> image variable and sync."""
    out = {}
    for name, ve in config.nc.ve.items():
        text = ve.map.upper()
        if text.startswith("K"):  # K12: the K packet's byte 12, as SK12
            text = "S" + text
        (area, index, view), _, _ = parse_condition(f"{text}=0")
        out[name] = ExternalBinding(area, index, view, ve.sync, ve.map)
    return out


def front_end_of(config: Config) -> NC110 | IsgFrontEnd:
    if config.nc.dialect is Dialect.ISG:
        return IsgFrontEnd(IsgOptions(config.nc.isg.max_events, config.nc.isg.signal_params,
                                      external_bindings(config)))
    return NC110()


@dataclass
class Runtime:
    config: Config
    image: IOImage
    store: ProgramStore
    engine: Engine
    trace: Trace
    plc: PlcRuntime | None = None  # the PLC logic, when [plc] logic names any


def build_runtime(config: Config, closed: bool, trace: Trace | None = None) -> Runtime:
    image = IOImage(config.plc.sa_bits, config.plc.k_bytes, config.plc.syvars)
    store = ProgramStore(config)
    trace = trace if trace is not None else Trace()
    front_end = front_end_of(config)
    engine = Engine(runtime_settings(config, closed), image, store, front_end, trace)
    if isinstance(front_end, IsgFrontEnd):
        front_end.attach(engine, engine.reset_listeners)

    def on_write(changes: list[Change] | tuple[Change, ...], writer: str) -> None:
        for change in changes:
            engine.note_write(variable_name(change.area, change.index, change.view),
                              change.value, writer)

    image.subscribe(on_write)  # type: ignore[arg-type]
    return Runtime(config, image, store, engine, trace)


def variable_name(area: str, index: int, view: str) -> str:
    if area == "SYVAR" or (area == "SA" and view == "bit") or (area == "SK" and view == "BY"):
        return f"{area}{index}"
    return f"{area}{index}.{view}"


class Backend(Protocol):
    """What the fieldbus adapters act on (the Gateway): the image and processes, read on the
    loop, and the one way in (:meth:`ncgate.gateway.Gateway.apply`)."""

    @property
    def image(self) -> IOImage: ...

    @property
    def engine(self) -> Engine: ...

    def apply(self, item: Input) -> None: ...

    @property
    def plc_status(self) -> PlcStatus | None: ...


ImageVar = tuple[str, int, str]


def _image_var(var: VarRef) -> ImageVar:
    return (var.kind.value, var.index, var.view.value)


def parse_condition(text: str) -> tuple[ImageVar, str, int]:
    """``"SYVAR1=10"`` -> (("SYVAR", 1, "IN"), "=", 10).  Raises ValueError with a reason."""
    try:
        block = parse_block(f"(WAI,{text})", "<condition>", 1)
    except LineError as exc:
        raise ValueError(exc.diagnostic.message) from None
    (item,) = block.items
    if not isinstance(item, WaitCond):
        raise ValueError(f"{text!r} is not a condition on SA, SK or SYVAR")
    if item.var.view is View.BIT and item.op in (CompareOp.GT, CompareOp.LT):
        raise ValueError(f"{item.var.name} is a bit, only = and # compare it")
    try:
        value = compile_expr(item.value)([], _no_read)
    except (RuntimeAlarm, IndexError):
        raise ValueError("the value must be a constant") from None
    if value != int(value):
        raise ValueError(f"{value:g} is not a whole number")
    return _image_var(item.var), item.op.value, int(value)


def parse_assignment(text: str) -> tuple[ImageVar, int]:
    """``"SA10=1"`` -> (("SA", 10, "bit"), 1).  Raises ValueError with a reason."""
    try:
        block = parse_block(text, "<assignment>", 1)
    except LineError as exc:
        raise ValueError(exc.diagnostic.message) from None
    if len(block.items) != 1 or not isinstance(block.items[0], Assign):
        raise ValueError(f"{text!r} is not an assignment such as SA10=1")
    item = block.items[0]
    if item.target.kind is VarKind.E:
        raise ValueError("E parameters belong to a process, not to the image")
    try:
        value = compile_expr(item.expr)([], _no_read)
    except (RuntimeAlarm, IndexError):
        raise ValueError("the value must be a constant") from None
    if value != int(value):
        raise ValueError(f"{value:g} is not a whole number")
    return _image_var(item.target), int(value)


def _no_read(area: str, index: int, view: str) -> int:
    raise IndexError("no image here")
