"""The plant: the machine around the cell, as a source of inputs (docs/plant.md).

Its models answer the PLC's outputs on the engine's clock -- the same clock as the NC and the
PLC scan, in ``sim`` and on the wall clock in ``run`` -- and every value they drive goes in
through the door as a :class:`~ncgate.inputs.Writes` from ``plant <name>``: it is checked,
traced and attributed like any input, and a force wins over it.  It is never recorded: a
replay runs the same plant from the same config, so it gives the same writes again.

Faults (:class:`~ncgate.inputs.Fault`, through the door as well) change a model's behaviour
(``never``, ``slow``), hold what every reader sees of a variable (``stuck``, ``wire_break``,
``chatter``: the image's hold layer, which a force overrides), or go to a fieldbus adapter
(``modbus``: ``exception``, ``delay``, ``no_reply``; ``canopen``: ``heartbeat_stop``,
``emcy``, ``pdo_stop``) through :attr:`Plant.fieldbus_listeners`.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ncgate.config.plant import (
    CANOPEN_FAULTS,
    MODBUS_FAULTS,
    MODEL_FAULTS,
    MODEL_KEYS,
    VARIABLE_FAULTS,
    fault_input,
)
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.plant.models import KINDS, Model
from ncgate.inputs import ClearFault, Fault, Source, SourceKind, Var, Writes
from ncgate.interpreter.engine.timers import Timer, grid_index
from ncgate.interpreter.settings import AXES
from ncgate.plc.image import ImageValueError, overlap, value_range

if TYPE_CHECKING:
    from ncgate.config.plant import PlantModelConfig
    from ncgate.gateway.wiring import Runtime
    from ncgate.plc.scan import PlcRuntime

log = logging.getLogger("ncgate")
# The share of the loop's time the plant's tick may take in run; past it the tick's period is
# stretched (x2 each time, up to MAX_STRETCH scans), never the switch points.
BUDGET = 0.2
MAX_STRETCH = 64
FIELDBUSES = frozenset({"modbus", "canopen"})  # the targets of the fieldbus faults
# And one tick holds the loop this long at most, and no longer than the engine's turn has
# left (a poller waits no longer behind it); the models it did not get to are written first
# at the next tick.
TICK_S = 0.0001
# Outputs that carry a number, not a bit: they need a word (a SYVAR, an SK/SA .IN word).
_NUMBER_OUTPUTS = frozenset({("cylinder", "position"), ("motor", "speed"), ("lag", "actual")})
# The outputs that need a word: the numbers, and a generator's output unless it is a square
_WORD_OUTPUTS = _NUMBER_OUTPUTS | {("generator", "output")}


@dataclass(eq=False)
class ActiveFault:
    """A fault in force: what it targets, its kind and parameters, who injected it."""

    target: str
    kind: str
    params: dict[str, Any]
    who: str
    since: float
    variables: tuple[Var, ...] = ()  # what a variable fault holds
    model: Model | None = None
    timers: list[Timer] = field(default_factory=list)  # its for_s, its chatter

    @property
    def group(self) -> str:
        """Faults of one group on one target replace each other."""
        if self.kind in MODEL_FAULTS:
            return "behaviour"
        if self.kind in VARIABLE_FAULTS:
            return "value"
        return self.kind


class Plant:
    """The models of ``[[plant.model]]`` and the faults in force, on one runtime."""

    def __init__(self, runtime: Runtime, apply: Callable[[Any], None], *,
                 closed: bool) -> None:
        """``apply``: the door's (the input goes in as any input does)."""
        self.runtime = runtime
        self._apply = apply
        self.closed = closed
        config = runtime.config.plant
        self.scan_s = config.scan_ms / 1000.0
        self.models: dict[str, Model] = {}
        self.variables: dict[str, dict[str, Var]] = {}  # model -> key -> variable
        self._drives: dict[tuple[str, int, str], tuple[Model, str]] = {}
        self._timers: dict[str, Timer] = {}
        self._written: dict[str, dict[str, int]] = {}
        self._sources: dict[str, Source] = {}
        self.faults: list[ActiveFault] = []
        # Adapters hear the fieldbus faults in force (the Modbus server, the CANopen node).
        self.fieldbus_listeners: list[Callable[[list[ActiveFault]], None]] = []
        # The fieldbuses whose faults act here, and who serves them: a fieldbus fault of
        # another is said, as it is injected, to have no effect -- the same file could pass
        # in `run` and fail in `sim` with no word why.  None: say nothing (a replay: the
        # record holds what the fault did).  The gateway sets them before any fault comes.
        self.served: frozenset[str] | None = frozenset()
        self.server = "sim"
        self._nc_change = 0.0
        self._sampling: dict[Model, None] = {}  # what the tick writes (in order)
        self._asleep: list[Model] = []  # free runners stopped while a closed run stands still
        self._tick: Timer | None = None
        self._next_in_turn = 0  # the sampled model a tick starts with (run: round robin)
        self.stretch = 1  # the tick's period in scans (run: the budget's)
        # What the wall clock's budget decided at a tick (a tick cut short after n models, the
        # period stretched to n scans), told as it is decided (run --record), and the decisions
        # a replay takes from its record instead of the replaying machine's budget (tick time,
        # rounded to the microsecond -> n): the ticks and their writes are then the session's.
        self.on_decision: Callable[[str, float, int], None] | None = None
        self.decided: dict[str, dict[float, int]] | None = None
        self.logic: PlcRuntime | None = None  # the plant's ST logic ([plant] logic)
        self.stretched = 0  # how often the budget stretched it
        # Told when a model's state changes (also one that writes nothing: a cylinder
        # stopped mid-stroke by a fault): the pytest kit's wait_state.
        self.state_listeners: list[Callable[[], None]] = []
        for i, model_config in enumerate(config.model):
            self._build(model_config, f"plant.model[{i}]")
        runtime.engine.state_listeners.append(self._on_state)
        runtime.engine.sync.explain = self.explain

    # -- building ---------------------------------------------------------------------------

    def _build(self, config: PlantModelConfig, key: str) -> None:
        from ncgate.config import ConfigError

        where = self.runtime.config.source or "<config>"
        variables: dict[str, Var] = {}
        for name, (role, _, _) in MODEL_KEYS[config.kind].items():
            text = config.keys.get(name)
            if role not in ("in", "out") or text is None:
                continue
            try:
                var = self.runtime.var(text)
                self.runtime.image.read(*var.address)
            except (InputRefused, IndexError) as exc:
                raise ConfigError(f"{where}: {key}.{name}: {exc}") from None
            if role == "out" and (config.kind, name) in _WORD_OUTPUTS and not (
                    config.kind == "generator" and config.keys.get("shape", "square")
                    == "square"):
                low, high = value_range(var.area, var.view)
                if high < 1000:
                    raise ConfigError(f"{where}: {key}.{name}: {var} holds {low}..{high}: a "
                                      "number needs a word (SYVARn, SKn.IN)")
            if role == "out":
                drives = self._drives.get(var.address)
                if drives is not None:
                    raise ConfigError(f"{where}: {key}.{name}: {var} is driven by "
                                      f"{drives[0].name}.{drives[1]} already")
            variables[name] = var
        if config.kind == "switch":
            process = int(str(config.keys["axis"]).split(".")[0][1:])
            if process not in self.runtime.engine.processes:
                raise ConfigError(f"{where}: {key}.axis: no process {process}")
        model = KINDS[config.kind](config, _ModelHost(self, variables), self.scan_s)
        model.on_state = self._state_changed
        self.models[config.name] = model
        self.variables[config.name] = variables
        for name, var in variables.items():
            if name in model.outputs_keys:
                self._drives[var.address] = (model, name)
        self._written[config.name] = {}
        self._sources[config.name] = Source(SourceKind.PLANT, config.name)

    def start(self) -> None:
        """Each model from its state at rest, its outputs written, its inputs watched."""
        now = self.runtime.engine.now
        for model in self.models.values():
            self._watch(model)
            self._after(model, model.start(now), force=True)

    def close(self) -> None:
        for timer in self._timers.values():
            timer.cancel()
        self._timers.clear()
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None
        for fault in self.faults:
            for timer in fault.timers:
                timer.cancel()

    # -- running ----------------------------------------------------------------------------

    def _watch(self, model: Model) -> None:
        image = self.runtime.image
        for name in model.inputs:
            var = self.variables[model.name].get(name)
            if var is None:
                continue
            self._arm(model, var, image.read(*var.address))

    def _arm(self, model: Model, var: Var, value: int) -> None:
        """Hear the next change of ``var`` (the image's index of waits: no polling)."""
        image = self.runtime.image

        def changed() -> None:
            now_value = image.read(*var.address)
            self._arm(model, var, now_value)
            # After the write, at the write's time: the model acts as an input of its own.
            # Its time is the write's, not the clock's when the loop gets round to it, so a
            # replay (which applies the write at its recorded time) gives the same times.
            engine = self.runtime.engine
            engine.call_at(engine.now, functools.partial(self._command, model, engine.now))

        handle = image.wait(*var.address, lambda v: v != value, changed)
        if handle is None:  # changed already
            changed()

    def _command(self, model: Model, t: float) -> None:
        self._after(model, model.command(t), t=t)

    def _advance(self, model: Model, t: float) -> None:
        self._timers.pop(model.name, None)
        nxt = model.advance(t)
        if nxt is not None and nxt <= t:  # a time that would never come: a bug
            log.error("plant %s asked to be called again at %.9f s, now: next scan instead",
                      model.name, nxt)
            nxt = t + self.scan_s
        if nxt is not None and model.free_running and self._idle():
            nxt = None  # a closed run that stands still: let it end (a stall, or idle)
            self._asleep.append(model)
        self._after(model, nxt, t=t)

    @property
    def moving(self) -> bool:
        """A model is on its way somewhere (a stroke, a ramp, a relay's delay): with
        ``--until``, a simulation whose processes are idle runs on while it is (free-running
        generators and switches do not count: they would never end it)."""
        return any(not self.models[name].free_running for name in self._timers) or any(
            not m.free_running for m in self._sampling)

    def _idle(self) -> bool:
        engine = self.runtime.engine
        if not self.closed:
            return False
        stall_s = self.runtime.config.nc.stall_s
        return (engine.all_idle or engine.stalled) and engine.now - self._nc_change >= stall_s

    def _on_state(self, process: object, old: object) -> None:
        self._nc_change = self.runtime.engine.now
        # A free runner that slept while the cell stood still wakes with it.
        if self._asleep:
            asleep, self._asleep = self._asleep, []
            for model in asleep:
                self._after(model, model.command(self._nc_change), t=self._nc_change)

    def _after(self, model: Model, nxt: float | None, force: bool = False,
               t: float | None = None) -> None:
        """Write what ``model`` drives at ``t`` (now), call it again at ``nxt``, and sample
        it on the tick while it moves."""
        self._write(model, force, t)
        old = self._timers.pop(model.name, None)
        if old is not None:
            old.cancel()
        if nxt is not None:
            engine = self.runtime.engine
            self._timers[model.name] = engine.call_at(
                nxt, functools.partial(self._advance, model, nxt))
        if model.sampled:
            self._sampling[model] = None
            now = self.runtime.engine.now if t is None else t
            if self._tick is None:
                self._arm_tick(now)
            elif self._tick.time > self._next_tick(now):  # (the ticks skipped a quiet tail)
                self._tick.cancel()
                self._arm_tick(now)
        else:
            self._sampling.pop(model, None)

    # -- the tick: what moves continuously, sampled -----------------------------------------

    def _next_tick(self, after: float, quiet: float | None = None) -> float:
        """The next tick on the scan grid after ``after`` (every scan_ms from 0, times the
        stretch the budget asks for in run), or the first at or after ``quiet``, when every
        model sampled writes nothing new before then (Model.quiet_until)."""
        period = self.scan_s * self.stretch
        k = grid_index(after, period, math.floor) + 1
        if quiet is not None and quiet > k * period:
            k = grid_index(quiet, period, math.ceil)
        return k * period

    def _arm_tick(self, after: float, quiet: float | None = None) -> None:
        """Arm the next tick (:meth:`_next_tick`).  It is *early*: it samples before any other
        timer of its instant (a PLC scan, a model's switch point) reads or writes, whenever it
        was armed -- so a tick armed past a quiet tail stands where a tick of every period
        would, and a scan of the tick's instant reads what it sampled."""
        t = self._next_tick(after, quiet)
        self._tick = self.runtime.engine.call_at(t, functools.partial(self._on_tick, t),
                                                 early=True)

    def _on_tick(self, t: float) -> None:
        self._tick = None
        started = time.perf_counter()
        models = list(self._sampling)
        if not self.closed and self._next_in_turn and models:
            # On the wall clock a tick holds the loop TICK_S at most: the models it did not
            # get to come first at the next one (round robin), so none is left behind.  (The
            # models it was due to start with may all have come to rest since: none left.)
            start = self._next_in_turn % len(models)
            models = models[start:] + models[:start]
        self._next_in_turn = 0
        decided = self.decided
        over = None if self.closed or decided is not None else self.runtime.engine.turn_over
        cut = None if decided is None else decided["cut"].get(round(t, 6))
        for done, model in enumerate(models):
            if done == cut or (over is not None and done and (
                    time.perf_counter() - started > TICK_S or over())):
                self._next_in_turn = list(self._sampling).index(model)
                if over is not None and self.on_decision is not None:
                    self.on_decision("cut", t, done)
                break
            if model.free_running and self._idle():
                self._sampling.pop(model, None)
                self._asleep.append(model)  # until the cell moves again
                continue
            self._write(model, t=t)
            if not model.sampled:
                self._sampling.pop(model, None)
        if over is not None:  # the wall clock's budget: on the virtual clock a tick takes
            stretch = self.stretch  # what it takes, and a replay stretches as its record says
            self._budget(time.perf_counter() - started)
            if self.stretch != stretch and self.on_decision is not None:
                self.on_decision("stretch", t, self.stretch)
        elif decided is not None:
            self.stretch = decided["stretch"].get(round(t, 6), self.stretch)
        if self._sampling:
            # From its own time, also when it came late: the ticks armed are the ones a
            # replay arms (armed from the wall clock's now, a late tick came at other times
            # than the replay's, which diverged; docs/decisions.md).  Past the ticks that
            # would write nothing (a lag's settling tail), when every model was written.
            quiet = None if self._next_in_turn else min(
                model.quiet_until(t, self._written[model.name]) for model in self._sampling)
            self._arm_tick(t, quiet)

    def _budget(self, spent: float) -> None:
        """On the wall clock the tick takes at most BUDGET of the loop's time: a tick that
        took more stretches the sampling period (2x, 4x, ... up to MAX_STRETCH), one that
        took less than a quarter of it shrinks it again.  Switch points stay exact; only how
        often a moving value is written changes (``plant.stretch`` in the status)."""
        period = self.scan_s * self.stretch
        if spent > BUDGET * period and self.stretch < MAX_STRETCH:
            self.stretch *= 2
            self.stretched += 1
        elif spent < BUDGET * period / 4 and self.stretch > 1:
            self.stretch //= 2

    def _write(self, model: Model, force: bool = False, t: float | None = None,
               shown: bool = False) -> None:
        """Write what ``model`` drives at ``t`` (now) that it has not written yet (``force``:
        all of it; ``shown``: what the image does not show -- after a hold was released, the
        held value stays until written, and every output written again put each model's
        every output, unchanged, in the trace at each clear)."""
        variables = self.variables[model.name]
        written = self._written[model.name]
        image = self.runtime.image
        read, forced = image.read, image.forced
        changes = []
        now = self.runtime.engine.now if t is None else t
        for key, value in model.outputs(now).items():
            var = variables.get(key)
            if var is None or (read(*var.address) == value if shown else
                               not force and written.get(key) == value):
                continue
            if shown and forced and any(overlap(f, var.address) for f in forced):
                continue  # a force shows its value, whatever is written: only a "forced"
                # event of every clear (a hostile try)
            changes.append((var, value))
            written[key] = value
        if not changes:
            return
        try:
            self._apply(Writes(tuple(changes), self._sources[model.name]))
        except InputRefused as exc:
            self.runtime.engine.note_hazard(0, f"plant {model.name}: {exc}")

    # -- faults ----------------------------------------------------------------------------------

    def check(self, item: Fault) -> ActiveFault:
        """The fault ``item`` asks for, resolved; InputRefused (nothing applied) otherwise."""
        target, kind = item.target, item.kind
        if not isinstance(target, str) or not target.strip():
            raise InputRefused(Reason.BAD_VALUE, f"a fault names its target, not {target!r}")
        raw = dict(item.params) if isinstance(item.params, tuple | list) else None
        if raw is None or not all(isinstance(k, str) for k in raw):
            raise InputRefused(Reason.BAD_VALUE, "a fault's parameters are (name, value) pairs")
        params = dict(fault_input(kind, raw, item.for_s,
                                  lambda message: InputRefused(Reason.BAD_VALUE, message)))
        fault = ActiveFault(target.strip(), kind, params, str(item.source),
                            self.runtime.engine.now)
        name = fault.target
        if name.lower() in FIELDBUSES:
            fault.target = name.lower()
            allowed = MODBUS_FAULTS if fault.target == "modbus" else CANOPEN_FAULTS
            if kind not in allowed:
                raise InputRefused(Reason.BAD_VALUE, f"{fault.target} takes "
                                   f"{', '.join(sorted(allowed))}, not {kind}")
            return fault
        if kind in MODBUS_FAULTS | CANOPEN_FAULTS:
            raise InputRefused(Reason.BAD_VALUE, f"a {kind} fault is a fieldbus's: target "
                               f"{'modbus' if kind in MODBUS_FAULTS else 'canopen'}")
        model_name, _, output = name.partition(".")
        model = self.models.get(model_name)
        if model is not None and not output:
            fault.model = model
            if kind in VARIABLE_FAULTS:
                fault.variables = tuple(var for key, var in self.variables[model_name].items()
                                        if key in model.outputs_keys)
        elif model is not None:
            if kind not in VARIABLE_FAULTS:
                raise InputRefused(Reason.BAD_VALUE, f"{name}: an output takes "
                                   f"{', '.join(sorted(VARIABLE_FAULTS))}; {kind} is the "
                                   f"model's ({model_name})")
            var = self.variables[model_name].get(output)
            if var is None or output not in model.outputs_keys:
                outs = [k for k in model.outputs_keys if k in self.variables[model_name]]
                raise InputRefused(Reason.UNKNOWN_VARIABLE, f"{name}: {model_name} drives "
                                   f"{', '.join(outs)}")
            fault.variables = (var,)
        else:
            if kind in MODEL_FAULTS:
                known = ", ".join(self.models) or "none configured"
                raise InputRefused(Reason.UNKNOWN_VARIABLE, f"{name}: a {kind} fault is a "
                                   f"plant model's ([[plant.model]]: {known})")
            try:
                var = self.runtime.var(name)
                self.runtime.image.read(*var.address)
            except IndexError as exc:
                raise InputRefused(Reason.OUTSIDE_IMAGE, str(exc)) from None
            fault.variables = (var,)
        for var in fault.variables:
            value = self._held_value(fault, var)
            try:
                self.runtime.image.check(*var.address, value)
            except ImageValueError as exc:
                raise InputRefused(Reason.BAD_VALUE, str(exc)) from None
        return fault

    def inject(self, fault: ActiveFault, for_s: float | None) -> None:
        """Put a checked fault in force (the door's, after it recorded it)."""
        engine = self.runtime.engine
        fault.since = engine.now
        # The same target's fault of the same group goes (a fieldbus's of the same kind
        # and scope: Modbus faults of other units or ranges stay beside it; the CANopen node
        # has one of each kind -- two EMCYs of other codes were both listed, one raised).
        for old in [f for f in self.faults if f.target == fault.target
                    and f.group == fault.group and (f.group != fault.kind or f.params
                                                    == fault.params or f.target == "canopen")]:
            self._remove(old, f"replaced by {fault.who}", notify=False)
        self.faults.append(fault)
        engine.note_fault(fault.target, fault.kind, fault.params, fault.who)
        if fault.target in FIELDBUSES and self.served is not None and (
                fault.target not in self.served):
            engine.note_hazard(0, f"a {fault.target} fault ({fault.kind}, by {fault.who}) acts "
                               f"on {fault.target}, which {self.server} does not serve: "
                               "traced, with no effect")
        if for_s is not None:
            fault.timers.append(engine.call_at(engine.now + for_s, functools.partial(
                self._expire, fault, for_s)))
        if fault.kind in VARIABLE_FAULTS:
            self._hold(fault)
        elif fault.model is not None:
            self._behave(fault.model)
        self._notify(fault)

    def _expire(self, fault: ActiveFault, for_s: float) -> None:
        if fault in self.faults:
            self._remove(fault, f"for_s {for_s:g}")

    def clear(self, item: ClearFault) -> list[ActiveFault]:
        """The faults ``item`` clears (checked: InputRefused when it names nothing known)."""
        target = item.target
        if target is None or target in ("*", "all"):
            return list(self.faults)
        if not isinstance(target, str):
            raise InputRefused(Reason.BAD_VALUE, f"clear names a target, not {target!r}")
        name = target.strip()
        found = [f for f in self.faults if f.target.lower() == name.lower()
                 or f.target.split(".")[0] == name]
        if not found and not self._known(name):
            raise InputRefused(Reason.UNKNOWN_VARIABLE, f"clear {name!r}: no such target (a "
                               "plant model, its output, a variable or I/O name, modbus, "
                               "canopen, or all)")
        return found

    def _known(self, name: str) -> bool:
        """Whether ``name`` is something a fault could target (a clear of it is no typo)."""
        if name.lower() in FIELDBUSES or name.split(".")[0] in self.models:
            return True
        try:
            var = self.runtime.var(name)
            self.runtime.image.read(*var.address)
        except (InputRefused, IndexError):
            return False
        return True

    def remove(self, faults: list[ActiveFault], who: str) -> None:
        for fault in faults:
            if fault in self.faults:
                self._remove(fault, who)

    def _remove(self, fault: ActiveFault, who: str, notify: bool = True) -> None:
        self.faults.remove(fault)
        for timer in fault.timers:
            timer.cancel()
        fault.timers.clear()
        self.runtime.engine.note_fault_clear(fault.target, fault.kind, who)
        if fault.kind in VARIABLE_FAULTS:
            if notify:  # (replaced, it is not: the new fault holds the same variables)
                self._release(fault, who)
        elif fault.model is not None and notify:
            self._behave(fault.model)
        if notify:
            self._notify(fault)

    def _release(self, fault: ActiveFault, who: str) -> None:
        """What a cleared value fault held: another fault's again where one holds it too (by
        another name: clamp.extended and SA30); else what no model drives shows again what
        its writers last wrote (the PLC's output as it set it, a sensor as the script or a
        client wrote it), in that writer's name -- a wire mended -- and the models write
        what they drive."""
        image = self.runtime.image
        for var in fault.variables:
            still = [f for f in self.faults if f.kind in VARIABLE_FAULTS
                     and any(v.address == var.address for v in f.variables)]
            if still:
                f = still[-1]
                image.hold(*var.address, self._held_value(f, var), f"fault {f.kind} {f.target}")
                continue
            driven = any(overlap(var.address, address) for address in self._drives)
            image.unhold(*var.address, give_back=None if driven else f"fault clear {who}")
        self.show_driven()

    def show_driven(self) -> None:
        """What the models drive, written where the image shows something else: after a
        hold or a force over it went (a model writes what changes, so the held or forced
        value stayed until its next change -- a running spindle read at standstill and at
        speed at once: a hostile try)."""
        for model in self.models.values():
            self._write(model, shown=True)

    def _behave(self, model: Model) -> None:
        never = any(f.model is model and f.kind == "never" for f in self.faults)
        factor = next((float(f.params["factor"]) for f in self.faults
                       if f.model is model and f.kind == "slow"), 1.0)
        self._after(model, model.set_fault(self.runtime.engine.now, never, factor))

    def _held_value(self, fault: ActiveFault, var: Var) -> int:
        if fault.kind == "stuck":
            return int(fault.params["value"])
        if fault.kind == "wire_break":
            return 0 if var.view == "bit" else int(fault.params["live_zero"])
        value = self.runtime.image.read(*var.address)  # chatter: from what it reads now
        return 1 - value if var.view == "bit" else value

    def _hold(self, fault: ActiveFault) -> None:
        image = self.runtime.image
        who = f"fault {fault.kind} {fault.target}"
        for var in fault.variables:
            image.hold(*var.address, self._held_value(fault, var), who)
        if fault.kind == "chatter":
            period = float(fault.params["period_ms"]) / 1000.0
            engine = self.runtime.engine
            fault.timers.append(engine.call_at(engine.now + period, functools.partial(
                self._chatter, fault, period)))

    def _chatter(self, fault: ActiveFault, period: float) -> None:
        if fault not in self.faults:
            return
        image = self.runtime.image
        who = f"fault chatter {fault.target}"
        later = self.faults[self.faults.index(fault) + 1:]
        for var in fault.variables:
            if any(f.kind in VARIABLE_FAULTS and any(overlap(var.address, v.address)
                                                     for v in f.variables) for f in later):
                continue  # a fault injected after it holds it: the latest wins
            value = image.read(*var.address)
            low, high = value_range(var.area, var.view)
            image.hold(*var.address, (1 - value) if var.view == "bit" else (
                high if value == low else low), who)
        engine = self.runtime.engine
        fault.timers[:] = [t for t in fault.timers if t.callback is not None]
        fault.timers.append(engine.call_at(engine.now + period, functools.partial(
            self._chatter, fault, period)))

    def _notify(self, fault: ActiveFault) -> None:
        if fault.target not in FIELDBUSES:
            return
        bus = [f for f in self.faults if f.target in FIELDBUSES]
        for listener in list(self.fieldbus_listeners):
            listener(bus)

    def _state_changed(self) -> None:
        for listener in list(self.state_listeners):
            listener()

    # -- what people see ---------------------------------------------------------------------

    def explain(self, address: tuple[str, int, str]) -> str | None:
        """What drives ``address``: its model and what that model is doing."""
        held = [f for f in self.faults if f.kind in VARIABLE_FAULTS
                and any(v.address == address for v in f.variables)]
        if held:
            f = held[-1]
            return f"fault {f.kind} on {f.target} (by {f.who})"
        drives = self._drives.get(address)
        if drives is None:
            return None
        return drives[0].describe(self.runtime.engine.read_time())  # (the read's time)

    def status(self) -> dict[str, Any]:
        """The console's and ``/api/status``'s ``plant``: each model and the faults (the
        encoding of the cell's read model, ``gateway/view.py``, of the plant as it is now)."""
        from ncgate.gateway.view import plant_status, plant_view

        return plant_status(plant_view(self))

    def fault_of(self, name: str) -> list[ActiveFault]:
        return [f for f in self.faults if f.target.split(".")[0] == name]


class _ModelHost:
    """What a model reads: its inputs by key, and the NC's axes."""

    def __init__(self, plant: Plant, variables: dict[str, Var]) -> None:
        self._plant = plant
        self._vars = variables

    def read(self, key: str) -> int:
        var = self._vars.get(key)
        return 0 if var is None else self._plant.runtime.image.read(*var.address)

    def axis(self, text: str) -> float:
        process, axis = text.split(".")
        position = self._plant.runtime.engine.status(int(process[1:])).position
        i = AXES.index(axis)
        return float(position[i]) if i < len(position) else 0.0
