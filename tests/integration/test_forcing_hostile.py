"""Forcing against a hostile client (issue 28, item 2): what a force request the door must
refuse -- a variable outside the image (even to release it), a value a REAL cannot hold, a
force list without end -- is refused with its reason and nothing of it is forced, recorded or
traced; one PLC variable spelled two ways is one force."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from ncgate.errors import InputRefused, Reason
from ncgate.gateway import Gateway
from ncgate.gateway.door import MAX_FORCED
from ncgate.gateway.testing.plc_kit import PlcWatch
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Force, Var
from tests.integration.modbus.rawclient import Raw, pdu

LOGIC = """PROGRAM main
VAR n : INT; r : REAL; l : LREAL; a : ARRAY[1..400] OF INT; END_VAR
n := n + 1;
r := 1.5;
l := l * 1.0;
END_PROGRAM
"""

# The force table (README's Modbus map): holding 2100..2103 = action, kind, index, value.
FORCE, RELEASE, SA_BIT, K_WORD = 2100, 2, 1, 5


def _config(tmp_path: Path, logic: bool = True) -> Path:
    (tmp_path / "logic.st").write_text(LOGIC)
    (tmp_path / "A.nc").write_text("N1(WAI,SA21=1)\nN2M30\n")
    plc = '[plc]\nlogic = "logic.st"\n' if logic else ""
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n' + plc + '[canopen]\nenabled = false\n')
    return tmp_path / "ncgate.toml"


def _fc16(address: int, values: list[int]) -> bytes:
    return pdu(16, "HHB" + "H" * len(values), address, len(values), 2 * len(values), *values)


async def test_releasing_a_variable_outside_the_image_is_refused_and_leaves_no_trace(
        tmp_path: Path) -> None:
    """docs/decisions.md: 'an index outside the image 02 ... and nothing of it is forced'.
    A release named SA65535 or SK511.IN (its high byte past the K packet) was taken,
    recorded and traced as released."""
    record = tmp_path / "session.jsonl"
    async with Gateway(ncgate_test_config(_config(tmp_path, logic=False)), record=record) as gw:
        for var in (Var.at("SA", 65535, "bit"), Var.at("SK", 511, "IN"),
                    Var.at("SYVAR", 256, "IN")):
            with pytest.raises(InputRefused) as caught:
                gw.apply(Force(var, None))
            assert caught.value.reason is Reason.OUTSIDE_IMAGE, var
        raw = await Raw.open("127.0.0.1", gw.modbus_address[1])
        try:
            for kind, index in ((SA_BIT, 65535), (SA_BIT, 1024), (K_WORD, 511)):
                answer = await raw.ask(_fc16(FORCE, [RELEASE, kind, index, 0]))
                assert answer == bytes((0x90, 2)), (kind, index, answer)
            # A release inside the image is taken (the request's answer echoes it).
            answer = await raw.ask(_fc16(FORCE, [RELEASE, SA_BIT, 1023, 0]))
            assert answer == struct.pack(">BHH", 16, FORCE, 4)
        finally:
            raw.close()
        trace = gw.trace
    assert [e["var"] for e in trace if e["event"] == "force"] == ["SA1023"]
    assert record.read_text().count('"input": "force"') == 1


async def test_a_value_a_real_cannot_hold_is_refused_not_an_internal_error(
        tmp_path: Path) -> None:
    """REAL is IEEE single: 3.5e38, 1e308 and 10**400 were an OverflowError or struct.error
    out of the door (the console's 500); LREAL's 10**400 was already BAD_VALUE."""
    async with Gateway(ncgate_test_config(_config(tmp_path))) as gw:
        await PlcWatch(gw).until("main.n", 2)
        for var, value in (("main.r", 3.5e38), ("main.r", 1e308), ("main.r", 10**400),
                           ("main.r", -(10**39)), ("main.l", 10**400)):
            with pytest.raises(InputRefused) as caught:
                gw.apply(Force(var, value))
            assert caught.value.reason is Reason.BAD_VALUE, (var, value)
        assert not gw.runtime.plc.forced
        trace = gw.trace
    assert not [e for e in trace if e["event"] == "force"]


async def test_a_whole_number_forced_into_an_lreal_is_the_lreal_the_logic_holds(
        tmp_path: Path) -> None:
    """{"value": 2} into an LREAL was kept as the int 2: the logic computed on an int, and
    each scan that left 2.0 was reported as overridden although the value was the force's."""
    async with Gateway(ncgate_test_config(_config(tmp_path))) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", 2)
        gw.apply(Force("main.l", 2))
        for _ in range(3):
            await watch.next_scan()
        assert type(watch.read("main.l")) is float and watch.read("main.l") == 2.0
        trace = gw.trace
    assert not [e for e in trace if e["event"] == "forced"]


async def test_one_plc_variable_spelled_two_ways_is_one_force(tmp_path: Path) -> None:
    """main.a[01] and main.a[1] are the same element: two forces of it, of which releasing
    one left the other holding it, was a force the operator could not see go."""
    async with Gateway(ncgate_test_config(_config(tmp_path))) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", 2)
        gw.apply(Force("main.a[01]", 5))
        gw.apply(Force("MAIN.A[1]", 6))
        assert len(gw.runtime.plc.forced) == 1
        gw.apply(Force("main.a[1]", None))
        assert not gw.runtime.plc.forced
        await watch.next_scan()
        assert watch.read("main.a[1]") == 6  # released: the value stays


async def test_the_force_list_is_bounded_and_a_force_past_it_is_refused(
        tmp_path: Path) -> None:
    """Every forced PLC variable is set twice a scan: 9,600 forced array elements took each
    scan to 41 ms at scan_ms 10 (a loop stall, measured through the console's API).  A force
    past MAX_FORCED (image and PLC together) is refused; a forced one may take a new value."""
    async with Gateway(ncgate_test_config(_config(tmp_path))) as gw:
        await PlcWatch(gw).until("main.n", 2)
        for i in range(MAX_FORCED - 1):
            gw.apply(Force(f"main.a[{i + 1}]", 1))
        gw.apply(Force(Var.parse("SA5"), 1))
        for var in ("main.a[400]", "SA6", "SYVAR1"):
            with pytest.raises(InputRefused) as caught:
                gw.apply(Force(var, 1))
            assert caught.value.reason is Reason.BAD_VALUE, var
        gw.apply(Force("main.a[1]", 2))  # already forced: a new value
        gw.apply(Force(Var.parse("SA5"), 0))
        assert len(gw.runtime.plc.forced) + len(gw.image.forced) == MAX_FORCED
        gw.apply(Force(Var.parse("SA5"), None))
        gw.apply(Force(Var.parse("SA6"), 1))  # room again


async def test_an_online_change_that_retypes_a_forced_variable_does_not_set_it(
        tmp_path: Path) -> None:
    """docs/decisions.md: an online change keeps a force.  One that retyped main.x from INT
    to BOOL, then to SINT, had the scan store the INT force 30000 into both: a BOOL and a
    SINT holding 30000, and the logic writing it on (SYVAR5 = 30000 from a SINT).  The force
    stays listed and holds again when the type comes back."""
    logic = tmp_path / "logic.st"
    logic.write_text("PROGRAM main\nVAR n : INT; x : INT; END_VAR\nn := n + 1;\n"
                     "SYVAR[5] := x;\nEND_PROGRAM\n")
    (tmp_path / "A.nc").write_text("N1(WAI,SA21=1)\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[plc]\nlogic = "logic.st"\n'
        '[canopen]\nenabled = false\n')
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml")) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", 2)
        gw.apply(Force("main.x", 30000))
        await watch.next_scan()
        assert gw.read("SYVAR5") == 30000
        for retyped, initial in (("BOOL", False), ("SINT", 0)):
            logic.write_text(f"PROGRAM main\nVAR n : INT; x : {retyped}; END_VAR\n"
                             "n := n + 1;\nSYVAR[5] := 3;\nEND_PROGRAM\n")
            assert (await gw.reload_plc()).ok
            await watch.next_scan()
            await watch.next_scan()
            assert watch.read("main.x") == initial and type(watch.read("main.x")) is (
                bool if retyped == "BOOL" else int), retyped
        assert gw.runtime.plc.is_forced("main.x")
        logic.write_text("PROGRAM main\nVAR n : INT; x : INT; END_VAR\nn := n + 1;\n"
                         "SYVAR[5] := x;\nEND_PROGRAM\n")
        assert (await gw.reload_plc()).ok
        await watch.next_scan()
        await watch.next_scan()
        assert watch.read("main.x") == 30000 and gw.read("SYVAR5") == 30000


async def test_a_force_over_the_bits_of_another_forced_variable_is_refused(
        tmp_path: Path) -> None:
    """SA10 forced to 1, then SA1.BY (bits 8..15) to 0: both were taken, the list said
    SA10 = 1 while SA10 read 0 -- and once SA1.BY was released, SA10 stayed 0 although listed
    as forced to 1.  A force over another's bits is refused; a variable forced again is not."""
    record = tmp_path / "session.jsonl"
    async with Gateway(ncgate_test_config(_config(tmp_path, logic=False)), record=record) as gw:
        gw.apply(Force(Var.parse("SA10"), 1))
        gw.apply(Force(Var.parse("SK4.IN"), 300))
        for var, value in (("SA1.BY", 0), ("SA0.IN", 0), ("SK5.BY", 1), ("SK3.IN", 7)):
            with pytest.raises(InputRefused) as caught:
                gw.apply(Force(var, value))
            assert caught.value.reason is Reason.BAD_VALUE, var
        raw = await Raw.open("127.0.0.1", gw.modbus_address[1])
        try:  # the force table: SA byte 1 over the forced SA10, exception 03
            assert await raw.ask(_fc16(FORCE, [1, 2, 1, 0])) == bytes((0x90, 3))
        finally:
            raw.close()
        gw.apply(Force(Var.parse("SA10"), 0))  # the same variable: a new value
        gw.apply(Force(Var.parse("SA11"), 1))  # the byte's other bits are free
        gw.apply(Force(Var.parse("SK6.BY"), 9))
        assert gw.read("SA10") == 0 and gw.read("SA11") == 1
        assert sorted(str(Var.at(*k)) for k in gw.image.forced) == [
            "SA10", "SA11", "SK4.IN", "SK6"]
    assert record.read_text().count('"input": "force"') == 5


async def test_the_api_takes_a_release_only_when_it_says_value_null(tmp_path: Path) -> None:
    """docs/console.md: '"value": null' releases.  A body without "value" (a client that
    forgot it, or sent "val") released the force -- 200, recorded -- as if it had asked."""
    import aiohttp

    config = _config(tmp_path, logic=False)
    config.write_text(config.read_text() + "[web]\nport = 0\n")
    async with Gateway(ncgate_test_config(config), console=True) as gw:
        gw.apply(Force(Var.parse("SA10"), 1))
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            for body in ({"var": "SA10"}, {"var": "SA10", "val": None}):
                async with http.post("/api/force", json=body) as r:
                    assert r.status == 400, (body, r.status, await r.text())
            assert gw.image.forced == {("SA", 10, "bit"): 1}
            async with http.post("/api/force", json={"var": "SA10", "value": None}) as r:
                assert r.status == 200
        assert not gw.image.forced
