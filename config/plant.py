"""The plant's tables (docs/plant.md): ``[[plant.model]]``, ``[[plant.fault]]`` and the sim
script's ``[[fault]]``, read and checked key by key.

A model's keys depend on its kind, so each kind lists its keys here once (:data:`MODEL_KEYS`):
what the reader accepts, what docs/plant.md documents and what ``ncgate map`` lists as read or
written.  Variables stay text (``"SA30"``, an I/O name of ``[symbols]``): the gateway resolves
them against the image and names the dotted key of one that is not in it.  Stdlib only.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

Fail = Callable[[str, str], Exception]  # (dotted key, message) -> the error to raise


def shown(value: object) -> str:
    """A value of a config, script or record as its file spells it, for a message: ``true``,
    ``null``, ``"text"`` (JSON and TOML alike), not Python's ``True``, ``None``, ``'text'``;
    what JSON cannot spell (a TOML date, ``nan``, ``inf``) as Python writes it, which is how
    TOML does."""
    try:
        return json.dumps(value, ensure_ascii=False, allow_nan=False)
    except (TypeError, ValueError):
        return repr(value)


# Roles of a key: "in" a variable the model reads, "out" one it writes, "ms" a time in ms > 0,
# "num" a number, "pct" a percentage, "choice:a|b" one of the words, "axis" an axis "P1.X".
MODEL_KEYS: Final[dict[str, dict[str, tuple[str, bool, Any]]]] = {
    # kind: {key: (role, required, default)}
    "delay": {"input": ("in", True, None), "output": ("out", True, None),
              "on_ms": ("ms0", False, 0.0), "off_ms": ("ms0", False, 0.0)},
    "cylinder": {"extend": ("in", True, None), "retract": ("in", False, None),
                 "extended": ("out", False, None), "retracted": ("out", False, None),
                 "position": ("out", False, None), "travel_ms": ("ms", True, None),
                 "retract_ms": ("ms", False, None)},
    "motor": {"run": ("in", True, None), "reverse": ("in", False, None),
              "speed": ("out", False, None), "at_speed": ("out", False, None),
              "standstill": ("out", False, None), "rated_rpm": ("pos", True, None),
              "ramp_rpm_s": ("pos", True, None), "tolerance": ("pct", False, 5.0)},
    "lag": {"target": ("in", True, None), "actual": ("out", True, None),
            "time_constant_ms": ("ms", True, None)},
    "generator": {"output": ("out", True, None),
                  "shape": ("choice:square|counter|sine|ramp", False, "square"),
                  "period_ms": ("period", True, None), "duty": ("frac", False, 0.5),
                  "low": ("num", False, 0.0), "high": ("num", False, 1000.0)},
    "switch": {"axis": ("axis", True, None), "output": ("out", True, None),
               "above": ("num", False, None), "below": ("num", False, None)},
}
COMMON_KEYS: Final = ("name", "kind")

# Fault kinds: which targets each takes and which keys.
FAULT_KEYS: Final[dict[str, tuple[str, ...]]] = {
    "stuck": ("value",),
    "wire_break": ("live_zero",),
    "chatter": ("period_ms",),
    "slow": ("factor",),
    "never": (),
    "exception": ("code", "unit", "addresses"),
    "delay": ("ms", "unit", "addresses"),
    "no_reply": ("unit", "addresses"),
    "heartbeat_stop": (),
    "emcy": ("code",),
    "pdo_stop": (),
}
MODEL_FAULTS: Final = frozenset({"slow", "never"})  # on a model: its behaviour
VARIABLE_FAULTS: Final = frozenset({"stuck", "wire_break", "chatter"})  # on what is read
MODBUS_FAULTS: Final = frozenset({"exception", "delay", "no_reply"})
CANOPEN_FAULTS: Final = frozenset({"heartbeat_stop", "emcy", "pdo_stop"})
WHEN_KEYS: Final = ("at", "when", "for_s")
CLEAR_KEYS: Final = ("target", "clear", "at", "when", "after")  # a script's clearing [[fault]]
# Bounds of what a fault or a generator may ask: a period shorter than a millisecond would
# make the clock take billions of steps per simulated second (a hang, not a machine), a delay
# or period over an hour or a slowing over 1,000x is no fault a commissioning rehearses.
MIN_PERIOD_MS: Final = 1.0
MAX_MS: Final = 3_600_000.0
MAX_FACTOR: Final = 1000.0
MAX_FOR_S: Final = 1e9  # a fault's own end: sooner than this (else it is one until cleared)


@dataclass(frozen=True, slots=True)
class PlantModelConfig:
    """One ``[[plant.model]]``: its name, kind and the kind's keys (:data:`MODEL_KEYS`)."""

    name: str
    kind: str
    keys: Mapping[str, Any] = field(default_factory=dict)

    def get(self, key: str) -> Any:
        return self.keys.get(key, MODEL_KEYS[self.kind][key][2])


@dataclass(frozen=True, slots=True)
class FaultConfig:
    """One ``[[plant.fault]]`` (or a script's ``[[fault]]``): what, when, for how long.
    ``at`` and ``when`` both None: at the start.  ``clear``: a script's clearing entry."""

    key: str  # "plant.fault[0]", "fault[1]": for messages
    target: str
    kind: str | None
    params: tuple[tuple[str, Any], ...] = ()
    at: float | None = None
    when: str | None = None
    after: float = 0.0
    for_s: float | None = None
    clear: bool = False


def read_models(raw: Any, key: str, fail: Fail) -> tuple[PlantModelConfig, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise fail(key, "expected an array of tables ([[plant.model]])")
    out: list[PlantModelConfig] = []
    names: set[str] = set()
    for i, table in enumerate(raw):
        item = f"{key}[{i}]"
        if not isinstance(table, dict):
            raise fail(item, "expected a table")
        name, kind = table.get("name"), table.get("kind")
        if not isinstance(name, str) or not name.strip() or not name.replace("_", "a").isalnum():
            raise fail(f"{item}.name", "expected a name of letters, digits and _, got "
                       f"{shown(name)}")
        if name in names:
            raise fail(f"{item}.name", f"{shown(name)} is the name of another model")
        names.add(name)
        if kind not in MODEL_KEYS:
            raise fail(f"{item}.kind", f"expected one of {', '.join(MODEL_KEYS)}, got "
                       f"{shown(kind)}")
        spec = MODEL_KEYS[kind]
        values: dict[str, Any] = {}
        for k, v in table.items():
            if k in COMMON_KEYS:
                continue
            if k not in spec:
                raise fail(f"{item}.{k}", f"unknown key for a {kind} (its keys: "
                           f"{', '.join(spec)})")
            values[k] = _value(spec[k][0], v, f"{item}.{k}", fail)
        for k, (_, required, _) in spec.items():
            if required and k not in values:
                raise fail(f"{item}.{k}", f"missing (a {kind} needs it)")
        if kind == "switch" and "above" not in values and "below" not in values:
            raise fail(f"{item}.above", "give above, below or both (the switch's range)")
        if kind == "switch" and "above" in values and "below" in values \
                and values["above"] >= values["below"]:
            raise fail(f"{item}.below", f"{values['below']:g} is not above above = "
                       f"{values['above']:g}: the switch is on between them, so it would "
                       "never close")
        if kind == "cylinder" and not ({"extended", "retracted", "position"} & set(values)):
            raise fail(f"{item}.extended", "a cylinder needs an output: extended, retracted "
                       "or position")
        out.append(PlantModelConfig(name, kind, values))
    return tuple(out)


def _value(role: str, v: Any, key: str, fail: Fail) -> Any:
    number = not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)
    if role in ("in", "out"):
        if not isinstance(v, str) or not v.strip():
            raise fail(key, f"expected a variable such as \"SA30\" or an I/O name, got {shown(v)}")
        return v.strip()
    if role == "axis":
        parts = v.split(".") if isinstance(v, str) else []
        if (len(parts) != 2 or parts[0][:1].upper() != "P" or not parts[0][1:].isdigit()
                or len(parts[1]) != 1 or parts[1].upper() not in "XYZUVWABC"):
            raise fail(key, f"expected a process's axis such as \"P1.X\", got {shown(v)}")
        return f"P{int(parts[0][1:])}.{parts[1].upper()}"
    if role.startswith("choice:"):
        choices = role[7:].split("|")
        if v not in choices:
            raise fail(key, f"expected one of {', '.join(choices)}, got {shown(v)}")
        return v
    if not number:
        raise fail(key, f"expected a number, got {shown(v)}")
    if role == "ms" and v <= 0:
        raise fail(key, f"expected a time in ms > 0, got {shown(v)}")
    if role == "period" and not MIN_PERIOD_MS <= v <= MAX_MS:
        raise fail(key, f"expected a period of {MIN_PERIOD_MS:g} ms .. 1 h (ms), got {shown(v)}")
    if (role in ("ms0", "pos") and v < 0) or (role == "pos" and v == 0):
        raise fail(key, f"expected a number {'> 0' if role == 'pos' else '>= 0'}, got {shown(v)}")
    if role == "pct" and not 0 <= v <= 100:
        raise fail(key, f"expected a percentage 0..100, got {shown(v)}")
    if role == "frac" and not 0 < v < 1:
        raise fail(key, f"expected a fraction between 0 and 1, got {shown(v)}")
    return float(v)


def read_faults(raw: Any, key: str, fail: Fail, *, script: bool = False
                ) -> tuple[FaultConfig, ...]:
    """``[[plant.fault]]`` (``script``: a script's ``[[fault]]``, which may ``clear``)."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise fail(key, f"expected an array of tables ([[{key}]])")
    return tuple(read_fault(table, f"{key}[{i}]", fail, script=script)
                 for i, table in enumerate(raw))


def read_fault(table: Any, key: str, fail: Fail, *, script: bool = False) -> FaultConfig:
    if not isinstance(table, dict):
        raise fail(key, "expected a table")
    target, kind = table.get("target"), table.get("kind")
    clear = table.get("clear", False)
    if not isinstance(clear, bool) or (clear and not script):
        raise fail(f"{key}.clear", "true clears the target's faults (a script's [[fault]] "
                   "only)" if script else "unknown key")
    targets = ("a model, a model's output (clamp.extended), a variable or I/O name, "
               "\"modbus\" or \"canopen\"")
    if target is None:
        raise fail(f"{key}.target", f"missing ({targets})")
    if not isinstance(target, str) or not target.strip():
        raise fail(f"{key}.target", f"expected {targets}; got {shown(target)}")
    if clear:
        if target == "all":
            target = "*"
        for name in table:
            if name not in CLEAR_KEYS:
                # A clear ends every fault of its target, whatever their kind: a kind or a
                # kind's key on it would say it clears only those, which it does not.
                raise fail(f"{key}.{name}", f"a clear takes no {name}: it clears every fault "
                           f"of its target (its keys: {', '.join(CLEAR_KEYS)})")
    else:
        if kind is None:
            raise fail(f"{key}.kind", f"missing (one of {', '.join(FAULT_KEYS)}"
                       + (", or clear = true" if script else "") + ")")
        if kind not in FAULT_KEYS:
            raise fail(f"{key}.kind", f"expected one of {', '.join(FAULT_KEYS)}, "
                       f"got {shown(kind)}")
        known = {"target", "kind", "at", "when", "after", "for_s", *FAULT_KEYS[kind]}
        if script:
            known.add("clear")
        for name in table:
            if name not in known:
                raise fail(f"{key}.{name}", f"unknown key for a {kind} fault (its keys: "
                           f"{', '.join(FAULT_KEYS[kind]) or 'none'})")
    at, when, after = table.get("at"), table.get("when"), table.get("after", 0)
    if at is not None and when is not None:
        raise fail(key, "give at most one of 'at' and 'when'")
    for name, v in (("at", at), ("after", after), ("for_s", table.get("for_s"))):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)
                              or not math.isfinite(v) or v < 0):
            raise fail(f"{key}.{name}", f"expected a time in seconds >= 0, got {shown(v)}")
    for_s = table.get("for_s")
    if for_s is not None and not 0 < for_s < MAX_FOR_S:
        raise fail(f"{key}.for_s", f"expected a time in seconds > 0 and < {MAX_FOR_S:g}, "
                   f"got {shown(for_s)}")
    if when is not None and (not isinstance(when, str) or not when.strip()):
        raise fail(f"{key}.when", f"expected a condition such as \"SA10=1\" or \"P1 "
                   f"WAIT_COND\", got {shown(when)}")
    if "after" in table and when is None:
        raise fail(f"{key}.after", "only with 'when'")
    params = [] if clear or kind is None else fault_params(kind, table, key, fail)
    for_s = table.get("for_s")
    return FaultConfig(key, target.strip(), None if clear else kind, tuple(params),
                       None if at is None else float(at), when, float(after),
                       None if for_s is None else float(for_s), clear)


def fault_input(kind: object, params: Mapping[str, Any], for_s: object,
                refuse: Callable[[str], Exception]) -> list[tuple[str, Any]]:
    """A fault input's kind, parameters and ``for_s`` as any cell's plant takes them (the
    plant's check, and a record's reader before a replay: what needs no cell): its
    parameters, checked and with their defaults; ``refuse(message)`` the error otherwise."""
    if not isinstance(kind, str) or kind not in FAULT_KEYS:
        raise refuse(f"fault kind {shown(kind)}: one of {', '.join(FAULT_KEYS)}")
    if for_s is not None and (isinstance(for_s, bool) or not isinstance(
            for_s, int | float) or not 0 < for_s < MAX_FOR_S):
        raise refuse(f"for_s: a time in seconds > 0 and < {MAX_FOR_S:g}, not {shown(for_s)}")
    unknown = sorted(set(params) - set(FAULT_KEYS[kind]))
    if unknown:
        raise refuse(f"a {kind} fault takes {', '.join(FAULT_KEYS[kind]) or 'no parameter'}, "
                     f"not {', '.join(unknown)}")
    return fault_params(kind, params, kind,
                        lambda where, message: refuse(f"{where}: {message}"))


def fault_params(kind: str, table: Mapping[str, Any], key: str, fail: Fail
                 ) -> list[tuple[str, Any]]:
    """The parameters of a fault of ``kind`` from ``table`` (a config table, an API body),
    checked and with their defaults, sorted by name."""
    out: dict[str, Any] = {}
    for name in FAULT_KEYS[kind]:
        v = table.get(name)
        where = f"{key}.{name}"
        if name == "value":
            if v is None:
                raise fail(where, "missing (the value the variable is stuck at)")
            if isinstance(v, bool) or not isinstance(v, int):
                raise fail(where, f"expected a whole number, got {shown(v)}")
        elif name in ("period_ms", "factor", "ms"):
            default = {"period_ms": 100.0, "factor": 2.0, "ms": 100.0}[name]
            # A slow fault's factor is 1 or more: below 1 it sped a model up, and shrank a
            # 1 ms generator's period past MIN_PERIOD_MS with no end (a sim that never got
            # on, a run flooding its log).
            low, high = {"period_ms": (MIN_PERIOD_MS, MAX_MS), "factor": (1.0, MAX_FACTOR),
                         "ms": (0.0, MAX_MS)}[name]
            v = default if v is None else v
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or v <= 0 or not low <= v <= high:
                raise fail(where, f"expected a number > 0 and <= {high:g}, got {shown(v)}"
                           if not low else f"expected {low:g}..{high:g}, got {shown(v)}")
            v = float(v)
        elif name == "live_zero":
            v = 0 if v is None else v
            if isinstance(v, bool) or not isinstance(v, int):
                raise fail(where, f"expected a whole number, got {shown(v)}")
        elif name == "code":
            default = 6 if kind == "exception" else 0x1000
            v = default if v is None else v
            hi = 255 if kind == "exception" else 0xFFFF
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= hi:
                raise fail(where, f"expected a code 1..{hi}, got {shown(v)}")
        elif name == "unit":
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 255:
                raise fail(where, f"expected a unit id 0..255, got {shown(v)}")
        elif name == "addresses":
            if v is None:
                continue
            if (not isinstance(v, list | tuple) or len(v) != 2
                    or any(isinstance(a, bool) or not isinstance(a, int) or not 0 <= a <= 65535
                           for a in v) or v[0] > v[1]):
                raise fail(where, f"expected [first, last] protocol addresses, got {shown(v)}")
            v = (v[0], v[1])
        out[name] = v
    return sorted(out.items())
