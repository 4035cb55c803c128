"""The image's notation: ``SA10``, ``SK12.BY``, ``SYVAR1>5`` -- image variables as NC-110
programs write them.  The config and the scripts (``[[write]] set``/``when``, ``[nc.ve]``
maps) and the fieldbus test kits write them so whatever the programs' dialect; they reach this
module through the registry (:mod:`ncgate.interpreter.dialects`), not by naming NC-110."""

from __future__ import annotations

import functools
from collections.abc import Callable

from ncgate.interpreter.diagnostics import LineError, RuntimeAlarm
from ncgate.interpreter.nc110.evaluate import compile_expr
from ncgate.interpreter.nc110.nodes import Assign, CompareOp, VarKind, VarRef, View, WaitCond
from ncgate.interpreter.nc110.parser import parse_block

ImageVar = tuple[str, int, str]


def _image_var(var: VarRef) -> ImageVar:
    return (var.kind.value, var.index, var.view.value)


@functools.lru_cache(maxsize=1024)  # (a scenario suite parses the same few at every run)
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


def comparison(op: str, value: float) -> Callable[[float], bool]:
    """The test of a condition's operator (``"="``, ``"#"``, ``">"``, ``"<"``) on a value."""
    return CompareOp(op).against(value)


def _no_read(area: str, index: int, view: str) -> int:
    raise IndexError("no image here")
