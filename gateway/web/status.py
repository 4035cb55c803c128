"""What the console shows, as JSON-ready dicts: the processes with their why-records, the PLC
and its variables, the image with its last writers, the fieldbus peers (``GET /api/status``).

Built on the loop, on demand, from the cell's view (:attr:`ncgate.gateway.Gateway.view`: the
processes, the PLC status, the forces, the SND counts, the image and its writers, the plant),
and from the :class:`~ncgate.gateway.app.Gateway` for what only the console shows (the PLC's
variables, the commissioning controls, the adapters); no web library here (the HTTP side is
:mod:`ncgate.gateway.web.console`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import TYPE_CHECKING, Any

from ncgate import __version__
from ncgate.gateway.view import PlcView, ProcessView, plant_status
from ncgate.inputs import var_name
from ncgate.interpreter.settings import AXES
from ncgate.plc.image import FrozenImage
from ncgate.plc.st.logic import ProgramVar
from ncgate.plc.st.types import ArrayOf, EnumOf, FbOf, Type

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway

WATCH_LIMIT = 200  # ST variables the status shows (the first ones, in declaration order)


def status(gw: Gateway, image: bool = True) -> dict[str, Any]:
    """The whole status (``image=False``: without the image, for a light poll)."""
    engine = gw.engine
    view = gw.view
    out: dict[str, Any] = {
        "version": __version__,
        "session": gw.session,
        "t": round(engine.now, 6),
        "time_scale": gw.config.nc.time_scale,  # machine s per wall s: the page's clock runs
        "config": str(gw.config.source) if gw.config.source else "built-in default",
        "main": gw.config.nc.main,
        "dialect": gw.config.nc.dialect.value,
        "held": any(p.held for p in view.processes),
        # Why the cell stands, in the page's words (a breakpoint is no feed hold): the first
        # process's that stands, or None.
        "standing": next((p.standing for p in view.processes if p.standing is not None),
                         None),
        "lag_s": round(view.lag_s, 6),  # behind the clock (machine s): 0 while on time
        # The commissioning controls in force.
        "controls": {"breakpoints": [b.text for b in engine.breakpoints],
                     "optional_stop": engine.optional_stop, "block_skip": engine.block_skip,
                     "forced": len(view.forced)},
        "processes": [process_view(p) for p in view.processes],
        # The force list (the F marks of the image grid) and the I/O names of [symbols]
        # by the variable they name (the grid's names).
        "forced": {var_name(*key): value for key, value in view.forced},
        "symbols": symbols(gw),
        # Each I/O name's comment of [symbols] (or the CSV I/O list), by its variable.
        "symbol_comments": symbol_comments(gw),
        "record": str(gw.recorder.path) if gw.recorder is not None else None,
        "plc": plc(gw, view.plc),
        "plant": plant_status(view.plant) if view.plant is not None else None,
        "fieldbus": fieldbus(gw),
        "counters": {"events": gw.runtime.trace.seq, "sync_events": view.events},
        "web": {"read_only": gw.config.web.read_only,
                "token": gw.config.web.token is not None},
    }
    if image:
        out["image"] = image_status(view.image)
    return out


def process(gw: Gateway, number: int) -> dict[str, Any]:
    """Process ``number``'s lane, as the cell's view shows it now."""
    return process_view(gw.view.processes[number - 1])


def process_view(p: ProcessView) -> dict[str, Any]:
    """A process's lane: its status and why it waits, stands or is in alarm."""
    wait = None
    w = p.wait
    if w is not None:
        wait = {"kind": w.kind.name, "code": w.code, "target": w.target, "cond": w.cond,
                "value": w.value, "writer": w.writer, "since": round(w.since, 6),
                "reason": w.reason, "where": {"prog": w.where[0], "line": w.where[1],
                                              "n": w.where[2]}}
    alarm = None
    a = p.alarm
    if a is not None:
        alarm = {"code": a.label, "message": a.message,
                 "where": ({"prog": a.where[0], "line": a.where[1], "n": a.where[2]}
                           if a.where is not None else None)}
    return {"number": p.number, "state": p.state.name, "external": p.external,
            "program": p.program, "line": p.line, "n": p.n, "block": p.block,
            "held": p.held, "standing": p.standing, "blocks": p.blocks,
            "snd_sent": p.snd_sent,
            "single_block": p.single_block, "feed_override": p.feed_override,
            "rapid_override": p.rapid_override,
            # Where the axes are (the interpolator's position, mm) and the modal feed.
            "position": {axis: round(value, 4) for axis, value in zip(
                AXES[:3], p.position, strict=False)},
            "feed": p.feed, "moving": p.moving,
            "snd_received": p.snd_received, "wait": wait, "alarm": alarm}


def symbols(gw: Gateway) -> dict[str, str]:
    """The I/O names by the variable they name: ``{"SA10": "door_closed"}``."""
    runtime = gw.runtime
    return {str(runtime.var(name)): name for name in gw.config.symbols}


def symbol_comments(gw: Gateway) -> dict[str, str]:
    """The I/O names' comments by the variable they name: ``{"SYVAR3": "rpm / 10"}``."""
    runtime, comments = gw.runtime, gw.config.symbols.comments
    return {str(runtime.var(name)): comment for name, comment in comments.items() if comment}


def plc(gw: Gateway, status: PlcView | None) -> dict[str, Any] | None:
    """The PLC logic's state and a watch of its programs' variables (None: no logic)."""
    if status is None:
        return None
    runtime = gw.plc
    variables: list[dict[str, Any]] = []
    for key, table in runtime.logic.programs.items():
        name = runtime.logic.display[key]
        for var in table.values():
            if len(variables) >= WATCH_LIMIT:
                break
            try:
                value = runtime.read(f"{name}.{var.display}")
            except KeyError:
                continue
            variables.append({"path": f"{name}.{var.display}", "type": str(var.type),
                              "value": plain(value, var.type, runtime.logic.fb_vars),
                              "retain": var.retain})
    return {"state": status.state, "scans": status.scans,
            "last_scan_us": status.last_scan_us, "max_scan_us": status.max_scan_us,
            "overruns": status.overruns, "last_lateness_us": status.last_lateness_us,
            "max_lateness_us": status.max_lateness_us, "fault": status.fault,
            "variables": variables}


def plain(value: Any, t: Type, fb_vars: dict[str, dict[str, ProgramVar]]) -> Any:
    """A PLC value as JSON has it, whatever its ST type: an array a list, a function block
    instance an object of its members (a TON's ``IN``, ``PT``, ``Q``, ``ET``; a user block's
    variables), a REAL that is not finite its name (JSON has no inf or NaN), an
    enumeration's value its name (``RUN``, not ``2``)."""
    if isinstance(t, EnumOf):
        return t.name_of(value)
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, list | tuple):
        element = t.element if isinstance(t, ArrayOf) else t
        return [plain(item, element, fb_vars) for item in value]
    if isinstance(t, FbOf) and not t.std and t.name in fb_vars:
        return {var.display: plain(getattr(value, f"v_{key}", None), var.type, fb_vars)
                for key, var in fb_vars[t.name].items()}
    if dataclasses.is_dataclass(value):  # a standard block: its IEC members, not its state
        return {f.name: plain(getattr(value, f.name), "", fb_vars)
                for f in dataclasses.fields(value) if not f.name.startswith("_")}
    slots = getattr(type(value), "__slots__", ())
    if hasattr(value, "_copy") and slots:  # a structure (the compiler's S_ class): its members
        return {name[2:]: plain(getattr(value, name), "", fb_vars) for name in slots}
    return str(value)  # nothing the compiler makes today; said rather than a 500


def fieldbus(gw: Gateway) -> dict[str, Any]:
    """Each registered adapter's status (ncgate.gateway.adapters), by its name; None for one
    that does not run.  The console itself has none."""
    from ncgate.gateway.adapters import ADAPTERS, plugin

    out: dict[str, Any] = {}
    for name in ADAPTERS:
        adapter = gw.adapters.get(name)
        if adapter is None:
            if name != "web":
                out[name] = None
            continue
        shown = plugin(name).status(adapter)
        if shown is not None:
            out[name] = shown
    return out


def image_status(image: FrozenImage) -> dict[str, Any]:
    """The SA packet as bits, the K bytes, the SYVARs, and who last wrote each (of the
    cell's view: :attr:`ncgate.gateway.view.CellView.image`)."""
    writers = image.writers()
    return {
        "sa": "".join(str((image.sa[i >> 3] >> (i & 7)) & 1) for i in range(image.sa_bits)),
        "k": list(image.k),
        "syvar": list(image.syvar),
        "writers": {area: {str(k): v for k, v in table.items()}
                    for area, table in writers.items()},
    }


# A byte of the SA packet as its eight bits, bit 0 first (the status's "sa" string).
_BITS = tuple("".join(str((byte >> bit) & 1) for bit in range(8)) for byte in range(256))


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


class LiveStatus:
    """The status as JSON parts (each top-level key; the image's ``sa``, ``k``, ``syvar`` and
    ``writers`` apart), for the console's streams: :meth:`parts` builds the small parts
    again and the image's only where the image changed -- a part that did not change is the
    same string as before, which a stream compares by identity.  (Building the whole status
    with its image 8 times a second took about 460 us each time in bench/storm.py's cell.)
    The image is the view's (:attr:`ncgate.gateway.view.CellView.image`): nothing of it is
    read while its version (the image's write counter) is the last one; after a write its
    values are compared with the last ones (a copy of 1 KB) and its writers built again."""

    def __init__(self, gw: Gateway) -> None:
        self.gw = gw
        self._image: dict[str, str] = {}
        self._seen: dict[str, bytes | tuple[int, ...]] = {}
        self._version: int | None = None  # the image's version the parts are of

    def close(self) -> None:
        pass  # (nothing subscribed: the view's image says its version)

    def parts(self) -> dict[str, str]:
        whole = status(self.gw, image=False)
        out = {name: _dumps(value) for name, value in whole.items()}
        image = self.gw.view.image  # (the view status() read: nothing ran in between)
        cached = self._image
        if image.version != self._version:
            self._version = image.version
            for name, now in (("sa", image.sa), ("k", image.k), ("syvar", image.syvar)):
                if self._seen.get(name) != now or name not in cached:
                    self._seen[name] = now
                    if name == "sa":
                        bits = "".join(_BITS[byte] for byte in now)[:image.sa_bits]
                        cached[name] = f'"{bits}"'
                    else:
                        cached[name] = _dumps(list(now))
            cached["writers"] = _dumps({area: {str(k): v for k, v in table.items()}
                                        for area, table in image.writers().items()})
        out.update({f"image.{name}": text for name, text in cached.items()})
        return out
