"""The OPC UA server against what a client may send (docs/opcua.md), driven by asyncua's client
(it needs no node): a method called with the wrong arguments."""

from __future__ import annotations

from typing import Any

import pytest
from asyncua import Client, ua

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from .conftest import NCGATE

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
