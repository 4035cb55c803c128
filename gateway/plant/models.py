"""The plant's built-in models (docs/plant.md has each one's timing diagram).

A model is event-driven on the engine's clock: it is told when one of its inputs changes
(:meth:`Model.command`) and when the time it asked for has come (:meth:`Model.advance`), and
each time it returns the next switch point it wants to be called at (None: not until an input
changes).  Switch points (an end switch, "at speed", a relay) fall at their exact time; what
moves continuously (a position, a speed, a lag, a sine) says so with :attr:`Model.sampled`,
and the plant samples it on its tick, every ``plant.scan_ms`` while it moves.
So a plant that stands still costs nothing, and ``ncgate sim`` runs it far faster than real
time.

A model reads and writes through its :class:`Host` (the plant); it never touches the image or
the engine itself.  ``outputs()`` is what the model drives now; the plant writes what changed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

from ncgate.config.plant import MODEL_KEYS, PlantModelConfig

EPS = 1e-9  # seconds: a timer that fires a hair before its time is on time


class Host(Protocol):
    def read(self, key: str) -> int: ...  # the model's input by its key ("extend")
    def axis(self, text: str) -> float: ...  # "P1.X": that axis's position now


class Model:
    """One model: its config, its behaviour fault (``never``, ``slow``), what it is doing."""

    kind = ""
    states: tuple[str, ...] = ("at rest",)  # what ``state`` may say
    inputs: tuple[str, ...] = ()  # the keys that name variables it reads
    outputs_keys: tuple[str, ...] = ()  # the keys that name variables it writes

    def __init__(self, config: PlantModelConfig, host: Host, scan_s: float) -> None:
        self.config = config
        self.name = config.name
        self.host = host
        self.scan_s = scan_s
        self.never = False  # fault "never": it does not move, whatever it is told
        self.factor = 1.0  # fault "slow": its times multiplied
        self.state = "at rest"
        self.since = 0.0
        self.progress: tuple[float, float] | None = None  # (done s, of s) of the current move
        self.on_state: Callable[[], None] | None = None  # told of each change of ``state``
        # Every key of its kind, its default filled in: read on every step.
        self._keys = {name: config.get(name) for name in MODEL_KEYS[config.kind]}

    def _state(self, now: float, state: str) -> None:
        if state != self.state:
            self.state, self.since = state, now
            if self.on_state is not None:
                self.on_state()

    def start(self, now: float) -> float | None:
        return self.command(now)

    def command(self, now: float) -> float | None:
        """An input changed (or a fault did): act on it."""
        raise NotImplementedError

    def advance(self, now: float) -> float | None:
        """The time asked for has come."""
        raise NotImplementedError

    def outputs(self, now: float) -> dict[str, int]:
        """What the model drives now, by output key."""
        raise NotImplementedError

    @property
    def sampled(self) -> bool:
        """A continuous output of it moves now: the plant's tick writes it."""
        return False

    def quiet_until(self, now: float, written: dict[str, int]) -> float:
        """While it is sampled: a time before which its outputs, as the tick writes them,
        stay ``written`` (what was written last) -- so the ticks before it would write nothing
        and need not come.  Never later than the first change: early is only a tick that
        writes nothing.  ``now``: the next tick is due as ever."""
        return now

    @property
    def free_running(self) -> bool:
        """It never stands still by itself (a generator, an axis switch)."""
        return False

    def set_fault(self, now: float, never: bool, factor: float) -> float | None:
        self.settle(now)
        self.never, self.factor = never, factor
        return self.command(now)

    def settle(self, now: float) -> None:
        """Bring the model's state to ``now`` before its rules change (a fault)."""

    def progress_at(self, now: float) -> tuple[float, float] | None:
        """(done, of) seconds of the move under way at ``now``; None: none."""
        return self.progress

    def key(self, name: str) -> Any:
        return self._keys[name]

    def describe(self, now: float) -> str:
        """"clamp extends, 120 of 300 ms": the why-record of a wait on its output."""
        text = f"{self.name} {self.state}"
        progress = self.progress_at(now)
        if progress is not None:
            done, total = progress
            done = min(max(0.0, done), total)  # (the wall clock may be past its end)
            text += f", {done * 1000:.0f} of {total * 1000:.0f} ms"
        if self.never:
            text += " (fault: never)"
        elif self.factor != 1.0:
            text += f" (fault: slow x{self.factor:g})"
        return text


class Delay(Model):
    """``input`` -> ``output`` after ``on_ms`` (rising) / ``off_ms`` (falling); an input that
    goes back before its time leaves the output as it was (a relay, a pressure switch)."""

    kind = "delay"
    states = ("at rest", "on", "off", "switching on", "switching off")
    inputs = ("input",)
    outputs_keys = ("output",)

    def __init__(self, config: PlantModelConfig, host: Host, scan_s: float) -> None:
        super().__init__(config, host, scan_s)
        self.out = 0
        self.due: float | None = None
        self.started = 0.0

    def command(self, now: float) -> float | None:
        if self.never:
            self.due = None
            self.progress = None
            return None
        want = 1 if self.host.read("input") else 0
        if want == self.out:
            self.due = None
            self.progress = None
            self._state(now, "on" if self.out else "off")
            return None
        if self.due is None:
            ms = self.key("on_ms") if want else self.key("off_ms")
            self.started = now
            self.due = now + ms / 1000.0 * self.factor
            self._state(now, "switching on" if want else "switching off")
        return self.advance(now)

    def advance(self, now: float) -> float | None:
        if self.due is None:
            return None
        if now + EPS >= self.due:
            self.out = 1 - self.out
            self.due = None
            self.progress = None
            self._state(now, "on" if self.out else "off")
            return None
        self.progress = (now - self.started, self.due - self.started)
        return self.due

    def progress_at(self, now: float) -> tuple[float, float] | None:
        if self.due is None:
            return None
        return (now - self.started, self.due - self.started)

    def outputs(self, now: float) -> dict[str, int]:
        return {"output": self.out}


class Cylinder(Model):
    """Valve ``extend`` (and ``retract``; without it a spring returns the rod) -> end
    switches ``extended`` / ``retracted`` after ``travel_ms`` / ``retract_ms``; both off while
    it travels; ``position`` in per mille of the stroke.  A double-acting valve with both or
    neither coil on holds the rod where it is."""

    kind = "cylinder"
    states = ("retracted", "extends", "extended", "retracts", "stopped mid-stroke")
    inputs = ("extend", "retract")
    outputs_keys = ("extended", "retracted", "position")

    def __init__(self, config: PlantModelConfig, host: Host, scan_s: float) -> None:
        super().__init__(config, host, scan_s)
        self.pos = 0.0  # 0 retracted .. 1 extended, at t_ref
        self.dir = 0
        self.t_ref = 0.0
        self.arrive: float | None = None
        self.state = "retracted"

    def _time(self, direction: int) -> float:
        ms = self.key("travel_ms") if direction > 0 else (
            self.key("retract_ms") or self.key("travel_ms"))
        return float(ms) / 1000.0 * self.factor

    def _pos(self, now: float) -> float:
        if not self.dir:
            return self.pos
        if self.arrive is not None and now + EPS >= self.arrive:
            return 1.0 if self.dir > 0 else 0.0
        p = self.pos + self.dir * (now - self.t_ref) / self._time(self.dir)
        return min(1.0, max(0.0, p))

    def settle(self, now: float) -> None:
        self.pos, self.t_ref = self._pos(now), now

    def command(self, now: float) -> float | None:
        self.settle(now)
        if self.never:
            want = 0
        elif self.config.keys.get("retract") is not None:
            ext, ret = self.host.read("extend"), self.host.read("retract")
            want = 1 if ext and not ret else -1 if ret and not ext else 0
        else:
            want = 1 if self.host.read("extend") else -1
        if (want > 0 and self.pos >= 1.0) or (want < 0 and self.pos <= 0.0):
            want = 0
        self.dir = want
        if want:
            remaining = (1.0 - self.pos) if want > 0 else self.pos
            self.arrive = now + remaining * self._time(want)
            self._state(now, "extends" if want > 0 else "retracts")
        else:
            self.arrive = None
            self.progress = None
            self._state(now, "extended" if self.pos >= 1.0 else "retracted"
                        if self.pos <= 0.0 else "stopped mid-stroke")
        return self.advance(now)

    def advance(self, now: float) -> float | None:
        if not self.dir or self.arrive is None:
            return None
        if now + EPS >= self.arrive:
            self.pos = 1.0 if self.dir > 0 else 0.0
            self.dir, self.arrive, self.t_ref, self.progress = 0, None, now, None
            self._state(now, "extended" if self.pos >= 1.0 else "retracted")
            return None
        total = self._time(self.dir)
        self.progress = (total - (self.arrive - now), total)
        return self.arrive

    @property
    def sampled(self) -> bool:
        return self.dir != 0 and self.has_position

    def progress_at(self, now: float) -> tuple[float, float] | None:
        if not self.dir or self.arrive is None:
            return None
        total = self._time(self.dir)
        return (total - (self.arrive - now), total)

    @property
    def has_position(self) -> bool:
        return self.config.keys.get("position") is not None

    def outputs(self, now: float) -> dict[str, int]:
        p = self._pos(now)
        moving = self.dir != 0  # the rod leaves its end switch as the valve switches
        return {"extended": 1 if p >= 1.0 and not moving else 0,
                "retracted": 1 if p <= 0.0 and not moving else 0,
                "position": round(p * 1000)}


class Motor(Model):
    """``run`` (``reverse``: the other way) -> ``speed`` in rpm ramping at ``ramp_rpm_s`` to
    ``rated_rpm`` and back to 0; ``at_speed`` within ``tolerance`` % of the rated speed;
    ``standstill`` at 0 with no run command (it drops as the motor is told to run)."""

    kind = "motor"
    states = ("stands still", "runs up", "at speed", "runs down")
    inputs = ("run", "reverse")
    outputs_keys = ("speed", "at_speed", "standstill")

    def __init__(self, config: PlantModelConfig, host: Host, scan_s: float) -> None:
        super().__init__(config, host, scan_s)
        self.v = 0.0
        self.t_ref = 0.0
        self.target = 0.0
        self.state = "stands still"

    def _rate(self) -> float:
        return float(self.key("ramp_rpm_s")) / self.factor

    def _v(self, now: float) -> float:
        if self.v == self.target:
            return self.v
        step = self._rate() * (now - self.t_ref)
        if abs(self.target - self.v) <= step + EPS * self._rate():
            return self.target
        return self.v + math.copysign(step, self.target - self.v)

    def _band(self) -> float:
        return float(self.key("rated_rpm")) * float(self.key("tolerance")) / 100.0

    def settle(self, now: float) -> None:
        self.v, self.t_ref = self._v(now), now

    def command(self, now: float) -> float | None:
        self.settle(now)
        if self.never:
            self.target = self.v
        else:
            rated = float(self.key("rated_rpm"))
            run = self.host.read("run")
            reverse = self.config.keys.get("reverse") is not None and self.host.read("reverse")
            self.target = (-rated if reverse else rated) if run else 0.0
        return self.advance(now)

    def advance(self, now: float) -> float | None:
        v = self._v(now)
        if v == self.target:
            self.v, self.t_ref, self.progress = v, now, None
            self._state(now, "stands still" if v == 0 else "at speed")
            return None
        self._state(now, "runs up" if abs(self.target) > abs(v) else "runs down")
        rate = self._rate()
        reach = now + abs(self.target - v) / rate
        self.progress = (now - self.t_ref, reach - self.t_ref)
        nxt = reach
        band = self._band()
        if self.target and abs(v - self.target) > band + 1e-6:  # when it comes within band
            nxt = min(nxt, now + (abs(v - self.target) - band) / rate)
        return nxt

    @property
    def sampled(self) -> bool:
        return self.v != self.target and self.config.keys.get("speed") is not None

    def progress_at(self, now: float) -> tuple[float, float] | None:
        if self.v == self.target:
            return None
        return (now - self.t_ref, abs(self.target - self.v) / self._rate())

    def outputs(self, now: float) -> dict[str, int]:
        v = self._v(now)
        at = 1 if self.target and abs(v - self.target) <= self._band() + 1e-6 else 0
        return {"speed": max(-32768, min(32767, round(v))), "at_speed": at,
                "standstill": 1 if v == 0 and self.target == 0 else 0}


class Lag(Model):
    """A first-order lag from ``target`` to ``actual`` with ``time_constant_ms`` (a
    temperature, a pressure, an analogue axis): written every scan until it is within half a
    unit of the target, then the target exactly."""

    kind = "lag"
    states = ("settled", "follows")
    inputs = ("target",)
    outputs_keys = ("actual",)

    def __init__(self, config: PlantModelConfig, host: Host, scan_s: float) -> None:
        super().__init__(config, host, scan_s)
        self.a0 = 0.0
        self.t_ref = 0.0
        self.target = 0.0
        self.state = "settled"

    def _tau(self) -> float:
        return float(self.key("time_constant_ms")) / 1000.0 * self.factor

    def settle(self, now: float) -> None:
        self.a0, self.t_ref = self._a(now), now

    def command(self, now: float) -> float | None:
        self.settle(now)
        self.target = self.a0 if self.never else float(self.host.read("target"))
        return self.advance(now)

    def _settle_at(self) -> float:
        """When it comes within half a unit of the target: tau * ln(2 |a0 - target|)."""
        return self.t_ref + self._tau() * math.log(2 * abs(self.a0 - self.target))

    def _a(self, now: float) -> float:
        if self.a0 == self.target or now + EPS >= self._settle_at():
            return self.target
        return self.target + (self.a0 - self.target) * math.exp(-(now - self.t_ref)
                                                                 / self._tau())

    def advance(self, now: float) -> float | None:
        a = self._a(now)
        if a == self.target:
            self.a0, self.t_ref = a, now
            self._state(now, "settled")
            return None
        self._state(now, "follows")
        return self._settle_at()

    @property
    def sampled(self) -> bool:
        return self.a0 != self.target

    def quiet_until(self, now: float, written: dict[str, int]) -> float:
        """The settling tail moves the value by less than a unit a tick: the rounded value
        changes when the lag crosses the next half unit towards the target, at
        ``t_ref - tau * ln((edge - target) / (a0 - target))`` -- less a microsecond, so that
        float noise never puts it past the tick that changes it (an early one writes
        nothing, and the next is worked out from there)."""
        value = written.get("actual")
        if value is None or self.a0 == self.target or abs(value) >= 32767:
            return now
        edge = value + (0.5 if self.target > self.a0 else -0.5)
        ratio = (edge - self.target) / (self.a0 - self.target)
        if not 0.0 < ratio < 1.0:
            return now  # the edge is past the target (it settles first) or behind it
        return min(self.t_ref - self._tau() * math.log(ratio), self._settle_at()) - 1e-6

    def outputs(self, now: float) -> dict[str, int]:
        return {"actual": max(-32768, min(32767, round(self._a(now))))}


class Generator(Model):
    """``output`` as a ``square`` wave (``period_ms``, ``duty``), a ``counter`` (one more
    every ``period_ms``: a light barrier counting parts), a ``sine`` or a ``ramp`` between
    ``low`` and ``high`` -- from t = 0, free running."""

    kind = "generator"
    states = ("square", "counter", "sine", "ramp")  # its shape: it never stops
    outputs_keys = ("output",)

    def __init__(self, config: PlantModelConfig, host: Host, scan_s: float) -> None:
        super().__init__(config, host, scan_s)
        self.t0 = 0.0
        self.frozen: tuple[float, int] | None = None  # (phase, count) while "never"
        self.count = 0
        self.phase = 0.0  # periods done at t_ref
        self.t_ref = 0.0
        self.state = str(self.key("shape"))

    def _period(self) -> float:
        return float(self.key("period_ms")) / 1000.0 * self.factor

    def _phase(self, now: float) -> float:
        if self.never:
            return self.phase
        return self.phase + (now - self.t_ref) / self._period()

    def settle(self, now: float) -> None:
        self.phase, self.t_ref = self._phase(now), now

    def command(self, now: float) -> float | None:
        self.settle(now)
        return self.advance(now)

    def advance(self, now: float) -> float | None:
        if self.never:
            return None
        phase = self._phase(now) + EPS
        shape = self.key("shape")
        if shape in ("sine", "ramp"):
            return None  # sampled on the plant's tick
        whole, frac = math.floor(phase), phase - math.floor(phase)
        duty = float(self.key("duty")) if shape == "square" else 1.0
        edge = whole + (duty if frac < duty else 1.0)
        return now + (edge - self._phase(now)) * self._period()

    @property
    def sampled(self) -> bool:
        return not self.never and self.key("shape") in ("sine", "ramp")

    @property
    def free_running(self) -> bool:
        return True

    def outputs(self, now: float) -> dict[str, int]:
        phase = self._phase(now) + EPS
        shape = self.key("shape")
        low, high = float(self.key("low")), float(self.key("high"))
        frac = phase - math.floor(phase)
        if shape == "square":
            return {"output": 1 if frac < float(self.key("duty")) else 0}
        if shape == "counter":
            return {"output": math.floor(phase) % 32768}
        if shape == "sine":
            value = low + (high - low) * (0.5 + 0.5 * math.sin(2 * math.pi * frac))
        else:
            value = low + (high - low) * frac
        return {"output": max(-32768, min(32767, round(value)))}


class Switch(Model):
    """An input from an NC axis: ``output`` is 1 while process k's axis (``axis = "P1.X"``)
    is above ``above`` (and below ``below``): a reference or a limit switch that follows the
    part program's motion, sampled every scan."""

    kind = "switch"
    states = ("at rest", "on", "off")
    outputs_keys = ("output",)

    def command(self, now: float) -> float | None:
        return None  # sampled on the plant's tick

    def advance(self, now: float) -> float | None:
        return None

    @property
    def sampled(self) -> bool:
        return not self.never

    @property
    def free_running(self) -> bool:
        return True

    def outputs(self, now: float) -> dict[str, int]:
        if self.never:
            return {}
        x = self.host.axis(str(self.key("axis")))
        above, below = self.key("above"), self.key("below")
        on = (above is None or x > above) and (below is None or x < below)
        self._state(now, "on" if on else "off")
        return {"output": 1 if on else 0}


KINDS: dict[str, Callable[[PlantModelConfig, Host, float], Model]] = {
    cls.kind: cls for cls in (Delay, Cylinder, Motor, Lag, Generator, Switch)}
