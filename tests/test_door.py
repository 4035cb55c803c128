"""One door in: every input from outside the engine reaches it through the door
(gateway/door.py), typed (ncgate.inputs) and refused with a Reason that each protocol maps in
one table."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from ncgate.errors import InputRefused, NcgateError, Reason
from ncgate.gateway import Gateway, load_config
from ncgate.gateway.canopen.codes import REFUSAL as SDO_ABORTS
from ncgate.gateway.modbus.codes import REFUSAL as MODBUS_EXCEPTIONS
from ncgate.inputs import (
    Command,
    FieldbusAlarm,
    Snd,
    Source,
    SourceKind,
    Start,
    Var,
    Write,
    Writes,
)
from ncgate.plc.image import PlcError

ROOT = Path(__file__).resolve().parent.parent
FREE = {"modbus.port": 0, "canopen.enabled": False}

# What only the door may call: the engine's and the image's ways of being changed from
# outside.  (The engine's own modules and the PLC scan's output stage are inside the cell.)
MUTATORS = {"cycle_start", "external_snd", "fieldbus_alarm", "apply_writes", "override", "switch",
            "set_break",
            "single_block"}


def _offending_calls(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
            continue
        name, owner = node.func.attr, node.func.value
        owner_name = (owner.attr if isinstance(owner, ast.Attribute)
                      else owner.id if isinstance(owner, ast.Name) else "")
        if (name in MUTATORS
                or (owner_name == "engine" and name in {"start", "hold", "reset", "step"})
                or (owner_name == "image" and name == "write")):
            out.append(f"{path.relative_to(ROOT)}:{node.lineno}: .{name}()")
    return out


def test_every_adapter_goes_through_the_door() -> None:
    """The call sites that change the engine or the image from outside it: the door alone."""
    found = [call for path in sorted((ROOT / "gateway").rglob("*.py"))
             for call in _offending_calls(path)]
    assert [c for c in found if not c.startswith("gateway/door.py")] == []
    assert any(c.startswith("gateway/door.py") for c in found)  # the search finds calls


@pytest.mark.parametrize("table", [MODBUS_EXCEPTIONS, SDO_ABORTS], ids=["modbus", "sdo"])
def test_every_reason_has_a_code_in_each_protocol_table(table: dict[Reason, int]) -> None:
    assert set(table) == set(Reason)


def test_every_reason_has_an_http_status() -> None:
    pytest.importorskip("aiohttp")
    from ncgate.gateway.web.console import HTTP_STATUS

    assert set(HTTP_STATUS) == set(Reason)
    assert all(400 <= status < 500 for status in HTTP_STATUS.values())


def test_sources_and_variables_read_back_what_they_print() -> None:
    for text in ("modbus 127.0.0.1:40312", "modbus-tls Operator", "web 127.0.0.1", "plc",
                 "plc logic.st:12", "script write[0]", "replay", "api test PLC"):
        assert str(Source.parse(text)) == text
    with pytest.raises(InputRefused) as caught:
        Source.parse("operator")
    assert caught.value.reason is Reason.BAD_VALUE
    for text in ("SA10", "SA1.BY", "SA2.IN", "SK3", "SK4.IN", "SYVAR5"):
        assert str(Var.parse(text)) == text
    assert Var.parse("sa10.bl") == Var("SA", 10, "bit") and Var.parse("SK3.BY") == Var.parse("SK3")
    for bad in ("XYZ", "E1", "SA", "SYVAR1.BY", "SK1.BL", "SA1.FOO", ""):
        with pytest.raises(InputRefused) as caught:
            Var.parse(bad)
        assert caught.value.reason is Reason.UNKNOWN_VARIABLE and isinstance(
            caught.value, NcgateError)


async def test_refusals_are_typed_and_store_nothing(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[[nc.process]]\nnumber = 4\nexternal = true\n')
    (tmp_path / "A.nc").write_text("N1(WAI,SA10=1)\nN2M30\n")
    (tmp_path / "BAD.nc").write_text("N1(WAI,SA10=1\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides=FREE)
    async with Gateway(cfg) as gw:
        before = (bytes(gw.image.sa), bytes(gw.image.k), list(gw.image.syvar), len(gw.trace))
        refused = {
            Reason.UNKNOWN_VARIABLE: lambda: gw.write("XYZ", 1),
            Reason.OUTSIDE_IMAGE: lambda: gw.write("SK99999", 1),
            Reason.BAD_VALUE: lambda: gw.apply(Writes.of({"SK1": 7, "SK2": 300})),
            Reason.UNKNOWN_PROCESS: lambda: gw.apply(Start("A", 9)),
            Reason.EXTERNAL_PROCESS: lambda: gw.apply(Start("A", 4)),
            Reason.NOT_EXTERNAL: lambda: gw.send(2, 1),
            Reason.NOT_RUNNING: lambda: gw.send(4, 1),
            Reason.PROGRAM_NOT_FOUND: lambda: gw.apply(Start("NOPE", 1)),

            Reason.UNSUPPORTED: lambda: gw.apply(object()),  # type: ignore[arg-type]
        }
        for reason, act in refused.items():
            with pytest.raises(InputRefused) as caught:
                act()
            assert caught.value.reason is reason, (reason, caught.value)
        with pytest.raises(InputRefused) as caught:  # read off the loop, then refused
            await gw.apply_async(Start("BAD", 1))
        assert caught.value.reason is Reason.PROGRAM_INVALID
        with pytest.raises(InputRefused, match="not an input"):
            gw.apply("SA10=1")  # type: ignore[arg-type]
        with pytest.raises(InputRefused) as caught:
            gw.apply(FieldbusAlarm(999, "no such alarm"))
        assert caught.value.reason is Reason.BAD_VALUE
        # Nothing of any refused input was stored, traced or started.
        assert (bytes(gw.image.sa), bytes(gw.image.k), list(gw.image.syvar),
                len(gw.trace)) == before
        await gw.start()
        with pytest.raises(InputRefused) as caught:
            await gw.start()
        assert caught.value.reason is Reason.BUSY
        with pytest.raises(InputRefused) as caught:
            gw.read("nothing")
        assert caught.value.reason is Reason.UNKNOWN_VARIABLE


async def test_a_plc_path_that_names_nothing_is_an_ncgate_error(tmp_path: Path) -> None:
    (tmp_path / "p.st").write_text("PROGRAM p VAR n : DINT; END_VAR n := n + 1; END_PROGRAM")
    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "p.st"\n')
    cfg = load_config(tmp_path / "ncgate.toml", overrides=FREE)
    async with Gateway(cfg, cold=True) as gw:
        for path in ("q.n", "p", "p.nothing"):
            with pytest.raises(PlcError):
                gw.plc.read(path)


def test_inputs_are_frozen_values() -> None:
    write = Write("SA10", 1)
    assert write == Write(Var("SA", 10, "bit"), 1) and write.source.kind is SourceKind.API
    with pytest.raises(AttributeError):
        write.value = 2  # type: ignore[misc]
    assert {Snd(4, 1), Snd(4, 1)} == {Snd(4, 1)}


def test_odd_inputs_are_refused_never_a_bare_exception() -> None:
    """Whatever a Python caller hands the door, the answer is InputRefused (a review of the
    door found AttributeErrors, TypeErrors and ValueErrors here)."""
    for make in (lambda: Write(123, 1), lambda: Write(None, 1),  # type: ignore[arg-type]
                 lambda: Writes.of({5: 1}),  # type: ignore[dict-item]
                 lambda: Writes(None),  # type: ignore[arg-type]
                 lambda: Source.parse(5),  # type: ignore[arg-type]
                 lambda: Source("bogus"),  # type: ignore[arg-type]
                 lambda: Var("SA", True, "bit"), lambda: Var("SA", "1", "bit"),  # type: ignore[arg-type]
                 lambda: Var("SA", 1.0, "bit"),  # type: ignore[arg-type]
                 lambda: Var.parse("SA" + "9" * 5000),
                 lambda: Var.parse("SA\u0661\u0661")):  # Arabic-Indic digits are not digits here
        with pytest.raises(InputRefused):
            make()
    assert Writes((("SA10", 1),)).changes == ((Var("SA", 10, "bit"), 1),)  # converted


async def test_odd_commands_starts_and_alarms_are_refused(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    (tmp_path / "A.nc").write_text("N1(WAI,SA10=1)\nN2M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides=FREE)
    async with Gateway(cfg) as gw:
        for item in (Command(True), Command(1.0), Start(123, 2), Start("", 2),  # type: ignore[arg-type]
                     FieldbusAlarm(150, None), FieldbusAlarm(True, "x")):  # type: ignore[arg-type]
            with pytest.raises(InputRefused) as caught:
                gw.apply(item)
            assert caught.value.reason is Reason.BAD_VALUE, item
        for word in (1.0, True, 4):
            with pytest.raises(InputRefused):
                gw.command(word)  # type: ignore[arg-type]
        assert not gw.trace  # nothing of any of them happened


async def test_breakpoints_are_bounded_and_spelled_in_ascii(tmp_path: Path) -> None:
    from ncgate.inputs import Break
    from ncgate.interpreter.engine.breaks import MAX_BREAKPOINTS

    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE)) as gw:
        for n in range(MAX_BREAKPOINTS):
            gw.apply(Break(f"N{n}"))
        with pytest.raises(InputRefused, match="breakpoints are set") as caught:
            gw.apply(Break(f"N{MAX_BREAKPOINTS}"))
        assert caught.value.reason is Reason.BAD_VALUE
        gw.apply(Break("N0"))  # one already set: no new one
        for text in ("P\uff11 N5", "N\u0663", "PROG92:" + "9" * 20):
            with pytest.raises(InputRefused):
                gw.apply(Break(text, on=False))
