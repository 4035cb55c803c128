"""Stored signals between channels (spec 5.3, 5.4): the ISG dialect's room of the engine.

Unlike NC-110's rendezvous SND, a ``#SIGNAL`` never blocks its sender: it is delivered to the
WAITs that need it now, and what is left is *stored* until a later ``#WAIT`` consumes it.

- A directed signal (``CH k``, one per named channel) is used up by one matching WAIT of that
  channel, or by ``COUNT c`` of them.  A broadcast (no ``CH``) satisfies only broadcast WAITs;
  without ``COUNT`` it is never used up (``#SIGNAL REMOVE`` or a reset clears it), with
  ``COUNT c`` after c WAITs from any channels.
- A directed WAIT (``CH j CH k``) needs one signal addressed to its channel from each named
  channel, in any order, each consumed when it arrives; a broadcast WAIT one broadcast signal.
- At most ``nc.isg.max_events`` signals are stored at once: one more is an alarm of the sender
  (a shift's worth of unconsumed signals cannot grow memory without bound).

The board acts through the engine's :class:`~ncgate.interpreter.engine.ports.BlockHost` only:
its waits are the engine's wait records (state WAIT_PROC, the trace, timeouts, the deadlock
search -- each directed WAIT has an edge to every channel it still needs).  Must not import
``plc`` or ``gateway``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import RuntimeAlarm
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.actions import ItemKind
from ncgate.interpreter.engine.ports import BlockHost
from ncgate.interpreter.engine.process import Process
from ncgate.interpreter.engine.states import Stage, WaitKind, WaitRecord, Where


@dataclass(frozen=True, slots=True)
class SendSignal:
    """A ``#SIGNAL``, evaluated by the decoder."""

    id: int
    count: int | None
    params: tuple[tuple[int, float], ...]
    to: tuple[int, ...]  # empty: a broadcast
    level: str  # "dec" or "syn"


@dataclass(frozen=True, slots=True)
class AwaitSignal:
    """A ``#WAIT``, evaluated by the decoder; ``store`` assigns the received parameters."""

    id: int
    channels: tuple[int, ...]  # empty: a broadcast wait
    params: tuple[int, ...]  # the P[i] it assigns
    level: str
    code: str
    store: Callable[[Process, dict[int, float], Where], None] | None = None
    on: ev.SignalOn | None = None  # the trace's "on"; made here when not given

    def __post_init__(self) -> None:
        if self.on is None:
            on = ev.SignalOn(self.id, self.channels if self.channels else "all", self.level)
            object.__setattr__(self, "on", on)


@dataclass(frozen=True, slots=True)
class RemoveSignals:
    low: int | None
    high: int | None
    channels: tuple[int, ...]


@dataclass(slots=True)
class Stored:
    id: int
    sender: int
    to: int  # 0: a broadcast
    left: int | None  # WAITs it may still satisfy; None: never used up
    params: tuple[tuple[int, float], ...]


@dataclass(slots=True, eq=False)
class Pending:
    """A WAIT under way; it is also its wait record's handle (``cancel``)."""

    board: SignalBoard
    p: Process
    action: AwaitSignal
    record: WaitRecord | None
    missing: list[int]  # channels whose signal it still needs; empty for a broadcast wait
    got: dict[int, float]

    def cancel(self) -> None:
        """The engine drops the wait (an alarm, a timeout, a reset)."""
        self.board._forget(self)

    def reason(self) -> str:
        ident = self.action.id
        if not self.missing:
            return f"waits for a broadcast signal {ident}"
        return f"waits for signal {ident} from " + ", ".join(f"P{k}" for k in self.missing)

    def note(self) -> str | None:
        return self.board._buffered_note(self)


class SignalBoard:
    """The stored signals and the WAITs under way, for every channel of one engine."""

    def __init__(self, host: BlockHost, max_events: int) -> None:
        self.host = host
        self.max_events = max_events
        # (id, addressee; 0 for a broadcast) -> stored signals, oldest first
        self._stored: dict[tuple[int, int], list[Stored]] = {}
        self.stored_count = 0
        self._record = host.record
        # (id, channel; 0 for a broadcast wait) -> the WAITs under way, oldest first
        self._waiting: dict[tuple[int, int], list[Pending]] = {}
        host.register_action(SendSignal, self.send)
        host.register_action(AwaitSignal, self.wait)
        host.register_action(RemoveSignals, self.remove)

    # ---- #SIGNAL ---------------------------------------------------------------------------

    def check_channels(self, channels: tuple[int, ...], what: str) -> None:
        """Channels a signal or WAIT names must exist (checked when the action is made)."""
        processes = self.host.processes
        for k in channels:
            if k not in processes:
                raise RuntimeAlarm(AlarmCode.PROCESS_OUT_OF_RANGE,
                                   f"{what} channel {k}, which is not configured "
                                   f"(1..{len(processes)})")

    def send(self, p: Process, stage: Stage, sig: SendSignal, where: Where) -> bool:
        host = self.host
        if len(sig.to) == 1 and sig.count is None:  # the common case: one WAIT uses it up
            return self._send_one(p, sig, sig.to[0], where)
        addressees = sig.to or _BROADCAST
        # Plan first: a signal that cannot be stored whole is an alarm, and nothing of it goes.
        plan = []
        new = 0
        waiting = self._waiting
        sender = p.number
        for to in addressees:
            left = sig.count if sig.count is not None else (1 if to else None)
            queue = waiting.get((sig.id, to))
            takers: list[Pending] = []
            if queue:
                for w in queue:
                    if to == 0 or sender in w.missing:
                        takers.append(w)
                        if left is not None and len(takers) == left:
                            break
            if left is not None:
                left -= len(takers)
            if left is None or left > 0:
                new += 1
            plan.append((to, takers, left))
        if new and self.stored_count + new > self.max_events:
            raise self._full(sig)
        host.count_signal(p, addressees[0], sig.id, where)
        if len(addressees) > 1:
            p.stats.snd_sent += len(addressees) - 1
        self._record(ev.Signal, sender, where, sig.id, sig.to or "all", sig.count,
                    dict(sig.params), sig.level)
        for to, takers, left in plan:
            for w in takers:
                self._deliver(w, sender, sig.params, sender if to else "all")
            if left is None or left > 0:
                self._keep(Stored(sig.id, sender, to, left, sig.params))
        return True

    def _send_one(self, p: Process, sig: SendSignal, to: int, where: Where) -> bool:
        """A directed signal without COUNT: to the oldest WAIT that needs it, else stored."""
        sender = p.number
        key = (sig.id, to)
        taker = None
        queue = self._waiting.get(key)
        if queue:
            for w in queue:
                if sender in w.missing:
                    taker = w
                    break
        if taker is None and self.stored_count >= self.max_events:
            raise self._full(sig)
        self.host.count_signal(p, to, sig.id, where)
        self._record(ev.Signal, sender, where, sig.id, sig.to, None, dict(sig.params),
                     sig.level)
        if taker is not None:
            self._deliver(taker, sender, sig.params, sender)
        else:
            self._keep(Stored(sig.id, sender, to, 1, sig.params))
        return True

    def _keep(self, stored: Stored) -> None:
        key = (stored.id, stored.to)
        if key in self._stored:
            self._stored[key].append(stored)
        else:
            self._stored[key] = [stored]
        self.stored_count += 1

    def _full(self, sig: SendSignal) -> RuntimeAlarm:
        return RuntimeAlarm(AlarmCode.SIGNAL_STORE_FULL,
                            f"#SIGNAL ID{sig.id}: {self.stored_count} signals are stored and "
                            f"nc.isg.max_events is {self.max_events}; WAIT for them, "
                            "#SIGNAL REMOVE them, or raise the limit")

    def _deliver(self, w: Pending, sender: int, params: tuple[tuple[int, float], ...],
                 by: int | str) -> None:
        w.p.stats.snd_received += 1
        if params:
            w.got.update(params)
        record = w.record
        assert record is not None
        missing = w.missing
        if missing:
            missing.remove(sender)
            if missing:
                record.targets = tuple(missing)
                record.target = missing[0]
                return
            record.targets = ()
            record.target = 0
        self._forget(w)
        record.handle = None
        host = self.host
        if w.action.params:
            try:
                self._store(w.p, w.action, w.got, record.where)
            except RuntimeAlarm as alarm:
                host.alarm(w.p, alarm.code, alarm.message, record.where)
                return
        host.finish_wait(w.p, record, by)

    # ---- #WAIT ------------------------------------------------------------------------------

    def wait(self, p: Process, stage: Stage, act: AwaitSignal, where: Where) -> bool:
        channels = act.channels
        got: dict[int, float] = {}
        stored_map = self._stored
        if not channels:
            missing: list[int] = []
            stored = self._take(act.id, 0, None) if (act.id, 0) in stored_map else None
            if stored is not None:
                p.stats.snd_received += 1
                if act.params:
                    self._store(p, act, dict(stored.params), where)
                return True
        else:
            missing = list(dict.fromkeys(channels)) if len(channels) > 1 else [channels[0]]
            if (act.id, p.number) in stored_map:
                for sender in list(missing):
                    stored = self._take(act.id, p.number, sender)
                    if stored is not None:
                        p.stats.snd_received += 1
                        got.update(stored.params)
                        missing.remove(sender)
                if not missing:
                    if act.params:
                        self._store(p, act, got, where)
                    return True
        on = act.on
        if channels and len(missing) < len(set(channels)):
            # Some signals were already there: the wait event names only those still awaited.
            on = ev.SignalOn(act.id, tuple(missing), act.level)
        pending = Pending(self, p, act, None, missing, got)
        # Positional (this is on every WAIT that waits): kind, target, code, where, since,
        # stage, cond, value, writer, handle, timeout, probe, on, text, targets, note.
        record = WaitRecord(_PROC, missing[0] if missing else 0, act.code, where,
                            self.host.now, stage, None, None, None, pending, None, None,
                            on, pending.reason, tuple(missing), pending.note)
        pending.record = record
        key = (act.id, p.number if missing else 0)
        queue = self._waiting.get(key)
        if queue is None:
            self._waiting[key] = [pending]
        else:
            queue.append(pending)
        host = self.host
        host.begin_wait(p, stage, record)
        host.check_wait(p, record)
        return False

    def _take(self, ident: int, to: int, sender: int | None) -> Stored | None:
        """Consume one stored signal: the oldest to ``to`` from ``sender`` (any: None)."""
        key = (ident, to)
        queue = self._stored.get(key)
        if not queue:
            return None
        for i, stored in enumerate(queue):
            if sender is None or stored.sender == sender:
                if stored.left is not None:
                    stored.left -= 1
                    if stored.left == 0:
                        del queue[i]
                        self.stored_count -= 1
                        if not queue:
                            del self._stored[key]
                return stored
        return None

    def _store(self, p: Process, act: AwaitSignal, got: dict[int, float], where: Where) -> None:
        """Assign the WAIT's parameters from what it received (spec 5.4)."""
        missing = [i for i in act.params if i not in got]
        if missing:
            raise RuntimeAlarm(AlarmCode.SIGNAL_PARAM_MISSING,
                               f"{act.code}: no received signal carried "
                               + ", ".join(f"P[{i}]" for i in missing))
        if act.store is not None and act.params:
            act.store(p, got, where)

    def _forget(self, w: Pending) -> None:
        key = (w.action.id, w.p.number if w.action.channels else 0)
        waiting = self._waiting.get(key)
        if waiting:
            if waiting[0] is w:
                del waiting[0]
            elif w in waiting:
                waiting.remove(w)
            if not waiting:
                del self._waiting[key]

    def _buffered_note(self, w: Pending) -> str | None:
        """The buffer effect (spec 5.4): a #SIGNAL SYN this WAIT needs, still queued in the
        buffer of a channel whose interpolator will not take it."""
        processes = self.host.processes
        for k in w.missing or [w.p.number]:
            q = processes[k]
            for item in q.queue:
                if item.kind != ItemKind.SYNC:
                    continue
                for action in item.actions or ():
                    if (isinstance(action, SendSignal) and action.id == w.action.id
                            and (w.p.number in action.to if w.missing else not action.to)):
                        file, line, n = item.where
                        number = f" N{n}" if n is not None else ""
                        return (f"the #SIGNAL SYN at {file}:{line}{number} is still in the "
                                f"buffer of P{k}, whose interpolator waits for the buffer to "
                                "fill while the decoder waits: add #FLUSH before the #WAIT")
        return None

    # ---- #SIGNAL REMOVE and reset -------------------------------------------------------------

    def remove(self, p: Process, stage: Stage, act: RemoveSignals, where: Where) -> bool:
        addressees = set(act.channels) if act.channels else {0}
        removed = 0
        for key in list(self._stored):
            ident, to = key
            if to not in addressees:
                continue
            if act.low is not None and ident < act.low:
                continue
            if act.high is not None and ident > act.high:
                continue
            removed += len(self._stored.pop(key))
        self.stored_count -= removed
        self._record(ev.Remove, p.number, where, removed)
        return True

    def clear(self) -> None:
        """A reset: every stored signal goes (the engine drops the waits itself)."""
        self._stored.clear()
        self._waiting.clear()
        self.stored_count = 0

    def stored(self) -> list[Stored]:
        """The stored signals (for tests and the console), oldest first per key."""
        return [s for queue in self._stored.values() for s in queue]


_BROADCAST = (0,)
_PROC = WaitKind.PROC
