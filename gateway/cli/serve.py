"""``ncgate run``: the gateway until SIGINT or SIGTERM (spec 4.1).

It logs what happens -- the listening address, connections, program starts and ends, alarms,
deadlocks -- and on a signal closes every connection and returns, leaving no task behind.
"""

from __future__ import annotations

import asyncio
import logging
import signal
from contextlib import suppress

from ncgate.config import Config
from ncgate.gateway.app import Gateway
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event

log = logging.getLogger("ncgate")


def describe(event: Event) -> str | None:
    """A log line for the events worth a line; None for the rest."""
    proc, where = event.proc, event.where
    at = f" at {where[0]}:{where[1]}" if where is not None and where[0] else ""
    if isinstance(event, ev.Start):
        return f"P{proc} starts {event.prog} (by {event.by})"
    if isinstance(event, ev.End):
        return f"P{proc} ends ({event.how}){at}"
    if isinstance(event, ev.Alarm):
        who = f"P{proc}" if proc else "fieldbus"  # process 0: the PLC/fieldbus side
        return f"{who} ALARM {event.code.label}{at}: {event.message}"
    if isinstance(event, ev.Deadlock):
        return event.message
    if isinstance(event, ev.Stall):
        return "stall: " + "; ".join(f"P{b.proc} {b.prog}:{b.line} {b.reason}"
                                     for b in event.blocked)
    if isinstance(event, ev.Hazard):
        return f"P{proc} hazard{at}: {event.message}"
    return None


HAZARDS_LOGGED = 1000  # distinct blocks whose hazard the log shows (the trace has them all)


async def serve(config: Config, stop: asyncio.Event | None = None, cold: bool = False) -> None:
    stop = stop if stop is not None else asyncio.Event()
    loop = asyncio.get_running_loop()
    installed = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with suppress(NotImplementedError, RuntimeError):  # not on every platform or thread
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)

    hazards_logged: set[tuple[int, object]] = set()

    def on_event(event: Event) -> None:
        if isinstance(event, ev.Hazard):
            # A loop repeats its hazards every turn: the log names each block once, the
            # trace has every one.
            key = (event.proc, event.where)
            if key in hazards_logged or len(hazards_logged) >= HAZARDS_LOGGED:
                return
            hazards_logged.add(key)
        line = describe(event)
        if line is not None:
            (log.warning if isinstance(event, ev.Alarm | ev.Deadlock | ev.Stall | ev.Hazard)
             else log.info)(line)

    try:
        async with Gateway(config, listeners=[on_event], cold=cold) as gw:
            source = str(config.source) if config.source else "built-in default"
            log.info("ncgate running: config %s, %d processes, main %s (%s)", source,
                     config.nc.processes, config.nc.main,
                     "started" if config.nc.autostart else "waits for cycle start")
            server = gw.modbus_server
            if server is not None:
                units = ",".join(map(str, config.modbus.unit_ids))
                if server.address is not None:
                    log.info("Modbus TCP on %s:%d, unit ids %s, at most %d clients",
                             *server.address, units, config.modbus.max_clients)
                if server.tls_address is not None:
                    log.info("Modbus/TCP Security (TLS) on %s:%d, roles %s", *server.tls_address,
                             ", ".join(config.modbus.roles) or "none")
            await stop.wait()
            log.info("stopping")
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
    log.info("stopped")
