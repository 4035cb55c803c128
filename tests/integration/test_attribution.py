"""One attribution everywhere: the same input shows the same source in the trace, the run
log, the session record and the console -- from the API, Modbus, the console and the PLC
logic, in one gateway."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import aiohttp
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway import Gateway, load_config
from ncgate.gateway.cli.serve import describe
from ncgate.interpreter.engine.events import Event


async def test_each_source_is_named_alike_in_trace_log_record_and_console(
        tmp_path: Path) -> None:
    (tmp_path / "A.nc").write_text("N1(WAI,SA30=1)\nN2M30\n")
    (tmp_path / "plc.st").write_text("PROGRAM p\n(* the PLC starts the cycle *)\n"
                                     "NC.START := SA[20];\nEND_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[plc]\nlogic = "plc.st"\n')
    cfg = load_config(tmp_path / "ncgate.toml",
                      overrides={"modbus.port": 0, "canopen.enabled": False, "web.port": 0})
    record = tmp_path / "session.jsonl"
    logged: list[str] = []

    def log(event: Event) -> None:
        line = describe(event)
        if line is not None:
            logged.append(line)

    async with Gateway(cfg, listeners=[log], console=True, record=record, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        host, port = gw.web_address
        try:
            gw.write("SA12", 1)  # the Python API
            await client.write_coil(13, True, device_id=1)  # a Modbus client
            async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
                async with http.post("/api/write", json={"var": "SA14", "value": 1}) as r:
                    assert r.status == 200  # the console
                async with http.get("/api/status") as r:
                    console = (await r.json())["image"]["writers"]["SA"]
            await client.write_coil(20, True, device_id=1)  # the PLC logic starts the cycle
            await gw.wait_state(1, "WAIT_COND", timeout_s=10)
            local = client.ctx.transport.get_extra_info("sockname")  # type: ignore[union-attr]
        finally:
            client.close()
        trace = gw.trace
    modbus = f"modbus 127.0.0.1:{local[1]}"
    web = "web 127.0.0.1"
    expected = {"SA12": "api", "SA13": modbus, "SA14": web}

    writes = {e["var"]: e["who"] for e in trace if e["event"] == "write"}
    assert {v: writes[v] for v in expected} == expected  # the trace
    for var, who in expected.items():
        assert f"{var} = 1 (by {who})" in logged  # the run log
        assert console[var[2:]] == who  # the console's "last written by"
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    recorded: dict[str, Any] = {f"{c[0]}{c[1]}": i["who"] for i in lines
                                if i.get("input") == "write" for c in i["changes"]}
    assert {v: recorded[v] for v in expected} == expected  # the record

    # The PLC's NC.START, named with the line of the logic that set it: in the trace and the
    # log; not in the record (a replay runs the same logic, which starts the cycle again).
    (start,) = [e for e in trace if e["event"] == "start"]
    assert start["by"] == "plc plc.st:3"
    assert "P1 starts A (by plc plc.st:3)" in logged
    assert not any(i.get("input") in ("command", "start") for i in lines)
