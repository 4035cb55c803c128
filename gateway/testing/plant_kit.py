"""The test kit's plant helper (docs/testing.md, docs/plant.md): faults and model states for
a test that drives the cell as a PLC would (``virtual_plc``) or from Python.

    async def test_the_plc_sees_a_clamp_that_never_closes(ncgate_gateway, virtual_plc, plant):
        await plant.fault("clamp", "never")
        await virtual_plc.set("SA20", 1)
        await plant.wait_state("clamp", "retracted")
        ...
        await plant.clear()

Every fault goes in through ``Gateway.apply`` as any input does (traced ``fault``, source
``api``).
"""

from __future__ import annotations

import asyncio
from typing import Any

from ncgate.gateway.app import Gateway
from ncgate.gateway.errors import GatewayError, WaitIdleTimeout
from ncgate.inputs import API, Source


class PlantKit:
    """Faults and model states of one gateway's plant."""

    def __init__(self, gw: Gateway, source: Source = API) -> None:
        self.gw = gw
        self.source = source

    async def fault(self, target: str, kind: str, *, for_s: float | None = None,
                    **params: Any) -> None:
        """Inject a fault: ``await plant.fault("clamp", "never")``, ``await
        plant.fault("SA30", "stuck", value=0, for_s=2)``."""
        self.gw.fault(target, kind, for_s=for_s, source=self.source, **params)

    async def clear(self, target: str | None = None) -> None:
        """Clear the target's faults (None: every one)."""
        self.gw.clear_fault(target, self.source)

    def state(self, model: str) -> dict[str, Any]:
        """The model's status: ``state``, ``since``, ``detail``, ``fault``, ``reads``,
        ``writes`` (as ``/api/status`` has it)."""
        for entry in self.gw.plant.status()["models"]:
            if entry["name"] == model:
                return dict(entry)
        known = ", ".join(self.gw.plant.models) or "none"
        raise KeyError(f"no plant model {model!r} (the config has: {known})")

    def faults(self) -> list[dict[str, Any]]:
        """The faults in force."""
        return list(self.gw.plant.status()["faults"])

    async def wait_state(self, model: str, state: str, timeout_s: float = 10.0) -> None:
        """Until the model is in ``state`` ("extended", "at speed", ...); WaitIdleTimeout
        naming what it is doing instead.  Woken by every write of the image and every change
        of a model's state (one that writes nothing too), no polling.  KeyError for a model
        the config has not, ValueError for a state its kind never is, GatewayError once the
        gateway is closed."""
        if not self.gw.running:
            raise GatewayError("the gateway is not running: wait_state waits on a running "
                               "one (use 'async with Gateway(...)')")
        self.state(model)  # the name, or KeyError now
        kind = self.gw.plant.models[model]
        if state not in kind.states:
            raise ValueError(f"a {kind.kind} is never {state!r}: it is "
                             f"{', '.join(repr(s) for s in kind.states)}")
        changed = asyncio.Event()
        unsubscribe = self.gw.image.subscribe(lambda changes, writer: changed.set())
        self.gw.plant.state_listeners.append(changed.set)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        try:
            while self.state(model)["state"] != state:
                remaining = deadline - loop.time()
                if remaining <= 0:
                    raise WaitIdleTimeout(f"plant model {model} not {state!r} in "
                                          f"{timeout_s:g} s: {self.state(model)['detail']}")
                changed.clear()
                try:
                    async with asyncio.timeout(remaining):
                        await changed.wait()
                except TimeoutError:
                    continue  # said above, with what it is doing
        finally:
            unsubscribe()
            self.gw.plant.state_listeners.remove(changed.set)
