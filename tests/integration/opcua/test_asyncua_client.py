"""The OPC UA server against what a client may send (docs/opcua.md), driven by asyncua's client
(it needs no node): a method called with the wrong arguments, a write of the wrong type or
with parts the image does not keep, what an anonymous session is told it may write while
[opcua.users] is set, and the limits one client cannot pass to starve another."""

from __future__ import annotations

import asyncio
import hashlib
import os
import re
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from typing import Any

import pytest
from asyncua import Client, ua

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from .conftest import IMAGE, NCGATE

Bad = ua.StatusCodes
V, T = ua.Variant, ua.VariantType


def gateway(**overrides: Any) -> Gateway:
    return Gateway(ncgate_test_config(**{"opcua.enabled": True, "opcua.port": 0,
                                         "canopen.enabled": False, **overrides}))


def written(gw: Gateway) -> list[tuple[str, int]]:
    return [(e["var"], e["value"]) for e in gw.trace if e["event"] == "write"]


async def call(client: Client, obj: ua.NodeId, method: int,
               args: list[ua.Variant]) -> ua.CallMethodResult:
    request = ua.CallMethodRequest(ObjectId=obj, MethodId=ua.NodeId(method),
                                   InputArguments=args)
    result: ua.CallMethodResult = (await client.uaclient.call([request]))[0]
    return result


async def test_a_method_called_with_missing_extra_or_mistyped_arguments_is_refused_unlogged(
        capfd: pytest.CaptureFixture[str]) -> None:
    """OPC 10000-4 5.12.2 (Call): Bad_ArgumentsMissing, Bad_TooManyArguments, and
    Bad_InvalidArgument with Bad_TypeMismatch for the argument -- never asyncua's
    Bad_UnexpectedError, and no traceback in the log (the server's stderr)."""
    event_id = V(b"not an event", T.ByteString)
    comment = V(ua.LocalizedText("seen"))
    async with gateway() as gw, Client(gw.opcua_endpoint) as client:
        ns = await client.get_namespace_index(NCGATE)
        condition = ua.NodeId("Alarms/Process 1", ns)
        acknowledge = ua.ObjectIds.AcknowledgeableConditionType_Acknowledge
        for args, status in (([], Bad.BadArgumentsMissing),
                             ([event_id], Bad.BadArgumentsMissing),
                             ([event_id, comment, V(1, T.Int32)], Bad.BadTooManyArguments),
                             ([event_id, V("seen", T.String)], Bad.BadInvalidArgument),
                             ([V([b"a"], T.ByteString), comment], Bad.BadInvalidArgument)):
            result = await call(client, condition, acknowledge, args)
            assert result.StatusCode.value == status, args
        assert [r.value for r in result.InputArgumentResults] == [Bad.BadTypeMismatch, 0]
        # Well formed, it reaches the condition: an EventId it never raised.
        result = await call(client, condition, acknowledge, [event_id, comment])
        assert result.StatusCode.value == Bad.BadEventIdUnknown
        # ConditionRefresh and ConditionRefresh2 alike (their ids are UInt32).
        condition_type = ua.NodeId(ua.ObjectIds.ConditionType)
        refresh, refresh2 = (ua.ObjectIds.ConditionType_ConditionRefresh,
                             ua.ObjectIds.ConditionType_ConditionRefresh2)
        for method, args, status in (
                (refresh, [], Bad.BadArgumentsMissing),
                (refresh, [V(1, T.Int64)], Bad.BadInvalidArgument),
                (refresh, [V(1, T.UInt32)], Bad.BadSubscriptionIdInvalid),
                (refresh2, [V(1, T.UInt32)], Bad.BadArgumentsMissing),
                (refresh2, [V(1, T.UInt32)] * 3, Bad.BadTooManyArguments)):
            result = await call(client, condition_type, method, args)
            assert result.StatusCode.value == status, (method, args)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "TypeError" not in err, err


async def write(client: Client, node: ua.NodeId, value: ua.DataValue,
                index_range: str | None = None) -> int:
    item = ua.WriteValue(NodeId=node, AttributeId=ua.AttributeIds.Value, Value=value,
                         IndexRange=index_range)  # type: ignore[arg-type]
    status: ua.StatusCode = (await client.uaclient.write(
        ua.WriteParameters(NodesToWrite=[item])))[0]
    return status.value


async def test_a_write_of_another_type_or_with_what_the_image_does_not_keep_is_refused(
        ) -> None:
    """OPC 10000-4 5.11.4 (Write): a value not exactly of the node's DataType is
    Bad_TypeMismatch; an IndexRange on these scalars Bad_WriteNotSupported (or
    Bad_IndexRangeInvalid, its syntax wrong); a StatusCode other than Good, which the image
    does not keep, Bad_WriteNotSupported.  Nothing of them is written or traced.  A
    timestamp is not kept and not refused: asyncua's own write_value (docs/opcua.md's
    recipe) stamps every write with one, and every such write was refused."""
    async with gateway(**{"opcua.writable": ["sa_bits", "syvars"],
                          "symbols": {"door_closed": "SA10"}}) as gw, \
            Client(gw.opcua_endpoint) as client:
        ns = await client.get_namespace_index(IMAGE)
        syvar, sa, door = (ua.NodeId(key, ns) for key in ("SYVAR7", "SA12", "door_closed"))
        for node, variant in ((syvar, V(True, T.Boolean)), (syvar, V(2.0, T.Double)),
                              (syvar, V(3.0, T.Float)), (syvar, V(4, T.UInt64)),
                              (syvar, V(4, T.Int32)), (syvar, V(4, T.UInt16)),
                              (syvar, V("8", T.String)), (syvar, V([1, 2], T.Int16)),
                              (syvar, V(None, T.Null)), (sa, V(1, T.Int32)),
                              (sa, V(1, T.Byte)), (door, V(1, T.Int16))):
            assert await write(client, node, ua.DataValue(variant)) == Bad.BadTypeMismatch, (
                node, variant)
        int16 = V(5, T.Int16)
        for index_range, status in (("0", Bad.BadWriteNotSupported),
                                    ("7:9", Bad.BadWriteNotSupported),
                                    ("9:7", Bad.BadIndexRangeInvalid),
                                    ("x", Bad.BadIndexRangeInvalid)):
            assert await write(client, syvar, ua.DataValue(int16), index_range) == status
        for value in (ua.DataValue(int16, StatusCode=ua.StatusCode(Bad.BadSensorFailure)),
                      ua.DataValue(int16, StatusCode=ua.StatusCode(
                          ua.StatusCodes.UncertainLastUsableValue))):
            assert await write(client, syvar, value) == Bad.BadWriteNotSupported, value
        assert (gw.read("SYVAR7"), gw.read("SA12"), gw.read("SA10")) == (0, 0, 0)
        assert written(gw) == []
        # Its own type is written; a region not writable is still Bad_NotWritable first.
        assert await write(client, syvar, ua.DataValue(V(-5, T.Int16))) == 0
        assert await write(client, door, ua.DataValue(V(True, T.Boolean))) == 0
        assert await write(client, ua.NodeId("SK2", ns),
                           ua.DataValue(V(2.0, T.Double))) == Bad.BadNotWritable
        # A node that does not exist (asyncua's answer was Bad_UserAccessDenied).
        for missing in (ua.NodeId("SYVAR999999", ns), ua.NodeId("SYVAR007", ns),
                        ua.NodeId("nothing", 7)):
            assert await write(client, missing, ua.DataValue(
                V(1, T.Int16))) == Bad.BadNodeIdUnknown, missing
        assert written(gw) == [("SYVAR7", -5), ("SA10", 1)]
        # docs/opcua.md's recipe: asyncua's write_value, which sends a SourceTimestamp.
        await client.get_node(syvar).write_value(V(9, T.Int16))
        assert await write(client, syvar, ua.DataValue(
            V(11, T.Int16), ServerTimestamp=datetime(2000, 1, 1, tzinfo=UTC))) == 0
        assert written(gw)[2:] == [("SYVAR7", 9), ("SYVAR7", 11)]


async def test_a_write_of_a_view_no_one_may_write_is_bad_not_writable() -> None:
    """A process's state, the PLC's, or any other attribute than a Value: asyncua answered
    Bad_UserAccessDenied, as if another user could, beside Bad_NotWritable for an image
    variable of the same AccessLevel (a dashboard builder's try)."""
    async with gateway(**{"opcua.writable": ["sa_bits"]}) as gw, \
            Client(gw.opcua_endpoint) as client:
        ns = await client.get_namespace_index(IMAGE)
        for key in ("Process 1.State", "PLC.State", "SK5"):
            node = ua.NodeId(key, ns)
            assert (await client.get_node(node).read_attribute(
                ua.AttributeIds.AccessLevel)).Value.Value == 1, key
            assert await write(client, node, ua.DataValue(V("RUN", T.String))) == (
                Bad.BadNotWritable), key
        item = ua.WriteValue(NodeId=ua.NodeId("SA12", ns),
                             AttributeId=ua.AttributeIds.DisplayName,
                             Value=ua.DataValue(V(ua.LocalizedText("x"))))
        assert [r.value for r in await client.uaclient.write(
            ua.WriteParameters(NodesToWrite=[item]))] == [Bad.BadNotWritable]
        assert written(gw) == []


@pytest.fixture
async def with_users() -> AsyncIterator[Gateway]:
    digest = hashlib.pbkdf2_hmac("sha256", b"s3cret", b"pepper", 1000).hex()
    async with gateway(**{"opcua.writable": ["syvars"], "opcua.users": {
            "alice": f"pbkdf2_sha256$1000$pepper${digest}"}}) as gw:
        yield gw


async def test_with_users_set_an_anonymous_session_reads_a_user_access_level_of_read_only(
        with_users: Gateway) -> None:
    """UserAccessLevel says what this session may do: CurrentRead alone for an anonymous
    session while [opcua.users] is set, as its writes are refused; a user's says it writes."""
    gw = with_users
    levels = (ua.AttributeIds.AccessLevel, ua.AttributeIds.UserAccessLevel)
    async with Client(gw.opcua_endpoint) as anonymous:
        node = anonymous.get_node(ua.NodeId("SYVAR7", await anonymous.get_namespace_index(IMAGE)))
        assert [(await node.read_attribute(a)).Value.Value for a in levels] == [3, 1]
        assert await write(anonymous, node.nodeid, ua.DataValue(V(5, T.Int16))) == (
            Bad.BadUserAccessDenied)
    alice = Client(gw.opcua_endpoint)
    alice.set_user("alice")
    alice.set_password("s3cret")
    async with alice:
        node = alice.get_node(ua.NodeId("SYVAR7", await alice.get_namespace_index(IMAGE)))
        assert [(await node.read_attribute(a)).Value.Value for a in levels] == [3, 3]
        assert await write(alice, node.nodeid, ua.DataValue(V(5, T.Int16))) == 0
    assert written(gw) == [("SYVAR7", 5)]


class _Quiet:
    def datachange_notification(self, *args: Any) -> None:
        pass


async def test_one_client_at_its_subscription_limit_leaves_a_second_its_subscription() -> None:
    """opcua.max_subscriptions_per_session and max_monitored_items_per_subscription hold one
    session to its share, so another client still subscribes; max_sessions caps the
    sessions, and a session's timeout is revised down to max_session_timeout_s.  The limits
    are in the Server object's ServerCapabilities."""
    async with gateway(**{"opcua.max_subscriptions_per_session": 2,
                          "opcua.max_monitored_items_per_subscription": 3,
                          "opcua.max_sessions": 2,
                          "opcua.max_session_timeout_s": 30}) as gw:
        greedy = Client(gw.opcua_endpoint)
        greedy.session_timeout = 3_600_000  # asks an hour
        async with greedy:
            assert greedy.session_timeout == 30_000
            for _ in range(2):
                await greedy.create_subscription(100, _Quiet())
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await greedy.create_subscription(100, _Quiet())
            assert refused.value.code == Bad.BadTooManySubscriptions
            async with Client(gw.opcua_endpoint) as newcomer:
                subscription = await newcomer.create_subscription(100, _Quiet())
                ns = await newcomer.get_namespace_index(IMAGE)
                nodes = [newcomer.get_node(ua.NodeId(f"SA{i}", ns)) for i in range(4)]
                handles = await subscription.subscribe_data_change(nodes)
                assert [isinstance(h, int) for h in handles] == [True, True, True, False]
                assert handles[3] == ua.StatusCode(Bad.BadTooManyMonitoredItems)
                with pytest.raises(ua.UaStatusCodeError) as full:
                    await subscription.subscribe_data_change(nodes[3])
                assert full.value.code == Bad.BadTooManyMonitoredItems
                capabilities = newcomer.get_node(ua.ObjectIds.Server_ServerCapabilities)
                read = {name: await (await capabilities.get_child(f"0:{name}")).read_value()
                        for name in ("MaxSessions", "MaxSubscriptionsPerSession",
                                     "MaxMonitoredItemsPerSubscription")}
                assert read == {"MaxSessions": 2, "MaxSubscriptionsPerSession": 2,
                                "MaxMonitoredItemsPerSubscription": 3}
                with pytest.raises(ua.UaStatusCodeError) as many:
                    async with Client(gw.opcua_endpoint):
                        pass
                assert many.value.code == Bad.BadTooManySessions


async def test_sessions_never_activated_do_not_hold_the_session_limit() -> None:
    """A client may send CreateSession again and again on one connection and never activate
    one: asyncua forgets all but the last (none is closed), and max_sessions, counting them,
    refused every other client for good.  A session not activated within its timeout is
    closed (OPC 10000-4 5.6.2), so the limit comes back."""
    async with gateway(**{"opcua.max_sessions": 3,
                          "opcua.max_session_timeout_s": 5}) as gw:
        hostile = Client(gw.opcua_endpoint)
        hostile.session_timeout = 5_000
        await hostile.connect_socket()
        try:
            await hostile.send_hello()
            await hostile.open_secure_channel()
            for _ in range(3):
                await hostile.create_session()  # never activated
            with pytest.raises(ua.UaStatusCodeError) as full:
                await hostile.create_session()
            assert full.value.code == Bad.BadTooManySessions
            async with asyncio.timeout(30):
                while True:  # until the sessions not activated are closed (5 s)
                    try:
                        async with Client(gw.opcua_endpoint) as newcomer:
                            assert await newcomer.get_namespace_index(IMAGE) > 0
                            break
                    except ua.UaStatusCodeError as exc:
                        assert exc.code == Bad.BadTooManySessions
                        await asyncio.sleep(0.5)  # (asks again: the expiry is a timeout)
        finally:
            hostile.disconnect_socket()


async def test_a_session_closed_keeping_its_subscriptions_takes_them_along() -> None:
    """CloseSession with DeleteSubscriptions false left its subscriptions to no session:
    no limit counted them, and a client closing sessions so filled the server's 1,000 for
    good (a hostile try).  They go with the session."""
    async with gateway(**{"opcua.writable": ["syvars"]}) as gw:
        adapter = gw.adapters["opcua"]
        leaver = Client(gw.opcua_endpoint)
        await leaver.connect()
        try:
            for _ in range(3):
                await leaver.create_subscription(100, _Quiet())
            await leaver.uaclient.close_session(False)
        finally:
            leaver.disconnect_socket()
        async with Client(gw.opcua_endpoint) as probe:
            ns = await probe.get_namespace_index(IMAGE)
            # Its write goes through the gateway after the counts told before it.
            await probe.get_node(ua.NodeId("SYVAR7", ns)).write_value(V(1, T.Int16))
            assert (adapter.sessions, adapter.subscriptions) == (1, 0)


async def test_a_create_session_refused_leaves_nothing_and_an_activate_after_it_is_refused(
        capfd: pytest.CaptureFixture[str]) -> None:
    """A CreateSession refused for max_sessions left its session registered (0.5 kB each,
    for ever), and an ActivateSession after it on that connection raised inside asyncua
    (a traceback in the log, Bad_InternalError)."""
    async with gateway(**{"opcua.max_sessions": 1}) as gw, Client(gw.opcua_endpoint):
        hostile = Client(gw.opcua_endpoint)
        await hostile.connect_socket()
        try:
            await hostile.send_hello()
            await hostile.open_secure_channel()
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await hostile.create_session()
            assert refused.value.code == Bad.BadTooManySessions
            with pytest.raises(ua.UaStatusCodeError) as activate:
                await hostile.activate_session()
            assert activate.value.code != Bad.BadInternalError
        finally:
            hostile.disconnect_socket()
    assert "Traceback" not in capfd.readouterr().err


async def test_an_anonymous_session_takes_no_other_sessions_subscription() -> None:
    """TransferSubscriptions: asyncua moved any session's subscription to any other, past
    the taker's max_subscriptions_per_session (one session gathered 64), and an anonymous
    client took another's (a hostile try).  Only a session of the same named user may."""
    async with gateway() as gw, Client(gw.opcua_endpoint) as owner, \
            Client(gw.opcua_endpoint) as taker:
        subscription = await owner.create_subscription(100, _Quiet())
        results = await taker.uaclient.transfer_subscriptions(ua.TransferSubscriptionsParameters(
            SubscriptionIds=[subscription.subscription_id], SendInitialValues=False))
        assert [r.StatusCode.value for r in results] == [Bad.BadUserAccessDenied]


async def test_condition_refresh_of_another_sessions_subscription_is_refused() -> None:
    """ConditionRefresh and ConditionRefresh2 take a subscription of the calling session
    (OPC 10000-9 5.5.7): another client's is Bad_SubscriptionIdInvalid, as one that does not
    exist (before, any client had another's alarms sent to it again).  Its owner refreshes it."""
    async with gateway() as gw, Client(gw.opcua_endpoint) as owner, \
            Client(gw.opcua_endpoint) as other:
        subscription = await owner.create_subscription(100, _Quiet())
        item = await subscription.subscribe_events(owner.nodes.server)
        sid = V(subscription.subscription_id, T.UInt32)
        condition_type = ua.NodeId(ua.ObjectIds.ConditionType)
        refresh, refresh2 = (ua.ObjectIds.ConditionType_ConditionRefresh,
                             ua.ObjectIds.ConditionType_ConditionRefresh2)
        for method, args in ((refresh, [sid]), (refresh2, [sid, V(item, T.UInt32)])):
            assert (await call(other, condition_type, method, args)).StatusCode.value == (
                Bad.BadSubscriptionIdInvalid), method
            assert (await call(owner, condition_type, method, args)).StatusCode.is_good(), method
        # One Call of several methods: each answered in its place.
        requests = [ua.CallMethodRequest(ObjectId=condition_type, MethodId=ua.NodeId(refresh),
                                         InputArguments=[sid]),
                    ua.CallMethodRequest(ObjectId=condition_type, MethodId=ua.NodeId(refresh),
                                         InputArguments=[V(999999, T.UInt32)])]
        results = await other.uaclient.call(requests)
        assert [r.StatusCode.value for r in results] == [Bad.BadSubscriptionIdInvalid] * 2
        results = await owner.uaclient.call(requests)
        assert [r.StatusCode.is_good() for r in results] == [True, False]


async def test_a_flood_of_refused_requests_is_a_few_lines_of_the_servers_log(
        capfd: pytest.CaptureFixture[str]) -> None:
    """asyncua logs an ERROR for every request it refuses: 40 refused CreateSubscriptions
    gave 40 lines of the server's log (ncgate run's stderr).  Now a few, and the server goes on
    answering."""
    async with gateway(**{"opcua.max_subscriptions_per_session": 1}) as gw, \
            Client(gw.opcua_endpoint) as client:
        await client.create_subscription(100, _Quiet())
        for _ in range(40):
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await client.create_subscription(100, _Quiet())
            assert refused.value.code == Bad.BadTooManySubscriptions
        assert await client.nodes.server_state.read_value() == ua.ServerState.Running
    lines = [line for line in capfd.readouterr().err.splitlines()
             if "BadTooManySubscriptions" in line]
    assert 2 <= len(lines) <= 6, lines  # a few lines, and the count of the rest
    said = 0
    for line in lines:  # every refusal is counted once: a line, or in a count
        held = re.search(r"(\d+) more like: |\(and (\d+) more like it\)", line)
        said += 1 if held is None or held[2] else int(held[1])
        said += int(held[2]) if held is not None and held[2] else 0
    assert said == 40, lines


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux's SCHED_IDLE")
async def test_the_server_process_runs_on_what_the_gateway_leaves() -> None:
    """At nice 10 the server, busy with ten dashboards, delayed a poller's answers as much
    as a bare server's (p99 2.4x quiet in bench/storm.py's OPC UA phase): it takes the
    cores only when nothing else wants them (SCHED_IDLE), every thread of it -- once it
    serves: it starts at the gateway's own priority (at nice 10 beside a busy suite it did
    not start within 60 s)."""
    async with gateway() as gw:
        process = gw.adapters["opcua"]._process
        assert process is not None
        tasks = os.listdir(f"/proc/{process.pid}/task")
        assert tasks and all(os.sched_getscheduler(int(t)) == os.SCHED_IDLE for t in tasks)
        assert os.getpriority(os.PRIO_PROCESS, process.pid) == os.getpriority(
            os.PRIO_PROCESS, 0)
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the gateway's own: untouched
