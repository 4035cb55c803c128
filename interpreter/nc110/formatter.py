"""Canonical text of a block: the inverse of the parser, up to spacing and letter case.

``parse_block(format_block(b))`` gives back ``b`` (spans aside) for every block ``b`` the
parser produces.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

from ncgate.interpreter.nc110.nodes import (
    Assign,
    Binary,
    Block,
    Branch,
    Call,
    Display,
    Dwell,
    EndRepeat,
    Exe,
    Expr,
    InertCode,
    Item,
    Jump,
    Num,
    Rel,
    Repeat,
    Snd,
    Unary,
    VarRef,
    WaitCond,
    WaitProc,
    Word,
)

_PRECEDENCE = {"+": 1, "-": 1, "*": 2, "/": 2}


def format_number(value: float) -> str:
    if value == int(value) and abs(value) < 1e15:
        return str(int(value))
    text = repr(value)
    if "e" in text or "E" in text:
        text = f"{value:.15f}".rstrip("0")
    return text


def format_expr(expr: Expr, parent: int = 0) -> str:
    if isinstance(expr, Num):
        text = format_number(abs(expr.value))
        return f"-{text}" if expr.value < 0 or (expr.value == 0 and str(expr.value)[0] == "-") \
            else text
    if isinstance(expr, VarRef):
        return expr.name
    if isinstance(expr, Unary):
        return f"{expr.op}{format_expr(expr.operand, 3)}"
    if isinstance(expr, Call):
        return f"{expr.func}({format_expr(expr.arg)})"
    assert isinstance(expr, Binary)
    mine = _PRECEDENCE[expr.op]
    # Left-associative: the right operand needs parentheses at equal precedence.
    text = f"{format_expr(expr.left, mine)}{expr.op}{format_expr(expr.right, mine + 1)}"
    return f"({text})" if mine < parent else text


def format_item(item: Item) -> str:
    if isinstance(item, Word):
        value = item.value.name if isinstance(item.value, VarRef) else item.text
        return f"{item.letter}{value}"
    if isinstance(item, Assign):
        return f"{item.target.name}={format_expr(item.expr)}"
    if isinstance(item, Exe):
        device = f"/{item.device}" if item.device else ""
        return f"(EXE,{format_expr(item.process)},{item.program}{device})"
    if isinstance(item, Rel):
        return "(REL)"
    if isinstance(item, WaitProc):
        return f"(WAI,{format_expr(item.process)})"
    if isinstance(item, WaitCond):
        return f"(WAI,{item.var.name}{item.op.value}{format_expr(item.value)})"
    if isinstance(item, Snd):
        return f"(SND,{format_expr(item.process)})"
    if isinstance(item, Jump):
        return f"(BNC,{item.label})"
    if isinstance(item, Branch):
        return f"({item.op.value},{format_expr(item.left)},{format_expr(item.right)},{item.label})"
    if isinstance(item, Repeat):
        return f"(RPT,{format_expr(item.count)})"
    if isinstance(item, EndRepeat):
        return "(ERP)"
    if isinstance(item, Dwell):
        return f"(DLY,{format_expr(item.seconds)})"
    if isinstance(item, Display):
        args = "".join(f",{format_expr(a)}" for a in item.args)
        return f'(DIS,"{item.text}"{args})'
    assert isinstance(item, InertCode)
    args = "".join(f",{a}" for a in item.args)
    return f"({item.code}{args})"


def format_block(block: Block) -> str:
    parts: list[str] = []
    if block.deleted:
        parts.append("/")
    if block.label is not None:
        parts.append(f'"{block.label}"')
    if block.number is not None:
        parts.append(f"N{block.number}")
    if block.synced:
        parts.append("#")
    text = "".join(parts)
    for item in block.items:
        piece = format_item(item)
        # Two words must not run together into something else (X1 then .5 -> X1.5):
        # a space between items is always legal.
        text = f"{text} {piece}" if text and not text.endswith(("/", '"', "#")) else text + piece
    if block.comment is not None:
        text = f"{text} ;{block.comment}" if text else f";{block.comment}"
    return text
