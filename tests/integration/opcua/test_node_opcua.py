"""The OPC UA server seen by an independent client, node-opcua (docs/opcua.md): the endpoints,
the machine found by its type, the channel state equal to /api/status through a scripted
run, a subscription that hears every state in order, an alarm as an AlertType event with its
ErrorCode, a write refused when the region is not writable and accepted (traced ``opcua
...``) when it is, and a (WAI,SA10=1) satisfied by a UA client."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.opcua.model import channel_state
from ncgate.gateway.record import replay
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import ProcessState

from ...helpers import write_cell
from .conftest import CNC, DI, IMAGE, MACHINE_TOOL, MACHINERY, NCGATE, UaClient

# Process 1 says what it waits for, waits for the door (SA10), moves, then sends to a
# process that runs nothing: AL111.
PROGRAM = 'N10 (DIS,"close the door")\nN20 (WAI,SA10=1)\nN30 G1X10F6000\nN40 (SND,2)\nN50 M30\n'


def cell(tmp_path: Path, record: Path | None = None, **overrides: Any) -> Gateway:
    # In a folder named ncgate: an ncgate.toml's machine is named after its folder
    # (docs/opcua.md), and the browse paths below name Machines/ncgate.
    folder = tmp_path / "ncgate"
    folder.mkdir()
    write_cell(folder, '[nc]\nmain = "A"\nprocesses = 2\n[nc.storage]\nMP0 = "."\n'
               '[symbols]\ndoor_closed = { var = "SA10", comment = "the guard door" }\n',
               {"A": PROGRAM})
    config = ncgate_test_config(folder / "ncgate.toml",
                                **{"opcua.enabled": True, "opcua.port": 0,
                                   "canopen.enabled": False, **overrides})
    return Gateway(config, console=True, record=record)


@pytest.fixture
async def gw(tmp_path: Path) -> AsyncIterator[Gateway]:
    async with cell(tmp_path, **{"opcua.writable": ["sa_bits"]}) as gateway:
        yield gateway


async def api_state(gw: Gateway, process: int) -> str:
    host, port = gw.web_address
    async with aiohttp.ClientSession() as http, \
            http.get(f"http://{host}:{port}/api/status") as r:
        status = await r.json()
    state: str = status["processes"][process - 1]["state"]
    return state


async def channel_states_match_api_status(gw: Gateway, ua_client: UaClient) -> None:
    """Every process's ChannelState (40501) is what /api/status's state maps to."""
    host, port = gw.web_address
    async with aiohttp.ClientSession() as http, \
            http.get(f"http://{host}:{port}/api/status") as r:
        status = await r.json()
    for p in status["processes"]:
        path = [*CHANNEL_STATE[:3], (NCGATE, f"Process {p['number']}"),
                (MACHINE_TOOL, "ChannelState")]
        node = await ua_client.call("translate", path=path)
        assert await ua_client.call("read", node=node) == channel_state(
            ProcessState[p["state"]]), p


STATE = {"ns": IMAGE, "id": "Process 1.State"}
CHANNEL_STATE = [(MACHINERY, "Machines"), (NCGATE, "ncgate"), (MACHINE_TOOL, "Monitoring"),
                 (NCGATE, "Process 1"), (MACHINE_TOOL, "ChannelState")]


async def test_the_endpoints_offer_none_on_loopback_with_anonymous_and_user_tokens(
        gw: Gateway, ua_client: UaClient) -> None:
    endpoints = await ua_client.call("endpoints", url=gw.opcua_endpoint)
    assert {(e["mode"], e["policy"].rsplit("#", 1)[1]) for e in endpoints} == {
        ("None", "None")}
    assert all(e["url"].startswith("opc.tcp://127.0.0.1:") for e in endpoints)
    assert "Anonymous" in endpoints[0]["tokens"]


async def test_the_cell_is_found_under_machines_by_its_type_with_its_identification(
        gw: Gateway, ua_client: UaClient) -> None:
    namespaces = await ua_client.call("connect", url=gw.opcua_endpoint)
    machines = await ua_client.call("translate", path=[(MACHINERY, "Machines")])
    children = await ua_client.call("browse", node=machines)
    machine_tool_type = f"ns={namespaces.index(MACHINE_TOOL)};i=13"
    found = [c for c in children if c["type"] == machine_tool_type]
    assert [c["name"] for c in found] == [f"{NCGATE}|ncgate"]
    ident = [(MACHINERY, "Machines"), (NCGATE, "ncgate"), (DI, "Identification")]
    read = {}
    for name in ("Manufacturer", "Model", "SoftwareRevision", "ProductInstanceUri"):
        node = await ua_client.call("translate", path=[*ident, (DI, name)])
        read[name] = await ua_client.call("read", node=node)
    from ncgate import __version__
    assert read == {"Manufacturer": "ncgate (virtual)", "Model": "ncgate",
                    "SoftwareRevision": __version__, "ProductInstanceUri": "urn:ncgate:ncgate"}


async def test_channel_state_equals_api_status_and_a_subscription_hears_every_state_in_order(
        gw: Gateway, ua_client: UaClient) -> None:
    namespaces = await ua_client.call("connect", url=gw.opcua_endpoint)
    channel = await ua_client.call("translate", path=CHANNEL_STATE)
    program_status = await ua_client.call("translate", path=[
        (CNC, "CncInterface"), (CNC, "CncChannelList"), (NCGATE, "Process 1"),
        (CNC, "ActProgramStatus")])
    # Typed by the specifications' enumerations (their names, on ncgate's DataType nodes).
    for node, ns, name in ((channel, MACHINE_TOOL, "ChannelState"),
                           (program_status, CNC, "CncChannelProgramStatus")):
        datatype = await ua_client.call("read", node=node, attribute="DataType")
        assert await ua_client.call("read", node=datatype, attribute="BrowseName") == (
            f"{namespaces.index(ns)}:{name}")
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("monitor", tag="state", node=STATE)
    await ua_client.call("monitor", tag="channel", node=channel)
    await ua_client.call("monitor", tag="program", node=program_status)
    await ua_client.until("state", lambda seen: seen == ["IDLE"])
    assert await api_state(gw, 1) == "IDLE"
    await channel_states_match_api_status(gw, ua_client)
    await gw.start()
    await gw.wait_state(1, "WAIT_COND")
    await ua_client.until("state", lambda seen: seen[-1:] == ["WAIT_COND"])
    api = await api_state(gw, 1)
    assert api == "WAIT_COND"
    assert await ua_client.call("read", node=channel) == channel_state(ProcessState[api])
    assert await ua_client.call("read", node=program_status) == 2  # Waiting
    await channel_states_match_api_status(gw, ua_client)
    gw.write("SA10", 1)  # the door closes: on to the SND to an idle P2
    await gw.wait_state(1, "ALARM")
    seen = await ua_client.until("state", lambda seen: seen[-1:] == ["ALARM"])
    assert await api_state(gw, 1) == "ALARM"
    await channel_states_match_api_status(gw, ua_client)
    # Every state the process went through, once each and in order.
    assert seen == ["IDLE", "RUNNING", "WAIT_COND", "RUNNING", "ALARM"]
    channel_seen = await ua_client.until("channel", lambda seen: seen[-1:] == [1])
    assert channel_seen == [2, 0, 1]  # Reset, Active (running and waiting), Interrupted
    program_seen = await ua_client.until("program", lambda seen: seen[-1:] == [4])
    assert program_seen == [0, 1, 2, 1, 4]  # Stopped, Running, Waiting, Running, Canceled



async def messages_node(ua_client: UaClient) -> str:
    """The cell's Notification/Messages, where its alarms and messages are events."""
    node: str = await ua_client.call("translate", path=[
        (MACHINERY, "Machines"), (NCGATE, "ncgate"), (MACHINE_TOOL, "Notification"),
        (MACHINE_TOOL, "Messages")])
    return node

async def test_an_alarm_is_an_alert_event_with_its_error_code_and_a_message_a_notification(
        gw: Gateway, ua_client: UaClient) -> None:
    await ua_client.call("connect", url=gw.opcua_endpoint)
    messages = await messages_node(ua_client)
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("events", tag="events", node=messages, fields=[
        ["", "EventType"], ["", "Message"], ["", "Severity"], [MACHINE_TOOL, "ErrorCode"]])
    await gw.start()
    await gw.wait_state(1, "WAIT_COND")
    gw.write("SA10", 1)
    await gw.wait_state(1, "ALARM")
    events = await ua_client.until("events", lambda seen: len(seen) >= 2)
    (message_type, message, _, _), (alert_type, alarm, severity, code) = events[:2]
    assert message == "close the door"
    assert alert_type.endswith(";i=39")  # AlertType (OPC 40501-1)
    assert message_type != alert_type
    assert code == "AL111"
    assert severity >= 667
    assert alarm.startswith("P1 A.nc:4 N40: AL111 "), alarm


async def test_a_write_of_a_region_not_writable_is_bad_not_writable_and_changes_nothing(
        tmp_path: Path, ua_client: UaClient) -> None:
    async with cell(tmp_path) as gw:  # opcua.writable: nothing
        await ua_client.call("connect", url=gw.opcua_endpoint)
        for node, kind, value in (("SA10", "Boolean", True), ("SK2", "Byte", 7),
                                  ("SYVAR7", "Int16", -5), ("door_closed", "Boolean", True)):
            answer = await ua_client.call("write", node={"ns": IMAGE, "id": node},
                                          type=kind, value=value)
            assert answer == "BadNotWritable", node
        assert (gw.read("SA10"), gw.read("SK2"), gw.read("SYVAR7")) == (0, 0, 0)
        assert not [e for e in gw.trace if e["event"] == "write"]


async def test_a_write_of_a_writable_region_goes_through_the_door_traced_opcua(
        gw: Gateway, ua_client: UaClient) -> None:
    await ua_client.call("connect", url=gw.opcua_endpoint)
    assert await ua_client.call("write", node={"ns": IMAGE, "id": "SA12"}, type="Boolean",
                                value=True) == "Good"
    assert gw.read("SA12") == 1
    writes = [e for e in gw.trace if e["event"] == "write"]
    assert [(w["var"], w["value"]) for w in writes] == [("SA12", 1)]
    assert writes[0]["who"].startswith("opcua 127.0.0.1:")
    # SK is not listed in opcua.writable: refused by the one table, nothing written.
    assert await ua_client.call("write", node={"ns": IMAGE, "id": "SK2"}, type="Byte",
                                value=3) == "BadNotWritable"
    assert gw.read("SK2") == 0
    # /api/status shows the server and what its clients did.
    host, port = gw.web_address
    async with aiohttp.ClientSession() as http, \
            http.get(f"http://{host}:{port}/api/status") as r:
        status = (await r.json())["fieldbus"]["opcua"]
    assert status == {"endpoint": gw.opcua_endpoint, "security": "none",
                      "writable": ["sa_bits"], "sessions": 1, "subscriptions": 0,
                      "writes": 1, "refused": 1}


async def test_a_ua_client_satisfies_a_wai_by_writing_sa10_and_sees_the_process_resume(
        gw: Gateway, ua_client: UaClient) -> None:
    await ua_client.call("connect", url=gw.opcua_endpoint)
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("monitor", tag="state", node=STATE)
    await ua_client.call("monitor", tag="door", node={"ns": IMAGE, "id": "door_closed"})
    await gw.start()
    await ua_client.until("state", lambda seen: seen[-1:] == ["WAIT_COND"])
    # The I/O name of [symbols] is a node of its own: writing it writes SA10.
    assert await ua_client.call("write", node={"ns": IMAGE, "id": "door_closed"},
                                type="Boolean", value=True) == "Good"
    seen = await ua_client.until("state", lambda seen: seen[-1:] == ["ALARM"])
    assert seen[seen.index("WAIT_COND") + 1] == "RUNNING"  # it resumed past N20
    assert await ua_client.until("door", lambda seen: seen[-1:] == [True]) == [False, True]
    assert await ua_client.call("read", node={"ns": IMAGE, "id": "SA10"}) is True
    resumes = [e for e in gw.trace if e["event"] == "resume" and e["proc"] == 1]
    assert resumes and any(e["who"].startswith("opcua ") for e in gw.trace
                           if e["event"] == "write" and e["var"] == "SA10")


async def test_the_snd_log_and_a_plant_model_are_nodes_of_the_image_namespace(
        tmp_path: Path, ua_client: UaClient) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\nprocesses = 2\n[nc.storage]\nMP0 = "."\n'
               '[[plant.model]]\nname = "relay"\nkind = "delay"\ninput = "SA20"\n'
               'output = "SA30"\non_ms = 50\n',
               {"A": "N10 (EXE,2,B)\nN20 (SND,2)\nN30 M30\n", "B": "N1 (WAI,1)\nN2 M30\n"})
    config = ncgate_test_config(tmp_path / "ncgate.toml", **{
        "opcua.enabled": True, "opcua.port": 0, "canopen.enabled": False})
    async with Gateway(config) as gw:
        await ua_client.call("connect", url=gw.opcua_endpoint)
        await ua_client.call("subscribe", interval=20)
        await ua_client.call("monitor", tag="snd", node={"ns": IMAGE, "id": "SndLog"})
        await ua_client.call("monitor", tag="relay",
                             node={"ns": IMAGE, "id": "Plant/relay.State"})
        first = (await ua_client.until("relay", lambda seen: len(seen) >= 1))[-1]
        await gw.start()
        await gw.wait_idle()
        log = await ua_client.until("snd", lambda seen: bool(seen and seen[-1]))
        assert len(log[-1]) == 1
        assert log[-1][0].endswith("P1 -> P2 A.nc:2 N20"), log[-1]
        gw.write("SA20", 1)  # the relay's input: its state changes
        seen = await ua_client.until("relay", lambda seen: seen[-1] != first)
        assert seen[-1] != first


async def test_a_session_with_a_ua_write_is_recorded_as_opcua_and_replays_without_divergence(
        tmp_path: Path, ua_client: UaClient) -> None:
    record = tmp_path / "session.jsonl"
    async with cell(tmp_path, record, **{"opcua.writable": ["sa_bits"]}) as gw:
        await ua_client.call("connect", url=gw.opcua_endpoint)
        await gw.start()
        await gw.wait_state(1, "WAIT_COND")
        assert await ua_client.call("write", node={"ns": IMAGE, "id": "SA10"},
                                    type="Boolean", value=True) == "Good"
        await gw.wait_state(1, "ALARM")
    text = await asyncio.to_thread(record.read_text)
    lines = [json.loads(line) for line in text.splitlines()]
    writes = [i for i in lines if i.get("input") == "write"]
    assert len(writes) == 1 and writes[0]["who"].startswith("opcua 127.0.0.1:"), writes
    result = replay(record)
    assert result.divergence is None, result.divergence


async def test_act_program_name_and_act_main_program_name_both_name_the_started_program(
        gw: Gateway, ua_client: UaClient) -> None:
    # Neither dialect calls subprograms (docs/language.md, docs/isg.md): the program a
    # process runs is the one its start, cycle start or EXE loaded, so both nodes name it.
    await ua_client.call("connect", url=gw.opcua_endpoint)
    channel = [(CNC, "CncInterface"), (CNC, "CncChannelList"), (NCGATE, "Process 1")]
    name = await ua_client.call("translate", path=[*channel, (CNC, "ActProgramName")])
    main = await ua_client.call("translate", path=[*channel, (CNC, "ActMainProgramName")])
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("monitor", tag="main", node=main)
    await gw.start()
    await gw.wait_state(1, "WAIT_COND")  # inside A, at its (WAI,SA10=1)
    await ua_client.until("main", lambda seen: seen[-1:] == ["A"])
    assert await ua_client.call("read", node=name) == "A"
    assert await ua_client.call("read", node=main) == "A"


REFRESH_START, REFRESH_END = "ns=0;i=2787", "ns=0;i=2788"  # RefreshStart/EndEventType
CONDITION_FIELDS = [["", "EventId"], ["", "EventType"], ["", "ConditionId"], ["", "Retain"],
                    ["", "ActiveState.Id"], ["", "AckedState.Id"], [MACHINE_TOOL, "ErrorCode"]]


async def test_an_alarm_is_a_condition_a_client_acknowledges_and_condition_refresh_resends(
        gw: Gateway, ua_client: UaClient) -> None:
    await ua_client.call("connect", url=gw.opcua_endpoint)
    messages = await messages_node(ua_client)
    subscription = await ua_client.call("subscribe", interval=20)
    await ua_client.call("events", tag="alarms", node=messages, fields=CONDITION_FIELDS)
    await ua_client.call("events", tag="server", node=SERVER, fields=[["", "EventType"]])

    def conditions(seen: list[Any]) -> list[Any]:
        return [e for e in seen if e[1].endswith(";i=39")]  # AlertType's

    await gw.start()
    await gw.wait_state(1, "WAIT_COND")
    gw.write("SA10", 1)
    await gw.wait_state(1, "ALARM")
    seen = await ua_client.until("alarms", lambda seen: len(conditions(seen)) == 1)
    event_id, _, condition, retain, active, acked, code = conditions(seen)[0]
    assert (retain, active, acked, code) == (True, True, False, "AL111")

    # Acknowledged: still active (the alarm stays until a reset), still retained.
    acknowledge = "ns=0;i=9111"  # AcknowledgeableConditionType's Acknowledge
    assert await ua_client.call("call", object=condition, method=acknowledge, args=[
        ["ByteString", event_id], ["LocalizedText", "seen"]]) == "Good"
    seen = await ua_client.until("alarms", lambda seen: len(conditions(seen)) == 2)
    acked_id, _, same, retain, active, acked, _ = conditions(seen)[1]
    assert (same, retain, active, acked) == (condition, True, True, True)
    assert await ua_client.call("call", object=condition, method=acknowledge, args=[
        ["ByteString", acked_id], ["LocalizedText", "again"]]) == (
        "BadConditionBranchAlreadyAcked")
    assert await ua_client.call("call", object=condition, method=acknowledge, args=[
        ["ByteString", event_id], ["LocalizedText", "stale"]]) == "BadEventIdUnknown"

    # ConditionRefresh: the retained condition again (a new event of the same condition).
    refresh = ("ns=0;i=2782", "ns=0;i=3875")  # ConditionType, its ConditionRefresh
    assert await ua_client.call("call", object=refresh[0], method=refresh[1],
                                args=[["UInt32", subscription]]) == "Good"
    seen = await ua_client.until("alarms", lambda seen: len(conditions(seen)) == 3)
    assert conditions(seen)[2][2:6] == [condition, True, True, True]
    at_server = await ua_client.until("server", lambda seen: [REFRESH_END] in seen)
    assert at_server[-3:] == [[REFRESH_START], [conditions(seen)[2][1]], [REFRESH_END]]

    # A reset ends the alarm: inactive and acknowledged, so no longer retained.
    gw.command(3, process=1)  # reset
    seen = await ua_client.until("alarms", lambda seen: len(conditions(seen)) == 4)
    assert conditions(seen)[3][2:6] == [condition, False, False, True]


async def test_the_cell_s_alarm_is_a_condition_active_until_a_client_acknowledges_it(
        gw: Gateway, ua_client: UaClient) -> None:
    # A fieldbus alarm (process 0) stops nothing and is pending nowhere in ncgate: only the
    # acknowledge ends its condition.
    from ncgate.inputs import FieldbusAlarm

    await ua_client.call("connect", url=gw.opcua_endpoint)
    messages = await messages_node(ua_client)
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("events", tag="alarms", node=messages, fields=CONDITION_FIELDS)
    gw.apply(FieldbusAlarm(150, "node 5's heartbeat stopped"))
    seen = await ua_client.until("alarms", lambda seen: len(seen) == 1)
    event_id, _, condition, *states, code = seen[0]
    assert (states, code) == ([True, True, False], "AL150")
    assert await ua_client.call("call", object=condition, method="ns=0;i=9111", args=[
        ["ByteString", event_id], ["LocalizedText", "replaced the cable"]]) == "Good"
    seen = await ua_client.until("alarms", lambda seen: len(seen) == 2)
    assert seen[1][2:6] == [condition, False, False, True]


SERVER = "ns=0;i=2253"  # the Server object, where an alarm list subscribes
HAS_NOTIFIER = "ns=0;i=48"
EVENT_FIELDS = [["", "EventId"], ["", "EventType"], ["", "Message"], ["", "SourceName"],
                [MACHINE_TOOL, "ErrorCode"]]


async def test_the_server_object_reports_the_alarm_and_the_message_as_the_events_of_messages(
        gw: Gateway, ua_client: UaClient) -> None:
    await ua_client.call("connect", url=gw.opcua_endpoint)
    messages = await messages_node(ua_client)
    # The notifier hierarchy (OPC 10000-3 7.17) browses from the Server object to Messages.
    chain, node = [], SERVER
    while node != messages and len(chain) < 4:
        below = await ua_client.call("browse", node=node, ref=HAS_NOTIFIER)
        assert [b["ref"] for b in below] == [HAS_NOTIFIER], (node, below)
        chain.append(below[0]["name"])
        node = below[0]["node"]
    assert chain == [f"{NCGATE}|ncgate", f"{MACHINE_TOOL}|Notification",
                     f"{MACHINE_TOOL}|Messages"]
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("events", tag="messages", node=messages, fields=EVENT_FIELDS)
    await ua_client.call("events", tag="server", node=SERVER, fields=EVENT_FIELDS)
    await gw.start()
    await gw.wait_state(1, "WAIT_COND")
    gw.write("SA10", 1)
    await gw.wait_state(1, "ALARM")
    at_server = await ua_client.until(
        "server", lambda seen: any(e[1].endswith(";i=39") for e in seen))
    at_messages = await ua_client.until("messages", lambda seen: len(seen) >= 2)
    # The same two events, one each: their EventIds and fields as Messages reported them.
    assert at_server == at_messages
    (_, _, message, _, _), (_, alert_type, alarm, source, code) = at_server
    assert message == "close the door"
    assert alert_type.endswith(";i=39") and code == "AL111" and source == "Process 1"
    assert alarm.startswith("P1 A.nc:4 N40: AL111 "), alarm


async def test_condition_refresh_sends_the_retained_alarm_to_the_server_object_s_items_too(
        gw: Gateway, ua_client: UaClient) -> None:
    await ua_client.call("connect", url=gw.opcua_endpoint)
    messages = await messages_node(ua_client)
    await gw.start()
    await gw.wait_state(1, "WAIT_COND")
    await ua_client.call("subscribe", interval=20)
    await ua_client.call("events", tag="live", node=messages, fields=EVENT_FIELDS)
    gw.write("SA10", 1)
    await gw.wait_state(1, "ALARM")
    # The alarm (AlertType, i=39); the program's message before it may come first when the
    # server's process took it in after the item was made (CI, loaded: the test took the
    # message for the alarm).
    seen = await ua_client.until("live", lambda seen: any(e[1].endswith(";i=39")
                                                          for e in seen))
    alarm = next(e for e in seen if e[1].endswith(";i=39"))
    # A client that subscribes after the alarm asks for the retained conditions.
    subscription = await ua_client.call("subscribe", interval=20)
    items = {tag: await ua_client.call("events", tag=tag, node=node, fields=EVENT_FIELDS)
             for tag, node in (("server", SERVER), ("messages", messages))}
    assert await ua_client.call("call", object="ns=0;i=2782", method="ns=0;i=3875",
                                args=[["UInt32", subscription]]) == "Good"
    refreshed = {tag: await ua_client.until(tag, lambda seen: len(seen) >= 3) for tag in items}
    for tag, seen in refreshed.items():  # each notifier item: start, the alarm, end
        assert [e[1] for e in seen] == [REFRESH_START, alarm[1], REFRESH_END], tag
        assert seen[1] == alarm, tag  # the condition's latest event, as it was sent
    # One RefreshStart and one RefreshEnd, a copy for each item (OPC 10000-9 5.5.7).
    assert refreshed["server"][0][0] == refreshed["messages"][0][0]
    assert refreshed["server"][2][0] == refreshed["messages"][2][0]
    # ConditionRefresh2: the one item (Messages's), then the other.
    refresh2 = "ns=0;i=12912"
    assert await ua_client.call("call", object="ns=0;i=2782", method=refresh2, args=[
        ["UInt32", subscription], ["UInt32", items["messages"]]]) == "Good"
    again = await ua_client.until("messages", lambda seen: len(seen) >= 6)
    assert [e[1] for e in again[3:]] == [REFRESH_START, alarm[1], REFRESH_END]
    assert await ua_client.call("call", object="ns=0;i=2782", method=refresh2, args=[
        ["UInt32", subscription], ["UInt32", items["server"]]]) == "Good"
    await ua_client.until("server", lambda seen: len(seen) >= 6)
    assert len(ua_client.notes["messages"]) == 6  # the second went to the Server's item only
    assert ua_client.notes["live"] == [alarm]  # nor to the other subscription


async def test_the_map_names_each_variable_s_data_type_as_the_server_declares_it(
        gw: Gateway, ua_client: UaClient) -> None:
    """``ncgate map``'s UA rows against the running server: a variable of an enumeration is
    typed by the enumeration (its name in the map), whose EnumValues name the values for a
    generic client; any other variable by the DataType the map names."""
    from ncgate.gateway.opcua.model import (
        CHANNEL_MODE,
        CHANNEL_STATE,
        CNC_CHANNEL_STATUS,
        CNC_PROGRAM_STATUS,
        node_rows,
    )

    enumerations = {e.name: e for e in (CHANNEL_STATE, CHANNEL_MODE, CNC_CHANNEL_STATUS,
                                        CNC_PROGRAM_STATUS)}
    namespaces = await ua_client.call("connect", url=gw.opcua_endpoint)
    rows = node_rows("ncgate", [1, 2], {"sa_bits": 8, "k_bytes": 8, "syvars": 8},
                     frozenset(), {})
    seen = set()
    for path, node_id, kind, _, _ in rows:
        if kind == "MachineToolType" or " .. " in path:
            continue  # the machine object, and the image's ranges
        uri, _, ident = node_id.removeprefix("ns=").partition(";s=")
        node = {"ns": uri, "id": ident} if ident else node_id
        if kind == "events":  # a notifier a client subscribes to: SubscribeToEvents
            assert await ua_client.call("read", node=node, attribute="EventNotifier") & 1, path
            continue
        datatype = await ua_client.call("read", node=node, attribute="DataType")
        ns, name = (await ua_client.call("read", node=datatype, attribute="BrowseName")
                    ).split(":", 1)
        rank = await ua_client.call("read", node=node, attribute="ValueRank")
        if kind.endswith(" (enumeration)"):
            enumeration = enumerations[kind.removesuffix(" (enumeration)")]
            assert (namespaces[int(ns)] in (MACHINE_TOOL, CNC), name, rank) == (
                True, enumeration.name, -1), path
            props = await ua_client.call("browse", node=datatype, ref="ns=0;i=46")
            (values,) = [p["node"] for p in props if p["name"].endswith("|EnumValues")]
            shown = await ua_client.call("read", node=values)
            assert [v["displayName"]["text"] for v in shown] == list(enumeration.names), path
            seen.add(enumeration.name)
        else:
            assert (ns, name, rank) == ("0", kind.removesuffix("[3]"),
                                        1 if kind.endswith("]") else -1), path
    assert seen == set(enumerations)  # each enumeration's variables are in the map
