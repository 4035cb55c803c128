"""Scenarios: a script's ``[[expect]]``, judged on the engine's clock (docs/plant.md).

An expectation watches its condition from the moment the scenario starts -- an image
condition through the image's listeners, a process state through the engine's, an alarm
through the trace -- and keeps when it changed, so a verdict is decided from what happened,
not from a sample: ``within = [a, b]`` passes when the condition holds at some moment of the
window, ``by = T`` is ``within = [0, T]``, ``always`` when it never stops holding.  The same
file is judged the same way by ``ncgate sim`` (virtual clock) and ``ncgate run --script`` (the
wall clock, with real clients connected).

Times are the scenario's: seconds since :meth:`Expectations.start` (``sim``: machine time 0;
``run --script``: the moment the scenario starts the main program).  A window the run did not
reach the end of is judged only on what was seen of it: a moment it held passes, but it never
passes for want of a moment not seen -- ``no alarm`` in it, or the condition's first moment
after the run's end: that is ``FAIL ...: not reached``.  So is an ``always`` over a run that
ended before the scenario's end (its last window or timed entry).
"""

from __future__ import annotations

import html
import io
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final, TextIO

from ncgate.config import ConfigError
from ncgate.config.script import Expect, Script
from ncgate.errors import InputRefused
from ncgate.gateway.atomic import write_output
from ncgate.gateway.wiring import Runtime, parse_condition
from ncgate.inputs import Var
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import did_you_mean
from ncgate.interpreter.dialects import comparison
from ncgate.interpreter.engine import Process, ProcessState
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.timers import Timer
from ncgate.plc.image import Change, ImageValueError, IOImage, PlcError


def seconds(t: float) -> str:
    """A time as the verdicts print it: to the millisecond, or with the digits it was given
    when they are finer, up to the microsecond (``--until 3.3999`` is 3.3999, not 3.400
    beside a window that ends at 3.4; a wall clock's 4.5193847 is 4.519)."""
    shown = f"{t:.3f}"
    if abs(t - float(shown)) < 1e-9:
        return shown
    fine = f"{t:.6f}".rstrip("0")
    return fine if abs(t - float(fine)) < 1e-9 else shown


def never_changes(image: IOImage, address: tuple[str, int, str], value: int) -> str | None:
    """Why a condition comparing the variable at ``address`` with ``value`` could never
    change -- a value the variable cannot hold: ``SA40=2`` never holds, ``SA40#2`` never
    fails, and either verdict says nothing -- or None."""
    try:
        image.check(*address, value)
    except ImageValueError as exc:
        return f"{exc}: the condition could never change"
    return None


def unknown_name(text: str, symbols: Iterable[str]) -> str | None:
    """What to say of a condition (an expectation's ``cond``, an entry's ``when``) whose
    left side is a word that names nothing: that it is no I/O name of ``[symbols]``, and the
    closest that is; None when its left side is no such word."""
    name = re.split(r"[=#<>]", text, maxsplit=1)[0].strip()
    if not re.fullmatch(r"[A-Za-z_]\w*", name) or re.fullmatch(
            r"(?i)(SA|SK|SYVAR|K)\d+", name):
        return None
    names = list(symbols)
    if name.upper() in {n.upper() for n in names}:
        return None
    close = did_you_mean(name, names)
    hint = f" (did you mean {close}?)" if close else ""
    return (f"{name!r} is neither an image variable (SA30, SK4, SYVAR10) nor an I/O name "
            f"of [symbols]{hint}")


# Every alarm the trace can hold has one of these codes: the NC's, the PLC's (AL160) and
# the fieldbus's (AL150) alike -- neither dialect has an alarm a program raises with a code
# of its own, and the door refuses a fieldbus alarm of any other code.  A code outside them
# is a typo whose "alarm" could never pass and whose "no alarm" could never fail.
_ALARM_CODES: Final = frozenset(int(code) for code in AlarmCode)


def _no_such_alarm(word: str) -> str:
    """What to say of an alarm code no alarm has: the codes one digit away (one dropped,
    added, changed or two swapped), as a typo makes them, when there are a few, and where
    the codes are listed."""
    digits = word.upper().removeprefix("AL")
    near = {digits[:i] + digits[i + 1:] for i in range(len(digits))}
    near |= {digits[:i] + digits[i + 1] + digits[i] + digits[i + 2:]
             for i in range(len(digits) - 1)}
    near |= {digits[:i] + d + digits[i + j:] for i in range(len(digits) + 1)
             for d in "0123456789" for j in (0, 1)}
    close = [code.label for code in AlarmCode if str(int(code)) in near - {digits}]
    # (more than three is a guess in a crowd: the range says as much)
    hint = ("" if not close or len(close) > 3 else f" (did you mean {close[0]}?)"
            if len(close) == 1 else f" (did you mean {', '.join(close[:-1])} or {close[-1]}?)")
    labels = [code.label for code in AlarmCode]
    return (f"no alarm has the code AL{digits}{hint}: the alarms' codes are those "
            f"docs/diagnostics.md lists, {labels[0]} .. {labels[-1]}")


class ScenarioError(ConfigError):
    """An expectation that cannot be read (the message names the file and the key): a
    mistake of the script, said as one (exit 2), as its other keys' are."""


@dataclass
class Verdict:
    name: str
    ok: bool
    detail: str
    script: str = ""

    def line(self) -> str:
        return f"{'PASS' if self.ok else 'FAIL'} {self.name}: {self.detail}"


@dataclass
class _Watch:
    expect: Expect
    kind: str  # "var", "state", "alarm", "no alarm"
    holds: bool = False
    changes: list[tuple[float, bool]] = field(default_factory=list)
    var: Var | None = None
    test: object = None
    process: int = 0
    state: ProcessState | None = None
    code: int | None = None
    alarms: list[tuple[float, str]] = field(default_factory=list)
    written: tuple[float, str | None] = (0.0, None)  # the variable's last write: when, who
    # What it was when: the variable's (t, value, writer since t) or the process's
    # (t, state name, "") at each change, so a verdict says how things stood at a window's
    # end, not at the run's.
    history: list[tuple[float, int | str, str | None]] = field(default_factory=list)
    note: str | None = None  # what the plant said of the variable as its window closed


class Expectations:
    """The ``[[expect]]`` of one script, watching one runtime from :meth:`start` on."""

    def __init__(self, runtime: Runtime, script: Script) -> None:
        self.runtime = runtime
        self.script = script
        self.watches = [self._watch(e) for e in script.expects]
        self.t0 = 0.0
        self._undo: list[object] = []
        self._timers: list[Timer] = []
        # The variables' watches by each byte they occupy (a SYVAR is its own): a write
        # looks at the watches of the bytes it touched, not at every watch.
        self._by_byte: dict[tuple[str, int], list[_Watch]] = {}
        self._watching: dict[tuple[str, int, str], tuple[int, ...]] = {}  # (_watching_of)
        for w in self.watches:
            if w.kind == "var" and w.var is not None:
                area, first, last = _bytes(*w.var.address)
                for byte in range(first, last + 1):
                    self._by_byte.setdefault((area, byte), []).append(w)

    def _watching_of(self, area: str, index: int, view: str) -> tuple[int, ...]:
        """The watches (ids) a write of the variable at (area, index, view) may change:
        those sharing a byte of its storage."""
        area, first, last = _bytes(area, index, view)
        return tuple(id(w) for byte in range(first, last + 1)
                     for w in self._by_byte.get((area, byte), ()))

    def _fail(self, expect: Expect, message: str) -> ScenarioError:
        return ScenarioError(f"{self.script.file}: {expect.key}.cond: {message}")

    def _watch(self, expect: Expect) -> _Watch:
        text = expect.cond
        words = text.split()
        lowered = [w.lower() for w in words]
        if lowered[:1] == ["alarm"] or lowered[:2] == ["no", "alarm"]:
            negative = lowered[0] == "no"
            rest = words[2:] if negative else words[1:]
            code = None
            if rest:
                number = rest[0].upper().removeprefix("AL")
                if len(rest) > 1 or not number.isdigit():
                    raise self._fail(expect, f"expected \"alarm\", \"alarm AL145\" or \"no "
                                     f"alarm\", got {text!r}")
                code = int(number)
                if code not in _ALARM_CODES:
                    raise self._fail(expect, _no_such_alarm(rest[0]))
            return _Watch(expect, "no alarm" if negative else "alarm", holds=negative,
                          code=code)
        if len(words) == 2 and words[0][:1].upper() == "P" and words[0][1:].isdigit():
            state = words[1].upper()
            if state not in ProcessState.__members__:
                raise self._fail(expect, f"unknown state {words[1]!r} (" +
                                 ", ".join(ProcessState.__members__) + ")")
            k = int(words[0][1:])
            if k not in self.runtime.engine.processes:
                raise self._fail(expect, f"no process {k}")
            return _Watch(expect, "state", process=k, state=ProcessState[state])
        try:
            (area, index, view), op, value = parse_condition(self.runtime.resolve(text))
            var = Var(area, index, view)
            self.runtime.image.read(area, index, view)
        except (ValueError, PlcError, InputRefused) as exc:
            raise self._fail(expect, unknown_name(text, self.runtime.config.symbols)
                             or str(exc)) from None
        never = never_changes(self.runtime.image, (area, index, view), value)
        if never is not None:
            raise self._fail(expect, never)
        return _Watch(expect, "var", var=var, test=comparison(op, value))

    def start(self, t0: float | None = None) -> None:
        """Watch from now on: each condition as it is now, then every change.  ``t0``: the
        machine time that is the scenario's 0 (default: now)."""
        runtime = self.runtime
        self.t0 = runtime.engine.now if t0 is None else t0
        now = 0.0  # (the scenario's time)
        for w in self.watches:
            if w.kind == "var":
                w.holds = self._var_holds(w)
                w.written = (now, self._writer(w))
                assert w.var is not None
                w.history.append((now, runtime.image.read(*w.var.address), w.written[1]))
            elif w.kind == "state":
                state = runtime.engine.processes[w.process].state
                w.holds = state is w.state
                w.history.append((now, state.name, None))
            w.changes.append((now, w.holds))
        if any(w.kind == "var" for w in self.watches):
            self._undo.append(runtime.image.subscribe(self._on_write))
        plant = runtime.plant
        for w in self.watches:  # what drives the variable, as its window closes
            if w.kind == "var" and w.var is not None and plant is not None and (
                    w.expect.within is not None):
                address = w.var.address

                def note(w: _Watch = w, address: tuple[str, int, str] = address) -> None:
                    w.note = plant.explain(address)

                self._timers.append(runtime.engine.call_at(self.t0 + w.expect.within[1],
                                                           note))
        if any(w.kind == "state" for w in self.watches):
            runtime.engine.state_listeners.append(self._on_state)
        if any(w.kind in ("alarm", "no alarm") for w in self.watches):
            self._undo.append(runtime.trace.subscribe(self._on_event))

    def stop(self) -> None:
        for timer in self._timers:
            timer.cancel()
        self._timers.clear()
        for undo in self._undo:
            undo()  # type: ignore[operator]
        self._undo.clear()
        listeners = self.runtime.engine.state_listeners
        if self._on_state in listeners:
            listeners.remove(self._on_state)

    def _var_holds(self, w: _Watch) -> bool:
        assert w.var is not None
        return bool(w.test(self.runtime.image.read(*w.var.address)))  # type: ignore[operator]

    def _writer(self, w: _Watch) -> str | None:
        assert w.var is not None
        return self.runtime.image.last_writer(*w.var.address)

    @property
    def now(self) -> float:
        """The scenario's time: seconds since :meth:`start`."""
        return self.runtime.engine.now - self.t0

    def _note(self, w: _Watch, holds: bool) -> None:
        if holds != w.holds:
            w.holds = holds
            w.changes.append((self.now, holds))

    def _on_write(self, changes: Sequence[Change], writer: str) -> None:
        hit: set[int] = set()  # (a write of other bytes: their value and writer are as were)
        watching = self._watching
        for c in changes:
            key = (c.area, c.index, c.view)
            found = watching.get(key)
            if found is None:
                found = watching[key] = self._watching_of(*key)
            hit.update(found)
        if not hit:
            return
        for w in self.watches:
            if id(w) not in hit:
                continue
            assert w.var is not None
            holds = self._var_holds(w)
            who = self._writer(w)
            value = self.runtime.image.read(*w.var.address)
            now = self.now
            if holds != w.holds or who != w.written[1] or value != w.history[-1][1]:
                w.written = (now, who)
                w.history.append((now, value, who))
            self._note(w, holds)

    def _on_state(self, process: Process, old: ProcessState) -> None:
        for w in self.watches:
            if w.kind == "state" and w.process == process.number:
                w.history.append((self.now, process.state.name, None))
                self._note(w, process.state is w.state)

    def _on_event(self, event: Event) -> None:
        if not isinstance(event, ev.Alarm):
            return
        for w in self.watches:
            if w.kind in ("alarm", "no alarm") and (w.code is None or int(event.code) == w.code):
                who = f"P{event.proc}" if event.proc else "PLC"
                w.alarms.append((event.t - self.t0,
                                 f"{who} alarm AL{int(event.code)}: {event.message}"))

    # -- verdicts ----------------------------------------------------------------------------

    def verdicts(self, end: float | None = None) -> list[Verdict]:
        """The verdicts of the run so far, or up to ``end`` (the scenario's time; what
        changed after it is not seen).  By default up to now: on the wall clock the
        clock's now, not the engine's last event (a run stopped after seconds of nothing
        said it ended at that event's time)."""
        end = self.runtime.engine.read_time() - self.t0 if end is None else end
        return [self._verdict(w, end) for w in self.watches]

    def _verdict(self, w: _Watch, end: float) -> Verdict:
        e = w.expect
        a, b = e.within if e.within is not None else (0.0, end)
        cond = e.cond
        window = f"[{a:g}, {b:g}] s"
        # A window the run ended inside is judged on what was seen of it: a moment it held
        # passes, but the moment it would have held after the end is not there to be seen.
        closed = end + EPS >= b
        short = (f"not reached: the run ended at {seconds(end)} s, before the window {window} "
                 + ("opened" if end + EPS < a else "closed"))
        if w.kind in ("alarm", "no alarm"):
            inside = [(t, text) for t, text in w.alarms if a - EPS <= t <= min(b, end) + EPS]
            if w.kind == "alarm":
                if inside:
                    return self._v(e, True, f"{inside[0][1]} at {inside[0][0]:.3f} s")
                if not closed:
                    return self._v(e, False, f"{short} (no {cond} until then)")
                return self._v(e, False, f"no {cond} in {self._window(e, a, b)}")
            if inside:
                t, text = inside[0]
                return self._v(e, False, f"{text} at {t:.3f} s")
            code = " AL" + str(w.code) if w.code else ""
            if not closed:
                return self._v(e, False, f"{short} (no alarm{code} until then)")
            if e.always and not self._whole(end):
                return self._v(e, False, self._unfinished(end) + f" (no alarm{code} until "
                               "then)")
            return self._v(e, True, f"no alarm{code} in {self._window(e, a, b)}")
        changes = [(t, holds) for t, holds in w.changes if t <= end + EPS]
        if e.always:
            broken = [t for t, holds in changes if not holds]
            if broken:
                return self._v(e, False, f"{cond} stopped holding at {broken[0]:.3f} s"
                               + self._now(w, broken[0]))
            if not self._whole(end):
                return self._v(e, False, self._unfinished(end) + f" ({cond} held from 0.000 "
                               f"to {seconds(end)} s)")
            return self._v(e, True, f"{cond} held from 0.000 to {seconds(end)} s")
        if end + EPS < a:
            return self._v(e, False, short)
        holds_at_a = changes[0][1]
        for t, holds in changes:
            if t <= a + EPS:
                holds_at_a = holds
        if holds_at_a:
            return self._v(e, True, f"{cond} at {a:.3f} s")
        became = [t for t, holds in changes if holds and a - EPS <= t <= b + EPS]
        if became:
            return self._v(e, True, f"{cond} at {became[0]:.3f} s")
        if not closed:
            return self._v(e, False, f"{short}; {self._still(w, end)}")
        return self._v(e, False, self._still(w, b))

    def _whole(self, end: float) -> bool:
        """Whether the run reached the scenario's end (its last window, its last timed
        entry): an ``always`` is judged over all of it."""
        horizon = self.horizon
        return horizon is None or end + EPS >= horizon

    def _unfinished(self, end: float) -> str:
        assert self.horizon is not None  # (said only when the run ended before it: _whole)
        return (f"not reached: the run ended at {seconds(end)} s, before the scenario's end at "
                f"{seconds(self.horizon)} s")

    @staticmethod
    def _at(w: _Watch, t: float) -> tuple[float, int | str, str | None]:
        """How it stood at ``t``: the last change at or before it."""
        found = w.history[0]
        for entry in w.history:
            if entry[0] > t + 1e-9:
                break
            found = entry
        return found

    def _still(self, w: _Watch, t: float) -> str:
        when, value, who = self._at(w, t)
        if w.kind == "var" and w.var is not None:
            by = f" (set by {who} at {when:.3f} s)" if who else " (never written)"
            note = w.note
            if note is None and self.runtime.plant is not None and t + EPS >= self.now:
                note = self.runtime.plant.explain(w.var.address)  # (what it does now)
            return f"{w.var} still {value} at {seconds(t)} s{by}" + (f"; {note}" if note else "")
        wanted = w.state.name if w.state is not None else "?"
        return f"P{w.process} {value}, not {wanted}, at {seconds(t)} s (since {when:.3f} s)"

    def _now(self, w: _Watch, t: float) -> str:
        """How it stood when it stopped holding (``t``)."""
        when, value, who = self._at(w, t)
        if w.kind == "var" and w.var is not None:
            return f" ({w.var} = {value}, set by {who} at {when:.3f} s)"
        return f" (P{w.process} {value})"

    @staticmethod
    def _window(e: Expect, a: float, b: float) -> str:
        return f"{a:.3f}..{b:.3f} s"

    def _v(self, e: Expect, ok: bool, detail: str) -> Verdict:
        return Verdict(e.name, ok, detail, self.script.file)

    @property
    def horizon(self) -> float | None:
        return self.script.horizon


EPS = 1e-9  # (seconds: two times this close are one moment)


def _bytes(area: str, index: int, view: str) -> tuple[str, int, int]:
    """The storage a variable occupies: (area, first, last) byte (a SYVAR is its own)."""
    if area == "SA" and view == "bit":
        return area, index >> 3, index >> 3
    return area, index, index + 1 if view == "IN" else index


def save_junit(path: Path, verdicts: Sequence[tuple[str, list[Verdict]]],
               notes: Mapping[str, str] | None = None) -> None:
    """:func:`write_junit` into ``path``, whole or not at all (a CI reading a half-written
    file after a kill would see an XML error, or fewer failures than there were), through
    its links and with a shell's ``>`` mode (``atomic.write_output``)."""
    out = io.StringIO()
    write_junit(verdicts, out, notes)
    write_output(path, out.getvalue().encode("utf-8"))


def write_junit(verdicts: Sequence[tuple[str, list[Verdict]]], out: TextIO,
                notes: Mapping[str, str] | None = None) -> None:
    """JUnit XML: one testsuite per scenario, one testcase per expectation; ``notes``: a
    scenario's note (``run --script`` on a machine that fell behind) as its system-err."""
    total = sum(len(v) for _, v in verdicts)
    failures = sum(1 for _, v in verdicts for x in v if not x.ok)
    out.write('<?xml version="1.0" encoding="UTF-8"?>\n')
    out.write(f'<testsuites name="ncgate scenarios" tests="{total}" failures="{failures}">\n')
    for name, items in verdicts:
        bad = sum(1 for x in items if not x.ok)
        out.write(f'  <testsuite name="{html.escape(name)}" tests="{len(items)}" '
                  f'failures="{bad}">\n')
        for v in items:
            out.write(f'    <testcase classname="{html.escape(name)}" '
                      f'name="{html.escape(v.name)}"')
            if v.ok:
                out.write(f'>\n      <system-out>{html.escape(v.line())}</system-out>\n'
                          '    </testcase>\n')
            else:
                out.write(f'>\n      <failure message="{html.escape(v.detail)}">'
                          f'{html.escape(v.line())}</failure>\n    </testcase>\n')
        note = (notes or {}).get(name)
        if note:
            out.write(f"    <system-err>{html.escape(note)}</system-err>\n")
        out.write("  </testsuite>\n")
    out.write("</testsuites>\n")
