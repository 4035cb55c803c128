"""The console's HTTP API over real HTTP on loopback (docs/console.md): every endpoint, the
token, the Origin and Host checks, read-only, the live stream, and refusing a public bind."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import socket
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from ncgate.config import ConfigError
from ncgate.gateway import Gateway
from ncgate.gateway.record import replay
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.plc_kit import PlcWatch
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Break, CommandKind

from ...conftest import EXAMPLES

TOKEN = "s3cret-token"


async def console(**overrides: Any) -> Gateway:
    # Ten times the machine's pace: the built-in cell's P2 reaches N40 at 18 s machine time.
    return Gateway(ncgate_test_config(**{"web.port": 0, "nc.time_scale": 10.0, **overrides}),
                   console=True)


@pytest.fixture
async def gw() -> AsyncIterator[Gateway]:
    async with await console() as gateway:
        yield gateway


@pytest.fixture
async def http(gw: Gateway) -> AsyncIterator[aiohttp.ClientSession]:
    host, port = gw.web_address
    async with aiohttp.ClientSession(f"http://{host}:{port}") as session:
        yield session


async def post(http: aiohttp.ClientSession, path: str, body: object,
               **headers: str) -> tuple[int, dict[str, Any]]:
    async with http.post(path, json=body, headers=headers) as r:
        return r.status, await r.json()


async def test_status_shows_each_process_with_its_why_record(gw: Gateway,
                                                             http: aiohttp.ClientSession) -> None:
    await gw.start()
    await gw.wait_state(2, "WAIT_COND")
    async with http.get("/api/status") as r:
        assert r.status == 200
        status = await r.json()
    assert [p["number"] for p in status["processes"]] == [1, 2, 3, 4, 5]
    p2 = status["processes"][1]
    assert (p2["state"], p2["program"], p2["n"]) == ("WAIT_COND", "PROG92", 40)
    assert p2["block"] == "N40(WAI,SA10=1)"
    assert p2["wait"]["cond"] == "SA10=1" and p2["wait"]["value"] == 0
    assert p2["wait"]["writer"] is None
    assert status["image"]["sa"][10] == "0" and len(status["image"]["sa"]) == 1024
    assert status["fieldbus"]["modbus"]["address"] == list(gw.modbus_address)
    assert status["fieldbus"]["canopen"]["node_id"] == gw.config.canopen.node_id
    assert status["plc"] is None  # the built-in config has no PLC logic
    assert status["counters"]["events"] == gw.runtime.trace.seq


async def test_status_shows_the_plc_its_variables_and_the_modbus_clients(
        tmp_path: Path) -> None:
    example = EXAMPLES / "plclogic" / "ncgate.toml"
    config = ncgate_test_config(example, **{"web.port": 0, "nc.time_scale": 30.0,
                                            "plc.retain_file": str(tmp_path / "r.sqlite")})
    async with Gateway(config, console=True) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        host, port = gw.web_address
        await plc.command(1)
        await gw.wait_idle(timeout_s=30)
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/status") as r:
            status = await r.json()
        assert status["plc"]["state"] == "RUNNING" and status["plc"]["scans"] > 0
        watch = {v["path"]: v for v in status["plc"]["variables"]}
        assert watch["cell.cycles"]["type"] == "INT"
        assert watch["cell.cycles"]["value"] == gw.plc.read("cell.cycles") == 2
        assert watch["cell.total"]["retain"] is True
        assert watch["cell.answer"]["value"] == {"IN": False, "PT": 500, "Q": False, "ET": 0}
        clients = status["fieldbus"]["modbus"]["clients"]
        assert len(clients) == 1 and clients[0].startswith("127.0.0.1:")
        assert status["image"]["writers"]["SA"]["10"] == "plc"


async def test_a_write_is_stored_as_web_and_releases_the_wait(
        gw: Gateway, http: aiohttp.ClientSession) -> None:
    await gw.start()
    await gw.wait_state(2, "WAIT_COND")
    code, body = await post(http, "/api/write", {"var": "sa10", "value": 1})
    assert (code, body) == (200, {"var": "SA10", "value": 1})
    assert gw.read("SA10") == 1
    assert gw.image.last_writer("SA", 10, "bit") == "web 127.0.0.1"
    resumed = [e for e in gw.trace if e["event"] == "resume" and e["proc"] == 2
               and e["n"] == 40]
    assert resumed and resumed[0]["by"] == "cond"
    async with http.get("/api/status") as r:
        status = await r.json()
    assert status["image"]["writers"]["SA"]["10"] == "web 127.0.0.1"


@pytest.mark.parametrize(("body", "status", "said"), [
    ({"var": "SA5000", "value": 1}, 422, "outside the image"),
    ({"var": "SA10", "value": 2}, 422, "SA10"),
    ({"var": "SK3", "value": 256}, 422, "0..255"),
    ({"var": "E1", "value": 1}, 422, "not an image variable"),
    ({"var": "SA10", "value": True}, 400, "whole number"),
    ({"var": "SA10", "value": 1.5}, 400, "whole number"),
    ({"value": 1}, 400, "var"),
    ({"var": "SA10=1 SA11", "value": 1}, 422, "SA10=1 SA11"),
    ([1, 2], 400, "JSON object"),
])
async def test_a_bad_write_gets_a_json_error_and_stores_nothing(
        gw: Gateway, http: aiohttp.ClientSession, body: object, status: int, said: str) -> None:
    before = gw.image.snapshot()
    seq = gw.runtime.trace.seq
    code, answer = await post(http, "/api/write", body)
    assert code == status
    assert said in answer["error"]
    assert gw.image.snapshot() == before
    assert gw.runtime.trace.seq == seq  # no write event either


async def test_a_body_that_is_not_json_is_refused(gw: Gateway,
                                                  http: aiohttp.ClientSession) -> None:
    async with http.post("/api/write", data=b"SA10=1",
                         headers={"Content-Type": "text/plain"}) as r:
        assert r.status == 415
    async with http.post("/api/write", data=b"{nope",
                         headers={"Content-Type": "application/json"}) as r:
        assert r.status == 400
        assert (await r.json())["error"] == "the body is not JSON"
    async with http.post("/api/write", data=b'{"var": "SYVAR1", "value": ' + b"9" * 5000 + b"}",
                         headers={"Content-Type": "application/json"}) as r:
        assert r.status == 400  # JSON, with a number beyond Python's conversion limit
        assert "more digits than any value here can hold" in (await r.json())["error"]
    assert gw.read("SA10") == 0


@pytest.mark.parametrize("path", ["/api/write", "/api/force", "/api/fault"])
async def test_a_name_longer_than_any_is_refused_and_not_echoed(
        gw: Gateway, http: aiohttp.ClientSession, path: str) -> None:
    name = "X" * 5000
    key = "target" if path == "/api/fault" else "var"
    code, answer = await post(http, path, {key: name, "value": 1, "kind": "stuck"})
    assert code == 400
    assert answer["error"] == f'"{key}": a name of at most 200 characters, got 5000'


async def test_commands_start_hold_and_reset(gw: Gateway, http: aiohttp.ClientSession) -> None:
    assert await post(http, "/api/command", {"command": "start"}) == (200, {"command": "start"})
    await gw.wait_state(2, "WAIT_COND")
    assert gw.trace[0]["event"] == "start" and gw.trace[0]["by"] == "web 127.0.0.1"
    assert (await post(http, "/api/command", {"command": "hold"}))[0] == 200
    assert all(p.held for p in gw.engine.processes.values() if not p.external)
    assert (await post(http, "/api/command", {"command": "reset"}))[0] == 200
    await gw.wait_idle(timeout_s=10)
    ends = [e["how"] for e in gw.trace if e["event"] == "end"]
    assert "reset" in ends


async def test_start_a_program_in_a_process(gw: Gateway, http: aiohttp.ClientSession) -> None:
    code, body = await post(http, "/api/command",
                            {"command": "start", "program": "PROG93", "process": 3})
    assert code == 200, body
    starts = [e for e in gw.trace if e["event"] == "start"]
    assert (starts[0]["proc"], starts[0]["prog"], starts[0]["by"]) == (3, "PROG93", "web 127.0.0.1")
    code, body = await post(http, "/api/command",
                            {"command": "start", "program": "PROG93", "process": 3})
    assert code == 409 and "busy" in body["error"]
    code, body = await post(http, "/api/command",
                            {"command": "start", "program": "NOPE", "process": 4})
    assert code == 404 and "NOPE" in body["error"]
    for bad in ({"command": "start", "program": "PROG93", "process": 9},
                {"command": "hold", "program": "PROG93"},
                {"command": "fly"}, {"command": "start", "process": "two"},
                {"command": "single_block", "process": 2}, {"command": "break"}):
        code, body = await post(http, "/api/command", bad)
        assert code == 400, bad
        assert body["error"]


async def test_events_timeline_and_programs(gw: Gateway, http: aiohttp.ClientSession) -> None:
    await gw.start()
    await gw.wait_state(2, "WAIT_COND")
    async with http.get("/api/events?since=0") as r:
        events = await r.json()
    assert [e["seq"] for e in events["events"]] == list(range(1, events["seq"] + 1))
    assert events["events"] == gw.trace[:len(events["events"])]
    async with http.get(f"/api/events?since={events['seq'] - 1}") as r:
        assert [e["seq"] for e in (await r.json())["events"]] == [events["seq"]]
    async with http.get("/api/events?since=x") as r:
        assert r.status == 400
    async with http.get("/api/timeline.svg") as r:
        assert r.status == 200 and r.content_type == "image/svg+xml"
        svg = await r.text()
    assert svg.startswith("<svg") and "P2" in svg
    async with http.get("/api/programs") as r:
        programs = await r.json()
    assert programs == {"programs": ["PROG91", "PROG92", "PROG93"], "main": "PROG91"}
    async with http.get("/") as r:
        assert r.status == 200 and "ncgate console" in await r.text()
    async with http.get("/static/app.js") as r:
        assert r.status == 200 and r.content_type == "text/javascript"
    async with http.get("/api/nothing") as r:
        assert r.status == 404 and "error" in await r.json()


async def test_a_write_from_another_origin_is_refused(gw: Gateway,
                                                      http: aiohttp.ClientSession) -> None:
    host, port = gw.web_address
    code, body = await post(http, "/api/write", {"var": "SA10", "value": 1},
                            Origin="http://evil.example")
    assert code == 403 and "another origin" in body["error"]
    code, _ = await post(http, "/api/write", {"var": "SA10", "value": 1},
                         **{"Sec-Fetch-Site": "cross-site"})
    assert code == 403
    assert gw.read("SA10") == 0
    code, _ = await post(http, "/api/write", {"var": "SA10", "value": 1},
                         Origin=f"http://{host}:{port}")
    assert code == 200 and gw.read("SA10") == 1


async def test_a_request_to_a_foreign_host_name_is_refused(gw: Gateway,
                                                           http: aiohttp.ClientSession) -> None:
    """DNS rebinding: a page of evil.example whose name now points at 127.0.0.1."""
    async with http.get("/api/status", headers={"Host": "evil.example"}) as r:
        assert r.status == 403
    code, _ = await post(http, "/api/write", {"var": "SA10", "value": 1}, Host="evil.example")
    assert code == 403 and gw.read("SA10") == 0
    async with http.get("/api/status", headers={"Host": "localhost:1"}) as r:
        assert r.status == 200


async def test_with_a_token_every_write_and_command_needs_it() -> None:
    async with await console(**{"web.token": TOKEN}) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            for headers in ({}, {"Authorization": "Bearer wrong-token"},
                            {"Authorization": TOKEN}):
                code, body = await post(http, "/api/write", {"var": "SA10", "value": 1},
                                        **headers)
                assert code == 401 and "token" in body["error"]
                code, _ = await post(http, "/api/command", {"command": "start"}, **headers)
                assert code == 401
            assert gw.read("SA10") == 0 and gw.trace == []
            async with http.get("/api/status") as r:  # reading needs none
                assert r.status == 200 and (await r.json())["web"]["token"] is True
            bearer = {"Authorization": f"Bearer {TOKEN}"}
            assert (await post(http, "/api/write", {"var": "SA10", "value": 1},
                               **bearer))[0] == 200
            assert gw.read("SA10") == 1


async def test_read_only_refuses_every_write_and_command() -> None:
    async with await console(**{"web.read_only": True}) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            code, body = await post(http, "/api/write", {"var": "SA10", "value": 1})
            assert code == 403 and "read-only" in body["error"]
            code, _ = await post(http, "/api/command", {"command": "start"})
            assert code == 403
            assert gw.read("SA10") == 0 and gw.trace == []


def test_a_public_bind_needs_a_token() -> None:
    with pytest.raises(ConfigError, match=r"web\.token: the console listens on 0\.0\.0\.0"):
        ncgate_test_config(**{"web.host": "0.0.0.0"})
    config = ncgate_test_config(**{"web.host": "0.0.0.0", "web.token": TOKEN})
    assert config.web.token == TOKEN
    ncgate_test_config(**{"web.host": "0.0.0.0", "web.enabled": False})  # no console: fine


async def test_a_taken_default_port_leaves_the_console_off_a_configured_one_is_an_error(
        caplog: pytest.LogCaptureFixture) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        # web.port unset, as run has it (the kit sets 0); ten times the machine's pace
        config = ncgate_test_config(**{"nc.time_scale": 10.0})
        config = dataclasses.replace(config, web=dataclasses.replace(config.web, port=None))
        async with Gateway(config, console=True, web_default_port=port) as gw:
            assert gw.web_console is None
            await gw.start()  # the rest of the gateway runs
            await gw.wait_state(2, "WAIT_COND")
        assert f"web console off: 127.0.0.1:{port} is taken" in caplog.text
        with pytest.raises(OSError, match=rf"web\.port: cannot listen on 127\.0\.0\.1:{port}"):
            async with Gateway(ncgate_test_config(**{"web.port": port}), console=True):
                pass


async def read_sse(response: aiohttp.ClientResponse) -> AsyncIterator[tuple[str, str, str]]:
    """(event, id, data) of each server-sent event."""
    event, ident, data = "message", "", []
    async for raw in response.content:
        line = raw.decode().rstrip("\n")
        if not line:
            if data:
                yield event, ident, "\n".join(data)
            event, data = "message", []
        elif line.startswith("event: "):
            event = line[7:]
        elif line.startswith("id: "):
            ident = line[4:]
        elif line.startswith("data: "):
            data.append(line[6:])


async def next_of(stream: AsyncIterator[tuple[str, str, str]], kind: str
                  ) -> tuple[str, dict[str, Any]]:
    async with asyncio.timeout(10):
        async for event, ident, data in stream:
            if event == kind:
                return ident, json.loads(data)
    raise AssertionError(f"the stream ended before a {kind} event")


async def test_the_stream_sends_status_then_events_as_they_happen() -> None:
    # The built-in cell at the control's look-ahead: P2 waits at t = 0, so the stream has
    # events at once (with the built-in lookahead 0 its first wait comes after seconds of
    # motion; this test is about the stream, not the cell's timing).
    async with await console(**{"nc.lookahead": 16}) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with http.get("/api/stream") as r:
                assert r.status == 200 and r.content_type == "text/event-stream"
                stream = read_sse(r)
                _, status = await next_of(stream, "status")
                assert status["session"] == gw.session
                await gw.start()
                ident, batch = await next_of(stream, "events")
                assert batch["missed"] == 0
                assert batch["events"][0] == gw.trace[0]
                seen = list(batch["events"])
                while not any(e["event"] == "wait" and e["proc"] == 2 for e in seen):
                    ident, batch = await next_of(stream, "events")
                    seen += batch["events"]
                assert int(ident) == seen[-1]["seq"]
                assert seen == gw.trace[:len(seen)]
            # A page opened now gets what the ring holds, from the first event on.
            async with http.get("/api/stream") as r:
                _, batch = await next_of(read_sse(r), "events")
                assert batch["events"][:len(seen)] == seen
            # A page that reconnects says where it was (Last-Event-ID): it gets the rest, not again
            # what it had.
            gw.write("SA10", 1)
            async with http.get("/api/stream", headers={"Last-Event-ID": ident}) as r:
                _, batch = await next_of(read_sse(r), "events")
                assert batch["events"][0]["seq"] == int(ident) + 1


async def test_streams_beyond_max_streams_are_refused() -> None:
    async with await console(**{"web.max_streams": 1}) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/stream") as first:
            await next_of(read_sse(first), "status")
            async with http.get("/api/stream") as second:
                assert second.status == 503
                assert "max_streams" in (await second.json())["error"]


# -- safe to leave open (issue 30 item 2) -----------------------------------------------------

SECURITY = {"Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
            "X-Frame-Options": "DENY", "X-Content-Type-Options": "nosniff",
            "Referrer-Policy": "no-referrer"}


async def test_every_answer_carries_the_security_headers(gw: Gateway,
                                                         http: aiohttp.ClientSession) -> None:
    answers = []
    for path in ("/", "/static/app.js", "/static/style.css", "/api/status", "/api/events",
                 "/api/programs", "/api/timeline.svg", "/api/nothing"):
        async with http.get(path) as r:
            answers.append((path, r.status, r.headers))
    async with http.post("/api/write", json={"var": "SA10", "value": 2}) as r:
        answers.append(("POST /api/write", r.status, r.headers))
    async with http.get("/api/status", headers={"Host": "evil.example"}) as r:
        answers.append(("foreign host", r.status, r.headers))
    async with http.get("/api/stream") as r:
        answers.append(("/api/stream", r.status, r.headers))
    assert [status for _, status, _ in answers] == [200] * 7 + [404, 422, 403, 200]
    for path, _, headers in answers:
        assert {k: headers.get(k) for k in SECURITY} == SECURITY, path


def test_a_token_with_spaces_around_it_is_a_config_error(tmp_path: Path) -> None:
    from ncgate.config import load_config

    path = tmp_path / "ncgate.toml"
    path.write_text('[web]\ntoken = " s3cret-token"\n')
    with pytest.raises(ConfigError, match=r"ncgate\.toml.*web\.token: has spaces"):
        load_config(path)
    path.write_text('[web]\ntoken = "s3cret-token\\n"\n')
    with pytest.raises(ConfigError, match=r"web\.token: has spaces"):
        load_config(path)


EVERY_TYPE = """\
FUNCTION_BLOCK pulse
VAR_INPUT
  go : BOOL;
END_VAR
VAR_OUTPUT
  count : INT;
END_VAR
VAR
  t : TON;
END_VAR
t(IN := go, PT := T#20ms);
IF t.Q THEN count := count + 1; END_IF
END_FUNCTION_BLOCK

PROGRAM every
VAR
  b : BOOL := TRUE; si : SINT := -5; i : INT := -300; di : DINT := 70000;
  us : USINT := 5; ui : UINT := 60000; ud : UDINT := 4000000000;
  bt : BYTE := 16#FF; w : WORD := 16#FFFF; dw : DWORD := 16#FFFFFFFF;
  r : REAL := 1.5; lr : LREAL := 2.25; tm : TIME := T#1s500ms;
  zero : REAL; inf : REAL;
  ints : ARRAY[1..3] OF INT;
  t : ARRAY[2..15] OF TON;
  edge : R_TRIG; fall : F_TRIG; tof1 : TOF; tp1 : TP;
  up : CTU; down : CTD; both : CTUD; sr1 : SR; rs1 : RS;
  mine : pulse;
  many : ARRAY[0..1] OF pulse;
END_VAR

t[3](IN := TRUE, PT := T#10ms);
ints[2] := 7;
mine(go := TRUE);
many[1](go := TRUE);
END_PROGRAM
"""


async def test_every_st_type_the_plc_supports_serialises(tmp_path: Path) -> None:
    """`t : ARRAY[2..15] OF TON;` made /api/status 500: every elementary type, TIME, arrays,
    every standard block, a user block and an array of them, each as JSON with its members."""
    (tmp_path / "every.st").write_text(EVERY_TYPE)
    config = ncgate_test_config(**{"web.port": 0, "plc.logic": str(tmp_path / "every.st"),
                                   "plc.retain_file": str(tmp_path / "r.sqlite")})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        await PlcWatch(gw).until("every.many[1].count", test=lambda count: count >= 1)
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/status") as r:
            assert r.status == 200
            text = await r.text()
    watch = {v["path"][6:]: v["value"] for v in json.loads(text)["plc"]["variables"]}
    assert {name: watch[name] for name in ("b", "si", "ud", "dw", "r", "tm", "ints")} == {
        "b": True, "si": -5, "ud": 4000000000, "dw": 0xFFFFFFFF, "r": 1.5, "tm": 1500,
        "ints": [0, 7, 0]}
    assert len(watch["t"]) == 14 and watch["t"][0] == {"IN": False, "PT": 0, "Q": False,
                                                       "ET": 0}
    assert watch["t"][1]["IN"] is True and watch["t"][1]["PT"] == 10  # t[3]
    assert set(watch["t"][1]) == {"IN", "PT", "Q", "ET"}
    assert watch["edge"] == {"CLK": False, "Q": False}
    assert set(watch["both"]) == {"CU", "CD", "R", "LD", "PV", "QU", "QD", "CV"}
    for name in ("fall", "tof1", "tp1", "up", "down", "sr1", "rs1"):
        assert isinstance(watch[name], dict) and watch[name], name
    assert watch["mine"]["go"] is True and set(watch["mine"]) == {"go", "count", "t"}
    assert watch["mine"]["t"]["PT"] == 20
    assert watch["many"][0]["go"] is False and watch["many"][1]["go"] is True
    assert watch["many"][1]["count"] >= 1


@pytest.mark.parametrize(("body", "status"), [
    (b"[" * 8000 + b"]" * 8000, 400),                      # deeper than the parser's stack
    (b'{"var": "SA10", "value": ' + b"[" * 5000 + b"]" * 5000 + b"}", 400),
    (b'{"var": "SA10", "value": 1, "pad": "' + b"x" * 100_000 + b'"}', 413),
])
async def test_a_deeply_nested_or_huge_body_is_400_or_413(
        gw: Gateway, http: aiohttp.ClientSession, body: bytes, status: int) -> None:
    async with http.post("/api/write", data=body,
                         headers={"Content-Type": "application/json"}) as r:
        assert r.status == status
        assert (await r.json())["error"]
    assert gw.read("SA10") == 0


async def test_a_stream_slot_frees_when_its_client_leaves() -> None:
    async with await console(**{"web.max_streams": 1}) as gw:
        web = gw.web_console
        assert web is not None
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with http.get("/api/stream") as first:
                await next_of(read_sse(first), "status")
                assert web.streams == 1
                first.connection.transport.close()  # the tab is closed: no more reading
            # A server learns that a peer left only from its socket: poll the count (well
            # under the 15 s of a ping, which is when the slot used to free).
            async with asyncio.timeout(5):
                while web.streams:  # noqa: ASYNC110
                    await asyncio.sleep(0.02)
            async with http.get("/api/stream") as second:
                assert second.status == 200


# -- live at any rate (issue 30 item 1) --------------------------------------------------------

async def test_a_page_that_connects_to_a_full_ring_gets_it_in_bounded_messages(
        gw: Gateway, http: aiohttp.ClientSession) -> None:
    from ncgate.gateway.web.console import MESSAGE_BYTES
    from ncgate.gateway.web.feed import RING

    for i in range(RING + 100):  # SYVARs: a full ring of writes, some 100 bytes each
        gw.write(f"SYVAR{i % 50}", i % 30000)
    longest, seqs, missed = 0, [], 0
    async with http.get("/api/stream") as r:
        async with asyncio.timeout(10):
            async for raw in r.content:
                longest = max(longest, len(raw))
                if raw.startswith(b"data: {\"missed\""):
                    batch = json.loads(raw[6:])
                    missed += batch["missed"]
                    seqs += [e["seq"] for e in batch["events"]]
                    if seqs[-1] == gw.runtime.trace.seq:
                        break
    assert longest <= MESSAGE_BYTES
    assert seqs == list(range(gw.runtime.trace.seq - RING + 1, gw.runtime.trace.seq + 1))
    assert missed == gw.runtime.trace.seq - RING


async def test_the_stream_sends_events_in_batches_not_one_message_per_write(
        gw: Gateway, http: aiohttp.ClientSession) -> None:
    writes = 300
    async with http.get("/api/stream") as r:
        stream = read_sse(r)
        await next_of(stream, "status")
        first = gw.runtime.trace.seq + 1
        for i in range(writes):  # one write a turn of the loop, as a fast fieldbus client
            gw.write("SYVAR3", i)
            await asyncio.sleep(0)
        messages, seen = 0, 0
        while seen < writes:
            _, batch = await next_of(stream, "events")
            messages += 1
            seen += sum(1 for e in batch["events"] if e["seq"] >= first)
    # One message a write put a page minutes behind; a batch per 50 ms is a handful here.
    assert messages <= writes // 10, messages


# -- always true (issue 30 item 3) -------------------------------------------------------------

async def test_programs_lists_only_programs_not_the_other_files_beside_them(
        tmp_path: Path) -> None:
    example = EXAMPLES / "plclogic"  # PROG91..93 beside ncgate.toml, plc.st and README.md
    assert {"ncgate.toml", "plc.st", "README.md"} <= {p.name for p in example.iterdir()}
    config = ncgate_test_config(example / "ncgate.toml", **{
        "web.port": 0, "plc.retain_file": str(tmp_path / "r.sqlite")})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/programs") as r:
            assert await r.json() == {"programs": ["PROG91", "PROG92", "PROG93"],
                                      "main": "PROG91"}


async def test_the_commissioning_commands_through_the_api(gw: Gateway,
                                                          http: aiohttp.ClientSession) -> None:
    """Issue 27's API: single block with "on", step and cycle start of one process, a
    breakpoint, the PLC restart (refused here: no PLC logic), the feed override as a write."""
    ok = {"command": "single_block", "on": True, "process": 1}
    assert (await post(http, "/api/command", ok))[0] == 200
    assert (await post(http, "/api/command", {"command": "cycle_start", "process": 1}))[0] == 200
    await gw.wait_state(1, "STEP", timeout_s=10)
    assert (await post(http, "/api/command", {"command": "step", "process": 1}))[0] == 200
    code, _ = await post(http, "/api/command", {"command": "break", "at": "P2 wait"})
    assert code == 200 and [b.text for b in gw.engine.breakpoints] == ["P2 wait"]
    code, body = await post(http, "/api/command", {"command": "restart_plc"})
    assert code == 409 and "no PLC logic" in body["error"]
    assert (await post(http, "/api/write", {"var": "P2.FEED_OVERRIDE", "value": 40}))[0] == 200
    assert (await post(http, "/api/write", {"var": "FEED_OVERRIDE", "value": 250}))[0] == 422
    assert gw.engine.processes[2].feed_override == 40
    assert gw.engine.processes[1].feed_override == 100
    overrides = [(e["proc"], e["feed"]) for e in gw.trace if e["event"] == "override"]
    assert overrides == [(2, 40)]


async def test_the_force_list_through_the_api(gw: Gateway, http: aiohttp.ClientSession) -> None:
    """Issue 28's interface: POST /api/force forces (and, value null, releases), DELETE
    releases every one, GET lists them; a forced bit keeps its value against a write."""
    assert (await post(http, "/api/force", {"var": "SA10", "value": 1}))[0] == 200
    assert (await post(http, "/api/force", {"var": "SYVAR3", "value": -5}))[0] == 200
    async with http.get("/api/force") as r:
        assert (await r.json())["forced"] == [{"var": "SA10", "value": 1},
                                              {"var": "SYVAR3", "value": -5}]
    gw.write("SA10", 0)  # overridden
    assert gw.read("SA10") == 1
    assert (await post(http, "/api/force", {"var": "SA10", "value": None}))[0] == 200
    gw.write("SA10", 0)
    assert gw.read("SA10") == 0
    code, body = await post(http, "/api/force", {"var": "SA10", "value": 2})
    assert code == 422 and "SA10" in body["error"]
    async with http.delete("/api/force") as r:
        assert r.status == 200
    assert gw.image.forced == {}
    forces = [(e["var"], e["value"]) for e in gw.trace if e["event"] == "force"]
    assert forces == [("SA10", 1), ("SYVAR3", -5), ("SA10", None), (None, None)]


async def test_odd_override_names_and_a_search_without_a_program_are_refused(
        gw: Gateway, http: aiohttp.ClientSession) -> None:
    """A hostile review's finds: a Unicode or 5,000-digit process number was a 500; extra text
    was accepted; "at" without "program" started the cell from the top."""
    for var in ("P\u00b2.FEED_OVERRIDE", "P" + "9" * 5000 + ".FEED_OVERRIDE",
                "P2.X.FEED_OVERRIDE", "P\u0663.FEED_OVERRIDE"):
        code, body = await post(http, "/api/write", {"var": var, "value": 50})
        assert code == (400 if len(var) > 200 else 422), (var, code, body)  # 400: too long
    assert all(p.feed_override == 100 for p in gw.engine.processes.values())
    code, _ = await post(http, "/api/command", {"command": "start", "at": "N0"})
    assert code == 400 and all(s.state.name == "IDLE" for s in map(gw.status, range(1, 6)))


async def test_a_record_started_and_stopped_from_the_console_replays_and_downloads(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 30: start/stop recording and download the record -- a whole record (header,
    the inputs, the events, the stop line) that replays as a match; and the trace kept."""
    monkeypatch.chdir(tmp_path)  # a run without --record records in the folder it started in
    async with await console() as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with http.get("/api/record") as r:
                assert r.status == 404  # none yet
            assert (await post(http, "/api/record", {"on": False}))[0] == 409
            code, body = await post(http, "/api/record", {"on": True})
            assert code == 200
            path = Path(body["record"])
            assert path.parent == tmp_path and path.name.startswith("ncgate-record-")
            assert (await post(http, "/api/record", {"on": True}))[0] == 409  # one at a time
            async with http.get("/api/status") as r:
                assert (await r.json())["record"] == str(path)
            await post(http, "/api/command", {"command": "start"})
            await gw.wait_state(2, "WAIT_COND")
            await post(http, "/api/write", {"var": "SA10", "value": 1})
            await gw.wait_state(2, "RUNNING")
            # The record so far, downloaded while it is written: its header and the inputs.
            async with http.get("/api/record") as r:
                assert r.status == 200
                assert "attachment" in r.headers["Content-Disposition"]
                lines = [json.loads(line) for line in (await r.text()).splitlines()]
            assert lines[0]["ncgate_record"] == 2
            assert [i["input"] for i in lines if "input" in i] == ["command", "write"]
            # Not while a program runs: the replay would miss its start.
            code, body = await post(http, "/api/record", {"on": False})
            assert code == 200 and body["last"] == str(path)
            code, body = await post(http, "/api/record", {"on": True})
            assert code == 409 and "idle" in body["error"]
            async with http.get("/api/trace.jsonl") as r:
                assert r.status == 200 and "attachment" in r.headers["Content-Disposition"]
                trace = [json.loads(line) for line in (await r.text()).splitlines()]
            assert [e["seq"] for e in trace] == [e["seq"] for e in gw.trace]
            assert any(e["event"] == "resume" and e["proc"] == 2 for e in trace)
    text = await asyncio.to_thread(path.read_text)
    assert json.loads(text.splitlines()[-1]).keys() == {"stop"}
    result = replay(path)
    assert result.divergence is None, result.divergence


async def test_a_record_is_not_started_over_forces_or_faults_a_replay_would_not_have(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A record begun with a fault and a force in force held neither, and its replay
    diverged from a cell it never saw (a hostile try)."""
    monkeypatch.chdir(tmp_path)
    async with await console() as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            assert (await post(http, "/api/force", {"var": "SA12", "value": 1}))[0] == 200
            assert (await post(http, "/api/fault", {"target": "SA13", "kind": "stuck",
                                                    "value": 1}))[0] == 200
            code, body = await post(http, "/api/record", {"on": True})
            assert code == 409 and "1 force(s) and 1 fault(s)" in body["error"], body
            assert gw.recorder is None
            assert (await post(http, "/api/force", {"var": "SA12", "value": None}))[0] == 200
            code, body = await post(http, "/api/record", {"on": True})
            assert code == 409 and "0 force(s) and 1 fault(s)" in body["error"], body
            assert (await post(http, "/api/fault", {"clear": "all"}))[0] == 200
            code, body = await post(http, "/api/record", {"on": True})
            assert code == 200, body


async def test_status_says_where_each_process_is_and_its_feed(tmp_path: Path) -> None:
    """Issue 30: a lane shows X/Y/Z and the feed: after G1 X10 Y20 Z-5 F300 the process
    stands there, with the modal feed 300 mm/min."""
    (tmp_path / "A.nc").write_text("N1G1X10Y20Z-5F300\nN2(WAI,SA10=1)\nN3M30\n")
    # lookahead 0: the WAI acts after the move above it (spec 2.4), not while it is queued.
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\nlookahead = 0\n'
                                          '[nc.storage]\nMP0 = "."\n')
    config = ncgate_test_config(tmp_path / "ncgate.toml", **{"web.port": 0,
                                                             "nc.time_scale": 100.0})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        await gw.start()
        await gw.wait_state(1, "WAIT_COND")
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/status") as r:
            p1 = (await r.json())["processes"][0]
    assert p1["position"] == {"X": 10, "Y": 20, "Z": -5} and p1["feed"] == 300


async def test_the_streams_status_built_from_changes_equals_the_whole_status() -> None:
    """Issue 24/30: the streams' status is built again only where the image changed; after
    each kind of write -- a bit, an SA byte, a K word, a SYVAR, and the same value by another
    writer (no value changes, its writer does) -- it says what /api/status says."""
    from ncgate.gateway.web.status import LiveStatus, status
    from ncgate.inputs import Source, SourceKind, Write

    async with await console() as gw:
        live = LiveStatus(gw)

        def whole() -> dict[str, str]:
            w = status(gw)
            out = {k: json.dumps(v, separators=(",", ":")) for k, v in w.items() if k != "image"}
            out.update({f"image.{k}": json.dumps(v, separators=(",", ":"))
                        for k, v in w["image"].items()})
            return out

        def image(parts: dict[str, str]) -> dict[str, str]:
            return {k: v for k, v in parts.items() if k.startswith("image.")}

        assert image(live.parts()) == image(whole())
        other = Source(SourceKind.WEB, "10.0.0.9", "10.0.0.9")
        for var, value, source in [("SA10", 1, None), ("SA3.BY", 0x81, None),
                                   ("SK6.IN", 0x1234, None), ("SYVAR7", -5, None),
                                   ("SYVAR7", -5, other)]:
            if source is None:
                gw.write(var, value)
            else:
                gw.apply(Write(gw.runtime.var(var), value, source))
            assert image(live.parts()) == image(whole()), var
        assert "10.0.0.9" in live.parts()["image.writers"]
        live.close()


async def test_the_status_shows_the_image_and_the_plant_of_the_cells_view(
        tmp_path: Path) -> None:
    """The console reads the image and the plant from the cell's read model (gateway/view.py),
    as every adapter does: /api/status's ``plant`` and ``image`` are the view's, encoded by
    the one encoding, and so is /api/fault's answer."""
    from ncgate.gateway.view import plant_status
    from ncgate.gateway.web.status import image_status

    (tmp_path / "A.nc").write_text("N1(WAI,SA10=1)\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[plant]\nscan_ms = 10\n'
        '[[plant.model]]\nname = "clamp"\nkind = "cylinder"\nextend = "SA20"\n'
        'extended = "SA30"\nretracted = "SA31"\ntravel_ms = 300\n')
    config = ncgate_test_config(tmp_path / "ncgate.toml", **{"web.port": 0})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        await gw.start()
        await gw.wait_state(1, "WAIT_COND")
        gw.write("SYVAR3", -7)
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            status, faults = await post(http, "/api/fault", {"target": "clamp",
                                                            "kind": "never"})
            assert status == 200
            async with http.get("/api/status") as r:
                shown = await r.json()
        view = gw.view  # the cell stands still: the view the answers were made of
        assert view.plant is not None and view.plant.faults[0].kind == "never"
        assert faults == plant_status(view.plant)["faults"]
        assert shown["plant"] == plant_status(view.plant) == gw.plant.status()
        assert shown["plant"]["models"][0]["state"] == "retracted"
        assert shown["image"] == image_status(view.image)
        assert shown["image"]["syvar"][3] == -7


async def test_an_idle_cells_page_hears_of_a_record_started(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The built-in cell without PLC logic stands still: no event, no write, no clock.  A
    record started from the page still reaches every stream's status (it stayed "Record"
    for 18 s, and a second click was refused)."""
    monkeypatch.chdir(tmp_path)  # where run puts a record started from the page
    async with await console() as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with http.get("/api/stream") as r:
                stream = read_sse(r)
                _, status = await next_of(stream, "status")
                assert status.get("record") is None
                async with http.post("/api/record", json={"on": True}) as answer:
                    assert answer.status == 200
                    path = (await answer.json())["record"]
                while True:  # (next_of gives up after 10 s: the page never heard of it)
                    _, status = await next_of(stream, "status")
                    if status.get("record") == path:
                        break
            assert gw.stop_record() == Path(path)


async def _half_a_body(host: str, port: int) -> tuple[asyncio.StreamReader,
                                                      asyncio.StreamWriter]:
    reader, writer = await asyncio.open_connection(host, port)
    writer.write(f"POST /api/write HTTP/1.1\r\nHost: {host}:{port}\r\nContent-Type: "
                 'application/json\r\nContent-Length: 100\r\n\r\n{"var": '.encode())
    await writer.drain()
    return reader, writer


async def test_a_client_gone_mid_body_is_one_line_not_a_traceback(
        gw: Gateway, caplog: pytest.LogCaptureFixture) -> None:
    host, port = gw.web_address
    with caplog.at_level(logging.INFO, logger="ncgate.web"):
        _, writer = await _half_a_body(host, port)
        writer.close()
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with asyncio.timeout(10):
                while not any("went away" in r.getMessage() for r in caplog.records):
                    # (the server's log is another task's: asked again until it is there)
                    async with http.get("/api/status") as answer:
                        assert answer.status == 200
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert sum("went away before its body was whole" in r.getMessage()
               for r in caplog.records) == 1


async def test_a_body_that_does_not_come_is_timed_out_with_408(
        gw: Gateway, monkeypatch: pytest.MonkeyPatch) -> None:
    from ncgate.gateway.web import console as console_module

    monkeypatch.setattr(console_module, "BODY_TIMEOUT_S", 0.2)
    host, port = gw.web_address
    slow = [await _half_a_body(host, port) for _ in range(5)]
    for reader, writer in slow:
        async with asyncio.timeout(10):
            head = await reader.readuntil(b"\r\n")
        assert head.startswith(b"HTTP/1.1 408"), head
        writer.close()
    assert gw.read("SA10") == 0  # nothing of a half body was applied


async def test_the_status_shows_an_enumeration_by_its_value_name(tmp_path: Path) -> None:
    (tmp_path / "logic.st").write_text(
        "TYPE Mode : (STOPPED, SETUP, RUN); END_TYPE\n"
        "PROGRAM main\nVAR m : Mode := RUN; modes : ARRAY[0..1] OF Mode; END_VAR\n"
        "modes[1] := SETUP;\nEND_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "logic.st"\n')
    config = ncgate_test_config(tmp_path / "ncgate.toml", **{"web.port": 0})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with asyncio.timeout(10):
                while True:  # until the logic has scanned once (a client polls)
                    async with http.get("/api/status") as answer:
                        rows = (await answer.json())["plc"]["variables"]
                    values = {row["path"]: row["value"] for row in rows}
                    if values["main.modes"][1] == "SETUP":
                        break
                    await asyncio.sleep(0.02)
    assert values["main.m"] == "RUN" and values["main.modes"] == ["STOPPED", "SETUP"]


async def test_the_status_says_why_a_process_stands(tmp_path: Path) -> None:
    """A breakpoint's stop is no feed hold, nor an interlock's hold: /api/status says which,
    per process and for the cell (the page showed "HOLD held" and "(feed hold)" for all)."""
    (tmp_path / "A.nc").write_text("N10G1X10F600\nN20G1X20\nN30M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\nfeed_hold_input = "SA100"\n'
                                          '[nc.storage]\nMP0 = "."\n')
    config = ncgate_test_config(tmp_path / "ncgate.toml", **{"web.port": 0,
                                                             "nc.time_scale": 10.0})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address

        async def shown() -> tuple[Any, Any]:
            async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                    http.get("/api/status") as answer:
                body = await answer.json()
            return body["standing"], body["processes"][0]["standing"]

        assert await shown() == (None, None)
        gw.apply(Break("N20"))
        await gw.start()
        await gw.wait_state(1, "HOLD")
        assert await shown() == ("breakpoint", "breakpoint")
        gw.command(CommandKind.CYCLE_START)
        await gw.wait_state(1, "RUNNING")
        gw.command(CommandKind.FEED_HOLD)
        assert await shown() == ("feed hold", "feed hold")
        gw.write("SA100", 1)
        assert await shown() == ("interlock SA100", "interlock SA100")


async def test_what_the_console_loads_at_its_first_connection_is_out_of_full_collections(
        ) -> None:
    """aiohttp, imported when the first client connects, goes to the collector's permanent
    generation, as everything loaded at start: a full collection walking it held the loop
    9-10 ms (docs/decisions.md, "The console loads at its first connection")."""
    import gc

    async with await console() as gw:
        port = gw.web_console
        assert port is not None and port.console is None  # not loaded before a client came
        frozen = gc.get_freeze_count()
        host, number = gw.web_address
        try:
            async with aiohttp.ClientSession(f"http://{host}:{number}") as http, \
                    http.get("/api/status") as r:
                assert r.status == 200
            assert port.console is not None
            assert gc.get_freeze_count() > frozen
        finally:
            gc.unfreeze()  # (this test process's own heap goes back to the collector)



async def test_a_console_that_cannot_load_at_its_first_connection_says_so_and_refuses(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """aiohttp broken on disk under a running gateway (found by a hostile try): the first
    client's connection made the console load, the import failed outside the error path,
    and every later client waited in the listen backlog for ever, with nothing logged."""
    import importlib

    import ncgate.gateway.web.port as port_module

    real = importlib.import_module

    def broken(name: str, *args: Any) -> Any:
        if name == "ncgate.gateway.web.console":
            raise ImportError("aiohttp: simulated")
        return real(name, *args)

    monkeypatch.setattr(port_module.importlib, "import_module", broken)
    async with await console() as gw:
        port = gw.web_console
        assert port is not None
        host, number = gw.web_address
        _, writer = await asyncio.open_connection(host, number)
        writer.close()
        while port._waking is None:  # noqa: ASYNC110 - the loop's reader runs the knock
            await asyncio.sleep(0.01)
        await port._waking
        assert "web console: could not start; it is off" in caplog.text
        with pytest.raises(OSError):  # refused now, not queued
            await asyncio.open_connection(host, number)


# -- a second hostile try: half requests, resets, long lines ---------------------------------

async def test_a_connection_with_half_a_request_line_is_closed_not_held(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """aiohttp held a connection that sent half a request line for its default hour: 1,100
    of them took every file descriptor of a process at the common limit of 1,024, and the
    Modbus server could accept no one.  Now it is closed after console.IDLE_S."""
    from ncgate.gateway.web import console as console_module

    monkeypatch.setattr(console_module, "IDLE_S", 0.3)
    async with await console() as gw:
        host, port = gw.web_address
        half = []
        for _ in range(5):
            reader, writer = await asyncio.open_connection(host, port)
            writer.write(b"GET /api/status HTTP/1.1\r\nHost: ")
            await writer.drain()
            half.append((reader, writer))
        for reader, writer in half:
            async with asyncio.timeout(10):
                assert await reader.read() == b""  # closed by the server
            writer.close()
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/status") as answer:
            assert answer.status == 200


async def test_a_stream_whose_client_went_while_a_write_waited_ends_without_an_error(
        gw: Gateway, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    """aiohttp says "Connection lost" (a ConnectionError, not a reset) when the client goes
    while a write waits for room: each was an ERROR with a traceback (60 stalled streams that
    reset, 60 tracebacks)."""
    from ncgate.gateway.web import console as console_module

    send = console_module.WebConsole._send
    lost: list[bool] = []

    async def lost_on_the_second(response: Any, text: str) -> None:
        if lost:
            raise ConnectionError("Connection lost")
        lost.append(True)
        await send(response, text)

    monkeypatch.setattr(console_module.WebConsole, "_send", staticmethod(lost_on_the_second))
    web = gw.web_console
    assert web is not None
    host, port = gw.web_address
    with caplog.at_level(logging.INFO):
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/stream") as stream:
            assert stream.status == 200
            async with asyncio.timeout(10):
                while web.streams:  # noqa: ASYNC110  (its end is the server's)
                    await asyncio.sleep(0.02)
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR] == []


async def test_a_header_line_too_long_is_a_line_of_the_log_not_a_traceback(
        gw: Gateway, caplog: pytest.LogCaptureFixture) -> None:
    host, port = gw.web_address
    with caplog.at_level(logging.INFO):
        for _ in range(20):
            reader, writer = await asyncio.open_connection(host, port)
            writer.write(b"GET /api/status HTTP/1.1\r\nHost: x\r\nX-Long: " + b"a" * 20_000
                         + b"\r\n\r\n")
            await writer.drain()
            async with asyncio.timeout(10):
                assert (await reader.read()).split(b" ")[1] == b"400"
            writer.close()
    assert [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info] == []
    lines = [r.getMessage() for r in caplog.records if "malformed request" in r.getMessage()]
    assert len(lines) <= 5, lines  # a few of a kind (the budget is the process's), the rest
    # counted


async def test_a_closed_console_leaves_another_its_quiet_malformed_requests(
        gw: Gateway, caplog: pytest.LogCaptureFixture) -> None:
    """The filter is the process's: a second console closing took it from the first, whose
    malformed requests were tracebacks again (a maintainer's review)."""
    host, port = gw.web_address
    async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
            http.get("/api/status") as answer:
        assert answer.status == 200  # its console is loaded (at its first connection)
    async with await console() as other:
        host, port = other.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http, \
                http.get("/api/status") as answer:
            assert answer.status == 200
    host, port = gw.web_address
    with caplog.at_level(logging.INFO):
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(b"GET /api/status HTTP/1.1\r\nHost: x\r\nX-Long: " + b"a" * 20_000
                     + b"\r\n\r\n")
        await writer.drain()
        async with asyncio.timeout(10):
            await reader.read()
        writer.close()
    assert [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info] == []


async def test_events_since_a_negative_number_missed_none(
        gw: Gateway, http: aiohttp.ClientSession) -> None:
    await gw.start()
    await gw.wait_state(2, "WAIT_COND")
    async with http.get("/api/events", params={"since": "-1000000"}) as r:
        body = await r.json()
    assert body["missed"] == 0 and body["events"]
