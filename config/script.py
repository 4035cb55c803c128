"""The scripted PLC of ``ncgate sim`` (spec 4.3), loaded and validated.

```toml
[[write]]                 # at a simulated time
at = 2.5
set = "SA10=1"
[[write]]                 # when a condition becomes true, after a delay
when = "SYVAR1=10"
after = 0.1
set = "SK250=8"
[[snd]]                   # an SND from an external process
when = "P3 WAIT_PROC"
from = 4
to = 3
```

Conditions and assignments stay text here; the gateway parses them with the interpreter's
grammar.  Each entry fires once: ``at`` a time, or ``after`` seconds (default 0) past the first
moment its ``when`` holds.  Errors name the file and the dotted key (``write[1].set``).
Stdlib only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from ncgate.config.plant import FaultConfig, read_fault, shown
from ncgate.config.reader import read_toml
from ncgate.config.schema import ConfigError


@dataclass(frozen=True, slots=True)
class ScriptEntry:
    key: str  # "write[0]", for messages
    at: float | None
    when: str | None
    after: float
    set: str | None = None  # write: "SA10=1"
    sender: int | None = None  # snd: from
    target: int | None = None  # snd: to
    command: str | None = None  # command: cycle_start, feed_hold, reset, step, ...
    process: int | None = None  # command: of one process (None: the cell)
    point: str | None = None  # break: the breakpoint ("PROG92:8", "P2 wait", "sync")
    on: bool = True  # break: set (or clear)
    feed: int | None = None  # override: the feed override in percent
    rapid: int | None = None  # override: the rapid override in percent
    fault: FaultConfig | None = None  # fault: inject (or clear) a fault


@dataclass(frozen=True, slots=True)
class Expect:
    """An expectation of a scenario (docs/plant.md): ``cond`` holds at some moment of the
    window ``within`` (``by`` T is [0, T]), or at every moment of the run (``always``)."""

    key: str  # "expect[0]"
    name: str
    cond: str  # "SA30=1", "P1 IDLE", "alarm AL145", "alarm", "no alarm"
    within: tuple[float, float] | None = None
    always: bool = False


@dataclass(frozen=True, slots=True)
class Script:
    file: str
    entries: tuple[ScriptEntry, ...]
    expects: tuple[Expect, ...] = ()

    @property
    def horizon(self) -> float | None:
        """The end of the last window, or of the last timed entry: how long a scenario runs.
        None for a scenario whose expectations are all ``always``: it has no end of its own
        (``sim`` needs ``--until``, ``run`` runs until stopped).  Cut at its last entry, an
        ``always`` was judged over nothing: a write at 0 ran 0 s and passed what broke at
        0.5 s."""
        if self.expects and all(e.within is None for e in self.expects):
            return None
        ends = [e.within[1] for e in self.expects if e.within is not None]
        ends += [e.at for e in self.entries if e.at is not None]
        ends += [e.fault.at + (e.fault.for_s or 0.0) for e in self.entries
                 if e.fault is not None and e.fault.at is not None]
        return max(ends) if ends else None


def load_script(path: str | Path | None) -> Script:
    if path is None:
        return Script("<no script>", ())
    source = Path(path)
    raw = read_toml(source)
    file = str(source)

    def fail(key: str, message: str) -> ConfigError:
        return ConfigError(f"{file}: {key}: {message}")

    for name in raw:
        if name not in SECTIONS:
            raise fail(name, "unknown key (expected [[write]], [[snd]], [[command]], [[break]], "
                       "[[override]], [[fault]] or [[expect]])")
    entries: list[ScriptEntry] = []
    faults = raw.get("fault", [])
    if not isinstance(faults, list):
        raise fail("fault", "expected an array of tables ([[fault]])")
    for i, table in enumerate(faults):
        fault = read_fault(table, f"fault[{i}]", fail, script=True)
        entries.append(ScriptEntry(fault.key, fault.at if fault.at is not None else (
            0.0 if fault.when is None else None), fault.when, fault.after, fault=fault))
    expects = raw.get("expect", [])
    if not isinstance(expects, list):
        raise fail("expect", "expected an array of tables ([[expect]])")
    found = tuple(_expect(table, f"expect[{i}]", fail) for i, table in enumerate(expects))
    named: dict[str, str] = {}
    for expect in found:  # a verdict line is known by its name
        if expect.name in named:
            raise fail(f"{expect.key}.name", f"{shown(expect.name)} is {named[expect.name]}'s name "
                       "too: each expectation's verdict is told by its name")
        named[expect.name] = expect.key
    for entry in entries:  # a script fault's end is where the scenario runs to
        f = entry.fault
        if f is not None and f.after > MAX_SCENARIO_S:
            raise fail(f"{f.key}.after", f"expected a delay in seconds, 0 .. "
                       f"{MAX_SCENARIO_S:g} (a day), got {f.after:g}")
        if f is not None and f.at is not None and f.at + (f.for_s or 0.0) > MAX_SCENARIO_S:
            raise fail(f"{f.key}.for_s", f"ends at {f.at + (f.for_s or 0.0):g} s, past "
                       f"{MAX_SCENARIO_S:g} s (a day): a scenario's times are at most that")
    for section in ("write", "snd", "command", "break", "override"):  # fault: above
        tables = raw.get(section, [])
        if not isinstance(tables, list):
            raise fail(section, f"expected an array of tables ([[{section}]])")
        for i, table in enumerate(tables):
            key = f"{section}[{i}]"
            entries.append(_entry(table, key, section, fail))
    return Script(file, tuple(entries), found)


SECTIONS = ("write", "snd", "command", "break", "override", "fault", "expect")
# The longest a scenario's times reach (an expectation's window, an entry's `at`, a fault's
# end), in seconds of machine time: a day.  `sim` runs to the last of them, scanning the PLC
# every few ms of it; a window of 1e9 s was a run of years.
MAX_SCENARIO_S: Final = 86_400.0


def _time(x: Any) -> bool:
    """A time of a scenario: a finite number of seconds, 0 .. MAX_SCENARIO_S."""
    return (not isinstance(x, bool) and isinstance(x, int | float)
            and 0 <= x <= MAX_SCENARIO_S)


def _expect(table: Any, key: str, fail: Any) -> Expect:
    if not isinstance(table, dict):
        raise fail(key, "expected a table")
    for name in table:
        if name not in ("name", "cond", "within", "by", "always"):
            raise fail(f"{key}.{name}", "unknown key (name, cond, within, by, always)")
    name, cond = table.get("name", key), table.get("cond")
    if not isinstance(name, str) or not name.strip():
        raise fail(f"{key}.name", f"expected a name, got {shown(name)}")
    if not name.isprintable():
        # A newline forged a verdict line of its own on the console, and a control character
        # made --junit's XML unreadable (XML 1.0 has no way to write one).
        raise fail(f"{key}.name", f"a name is one line of printable characters, got {shown(name)}")
    if not isinstance(cond, str) or not cond.strip():
        raise fail(f"{key}.cond", "expected a condition such as \"SA30=1\", \"P1 IDLE\", "
                   f"\"alarm AL145\", \"alarm\" or \"no alarm\"; got {shown(cond)}")
    given = [k for k in ("within", "by", "always") if k in table]
    if len(given) != 1:
        raise fail(key, "give exactly one of within = [from, to], by = T and always = true")
    window: tuple[float, float] | None = None
    if "within" in table:
        w = table["within"]
        if (not isinstance(w, list) or len(w) != 2 or not all(_time(x) for x in w)
                or w[0] > w[1]):
            raise fail(f"{key}.within", f"expected [from, to] in seconds, 0 <= from <= to <= "
                       f"{MAX_SCENARIO_S:g} (a day), got {shown(w)}")
        window = (float(w[0]), float(w[1]))
    elif "by" in table:
        b = table["by"]
        if not _time(b):
            raise fail(f"{key}.by", f"expected a time in seconds, 0 .. {MAX_SCENARIO_S:g} (a "
                       f"day), got {shown(b)}")
        window = (0.0, float(b))
    elif table["always"] is not True:
        raise fail(f"{key}.always", "expected true")
    return Expect(key, name.strip(), cond.strip(), window, window is None)


def _entry(table: Any, key: str, section: str, fail: Any) -> ScriptEntry:
    if not isinstance(table, dict):
        raise fail(key, "expected a table")
    known = {"at", "when", "after"} | {"write": {"set"}, "snd": {"from", "to"},
                                       "command": {"command", "process"},
                                       "break": {"point", "on"},
                                       "override": {"feed", "rapid", "process"}}[section]
    for name in table:
        if name not in known:
            raise fail(f"{key}.{name}", "unknown key")
    at, when = table.get("at"), table.get("when")
    if (at is None) == (when is None):
        raise fail(key, "give exactly one of 'at' and 'when'")
    if at is not None and not _time(at):
        raise fail(f"{key}.at", f"expected a time in seconds, 0 .. {MAX_SCENARIO_S:g} (a day), "
                   f"got {shown(at)}")
    if when is not None and (not isinstance(when, str) or not when.strip()):
        raise fail(f"{key}.when", f"expected a condition such as \"SA10=1\" or \"P3 WAIT_PROC\", "
                   f"got {shown(when)}")
    after = table.get("after", 0)
    if not _time(after):
        raise fail(f"{key}.after", f"expected a delay in seconds, 0 .. {MAX_SCENARIO_S:g} (a "
                   f"day), got {shown(after)}")
    if at is not None and "after" in table:
        raise fail(f"{key}.after", "only with 'when'")
    if section == "write":
        value = table.get("set")
        if not isinstance(value, str) or "=" not in value:
            raise fail(f"{key}.set", "expected an assignment such as \"SA10=1\", got "
                       f"{shown(value)}")
        return ScriptEntry(key, _f(at), when, float(after), set=value)
    if section == "override":
        values = {}
        for name in ("feed", "rapid", "process"):
            value = table.get(name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
                raise fail(f"{key}.{name}", f"expected a whole number, got {shown(value)}")
            values[name] = value
        if values["feed"] is None and values["rapid"] is None:
            raise fail(key, "give feed, rapid or both (percent)")
        return ScriptEntry(key, _f(at), when, float(after), feed=values["feed"],
                           rapid=values["rapid"], process=values["process"])
    if section == "break":
        point, on = table.get("point"), table.get("on", True)
        if not isinstance(point, str) or not point.strip():
            raise fail(f"{key}.point", f"expected a breakpoint such as \"PROG92:8\", \"N40\", "
                       f"\"P2 wait\" or \"sync\", got {shown(point)}")
        if not isinstance(on, bool):
            raise fail(f"{key}.on", f"expected true (set) or false (clear), got {shown(on)}")
        return ScriptEntry(key, _f(at), when, float(after), point=point, on=on)
    if section == "command":
        name = table.get("command")
        if not isinstance(name, str) or not name:
            raise fail(f"{key}.command", f"expected a command such as \"step\" or "
                       f"\"cycle_start\", got {shown(name)}")
        process = table.get("process")
        if process is not None and (isinstance(process, bool) or not isinstance(process, int)
                                    or process < 1):
            raise fail(f"{key}.process", f"expected a process number, got {shown(process)}")
        return ScriptEntry(key, _f(at), when, float(after), command=name, process=process)
    ends = []
    for name in ("from", "to"):
        value = table.get(name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise fail(f"{key}.{name}", f"expected a process number, got {shown(value)}")
        ends.append(value)
    return ScriptEntry(key, _f(at), when, float(after), sender=ends[0], target=ends[1])


def _f(value: Any) -> float | None:
    return None if value is None else float(value)
