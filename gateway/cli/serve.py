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
from ncgate.interpreter.trace import Event

log = logging.getLogger("ncgate")


def describe(event: Event) -> str | None:
    """A log line for the events worth a line; None for the rest."""
    kind, proc = event["event"], event["proc"]
    where = f" at {event['prog']}:{event['line']}" if event.get("prog") and "line" in event \
        else ""
    if kind == "start":
        return f"P{proc} starts {event['prog']} (by {event['by']})"
    if kind == "end":
        return f"P{proc} ends ({event['how']}){where}"
    if kind == "alarm":
        return f"P{proc} ALARM {event['code']}{where}: {event['message']}"
    if kind in ("deadlock", "stall"):
        return str(event.get("message", kind))
    if kind == "hazard":
        return f"P{proc} hazard{where}: {event['message']}"
    return None


async def serve(config: Config, stop: asyncio.Event | None = None) -> None:
    stop = stop if stop is not None else asyncio.Event()
    loop = asyncio.get_running_loop()
    installed = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with suppress(NotImplementedError, RuntimeError):  # not on every platform or thread
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)

    def on_event(event: Event) -> None:
        line = describe(event)
        if line is not None:
            (log.warning if event["event"] in ("alarm", "deadlock", "stall", "hazard")
             else log.info)(line)

    try:
        async with Gateway(config, listeners=[on_event]) as gw:
            source = str(config.source) if config.source else "built-in default"
            log.info("ncgate running: config %s, %d processes, main %s (%s)", source,
                     config.nc.processes, config.nc.main,
                     "started" if config.nc.autostart else "waits for cycle start")
            if config.modbus.enabled:
                host, port = gw.modbus_address
                log.info("Modbus TCP on %s:%d, unit ids %s, at most %d clients", host, port,
                         ",".join(map(str, config.modbus.unit_ids)), config.modbus.max_clients)
            await stop.wait()
            log.info("stopping")
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
    log.info("stopped")
