"""A virtual PLC over Modbus TCP, for integration tests (spec 4.5).

It speaks the map in force (``ncgate.gateway.modbus.map``) through pymodbus's client, so a test
plays the PLC with the real protocol:

    plc = VirtualPLC("127.0.0.1", port, config)
    await plc.connect()
    await plc.wait_state(2, "WAIT_COND")     # process 2 waits at N40 ...
    await plc.set("SA10", 1)                 # ... for the PLC to set SA10
    snd = await plc.next_snd()               # the next SND the gateway reports
    await plc.expect_aux("M08")              # P1 outputs M08 with its strobe ([nc.aux])
    await plc.ack_aux()                      # acknowledge, strobe drops, drop the ack

A Modbus client learns of changes only by reading: the ``wait_*``/``next_*``/``expect_*``
helpers poll every ``poll_s`` until what they wait for is there or ``timeout_s`` runs out.
Each round checks the wait's own deadline, and each read is bounded by the time left, so a
wait always ends by its deadline: one ``asyncio.timeout()`` around the whole loop did not,
because the client's call can return an answer that arrived together with the cancellation
(Python 3.11's ``asyncio.wait_for``, which pymodbus awaits each answer with, drops the
cancellation then) and the loop polled on for ever.  When a wait fails, its message has
every process's status as the gateway reports it (what ``Gateway.wait_idle`` says from the
engine), read within ``EXPLAIN_S`` more.
"""

from __future__ import annotations

import asyncio
import os
import re
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TypeVar, overload

from pymodbus import FramerType
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from ncgate.config import Config
from ncgate.gateway.errors import VirtualPLCError
from ncgate.gateway.modbus.map import ModbusMap
from ncgate.gateway.wiring import image_var, parse_assignment
from ncgate.interpreter.engine import ProcessState, WaitKind
from ncgate.plc.scan import PlcState

T = TypeVar("T")
# After a wait's deadline, at most this long to read the statuses its failure message shows
# (a gateway that does not answer gets the message without them).
EXPLAIN_S = 0.5


@dataclass(frozen=True, slots=True)
class SndSeen:
    sender: int
    target: int  # 0: a broadcast (an ISG signal to every channel)
    n: int  # the N number of the SND block (0 when none)
    seq: int  # its sequence number in the SND log (1, 2, ... since the gateway started)
    id: int = 0  # an ISG signal's number (0 for an SND)


def _int32(hi: int, lo: int) -> int:
    value = hi << 16 | lo
    return value - 0x1_0000_0000 if value & 0x8000_0000 else value


@dataclass(frozen=True, slots=True)
class ProcessSeen:
    """Process k's status block as a Modbus client reads it (``modbus.map.status``).

    Indexing reads the 18 registers by position, as :meth:`VirtualPLC.status` once returned
    them (``status[1]`` the block N, ``status[6:8]`` the SNDs sent)."""

    process: int
    state: ProcessState
    n: int  # the block's N number (0: none)
    line: int  # its source line
    wait_kind: WaitKind
    wait_target: int  # the process (or channel) waited for; 0 when none
    alarm_code: int  # 0: no alarm
    snds_sent: int
    snds_received: int
    blocks: int  # blocks executed
    position_um: tuple[int, int, int]  # X, Y, Z
    registers: tuple[int, ...]

    @classmethod
    def from_registers(cls, process: int, r: list[int]) -> ProcessSeen:
        return cls(process, ProcessState(r[0]), r[1], r[2], WaitKind(r[3]), r[4], r[5],
                   r[6] << 16 | r[7], r[8] << 16 | r[9], r[10] << 16 | r[11],
                   (_int32(r[12], r[13]), _int32(r[14], r[15]), _int32(r[16], r[17])),
                   tuple(r))

    @overload
    def __getitem__(self, at: int) -> int: ...

    @overload
    def __getitem__(self, at: slice) -> list[int]: ...

    def __getitem__(self, at: int | slice) -> int | list[int]:
        return list(self.registers[at]) if isinstance(at, slice) else self.registers[at]

    def why(self) -> str:
        """One line, as a why-record says it: ``P2 WAIT_COND at line 3 N40, wait COND 0``."""
        text = f"P{self.process} {self.state.name} at line {self.line}"
        if self.n:
            text += f" N{self.n}"
        if self.wait_kind is not WaitKind.NONE:
            text += f", wait {self.wait_kind.name} {self.wait_target}"
        if self.alarm_code:
            text += f", alarm AL{self.alarm_code}"
        return text


@dataclass(frozen=True, slots=True)
class PlcSeen:
    """The PLC status as a Modbus client reads it."""

    state: PlcState
    scans: int
    last_scan_us: int
    max_scan_us: int
    overruns: int
    fault_line: int
    late_us: int = 0  # how late the last scan started
    max_late_us: int = 0  # the largest lateness since the PLC started


@dataclass(frozen=True, slots=True)
class AuxSeen:
    """An auxiliary function the NC outputs with its strobe up ([nc.aux])."""

    process: int
    letter: str  # M, S, T, H
    value: int

    @property
    def code(self) -> str:
        """As the trace names it: ``M8``, ``T5``."""
        return f"{self.letter}{self.value}"


_AUX_CODE = re.compile(r"([MSTH])(-?\d+)$", re.IGNORECASE)


class VirtualPLC:
    def __init__(self, host: str, port: int, config: Config, unit: int | None = None,
                 poll_s: float = 0.005, *,
                 client: AsyncModbusTcpClient | AsyncModbusSerialClient | None = None) -> None:
        self.map = ModbusMap(config)
        self.config = config
        self._symbols = {name.upper(): str(image_var(text))
                         for name, text in config.symbols.items()}
        self.unit = unit if unit is not None else config.modbus.unit_ids[0]
        self.poll_s = poll_s
        self.client = client or AsyncModbusTcpClient(host, port=port, retries=0)
        self._last_seq = 0  # the newest SND log entry this client has returned

    @classmethod
    def rtu(cls, device: str, config: Config, unit: int | None = None,
            poll_s: float = 0.02) -> VirtualPLC:
        """The same PLC as a Modbus RTU master on the serial port ``device`` (the other end
        of ``modbus.rtu.port``'s line: ``ncgate_rtu_line.plc_end``), with the line settings
        of ``[modbus.rtu]`` and its first unit id."""
        rtu = config.modbus.rtu
        units = config.modbus.rtu_unit_ids
        # A pty carries no parity bit: Linux's pty driver drops PARENB from what is set, and
        # pymodbus's serial transport, which sets the port up twice, then fails (EINVAL) on
        # the second -- so on a pty the client asks for none.  The gateway's side sets its
        # port up once and keeps [modbus.rtu] parity.
        pty = os.path.realpath(device).startswith("/dev/pts/")
        client = AsyncModbusSerialClient(device, framer=FramerType.RTU, baudrate=rtu.baudrate,
                                         bytesize=rtu.bytesize,
                                         parity="N" if pty else rtu.parity.value,
                                         stopbits=rtu.stopbits, retries=0, timeout=2)
        return cls("", 0, config, unit if unit is not None else (units or (1,))[0], poll_s,
                   client=client)

    async def connect(self) -> None:
        if not await self.client.connect():
            raise VirtualPLCError("cannot connect to the gateway")
        hi, lo = await self._input(self.map.SND_LOG_BASE, 2)
        self._last_seq = hi << 16 | lo  # SNDs from now on

    def close(self) -> None:
        self.client.close()

    async def __aenter__(self) -> VirtualPLC:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    # -- raw access -----------------------------------------------------------------------

    @staticmethod
    def _check(response: object) -> None:
        if response.isError():  # type: ignore[attr-defined]
            raise VirtualPLCError(f"the gateway answered {response}")

    async def _input(self, address: int, count: int) -> list[int]:
        r = await self.client.read_input_registers(address, count=count, device_id=self.unit)
        self._check(r)
        return list(r.registers)

    async def _holding(self, address: int, count: int) -> list[int]:
        r = await self.client.read_holding_registers(address, count=count, device_id=self.unit)
        self._check(r)
        return list(r.registers)

    async def _write(self, address: int, values: list[int]) -> None:
        r = await self.client.write_registers(address, values, device_id=self.unit)
        self._check(r)

    # -- the image --------------------------------------------------------------------------

    def _named(self, var: str) -> str:
        """``var`` as the image names it: an I/O name of ``[symbols]`` (any case) is the
        variable it stands for (``clamp_valve`` -> ``SA20``; a K byte is the SK packet's)."""
        return self._symbols.get(var.strip().upper(), var)

    async def set(self, var: str, value: int) -> None:
        """Write SA10 (a coil), SA1.BY, SK250, SK2.IN, SYVAR1, or an I/O name of
        ``[symbols]`` … as the PLC."""
        (area, index, view), number = parse_assignment(f"{self._named(var)}={value}")
        m = self.map
        if area == "SA" and view == "bit":
            r = await self.client.write_coil(index, bool(number), device_id=self.unit)
            self._check(r)
        elif area == "SYVAR":
            await self._write(m.SYVAR_BASE + index, [number & 0xFFFF])
        else:
            base = m.K_BASE if area == "SK" else m.SA_BYTE_BASE
            if view == "BY":
                await self._write(base + index, [number])
            else:  # .IN: two bytes, little-endian, in one request
                word = number & 0xFFFF
                await self._write(base + index, [word & 0xFF, word >> 8])

    async def get(self, var: str) -> int:
        (area, index, view), _ = parse_assignment(f"{self._named(var)}=0")
        m = self.map
        if area == "SA" and view == "bit":
            r = await self.client.read_coils(index, count=1, device_id=self.unit)
            self._check(r)
            return int(r.bits[0])
        if area == "SYVAR":
            (v,) = await self._holding(m.SYVAR_BASE + index, 1)
            return v - 0x10000 if v & 0x8000 else v
        base = m.K_BASE if area == "SK" else m.SA_BYTE_BASE
        if view == "BY":
            (v,) = await self._holding(base + index, 1)
            return v
        lo, hi = await self._holding(base + index, 2)
        word = lo | hi << 8
        return word - 0x10000 if word & 0x8000 else word

    # -- processes ----------------------------------------------------------------------------

    async def status(self, process: int) -> ProcessSeen:
        """Process k's status block: state, N, line, wait kind and target, alarm, counters,
        position (indexing it reads the 18 registers by position)."""
        base = self.map.STATUS_BASE + self.map.STATUS_STRIDE * (process - 1)
        return ProcessSeen.from_registers(process, await self._input(base, 18))

    async def _statuses(self) -> list[ProcessSeen]:
        """Every process's status block, six to a request (a read takes 125 registers)."""
        stride, processes = self.map.STATUS_STRIDE, self.config.nc.processes
        out: list[ProcessSeen] = []
        for first in range(1, processes + 1, 6):
            count = min(6, processes - first + 1)
            regs = await self._input(self.map.STATUS_BASE + stride * (first - 1),
                                     stride * count)
            out += [ProcessSeen.from_registers(first + i, regs[stride * i:stride * i + 18])
                    for i in range(count)]
        return out

    async def state(self, process: int) -> ProcessState:
        return (await self.status(process)).state

    async def _until(self, probe: Callable[[], Awaitable[T | None]], timeout_s: float,
                     failed: Callable[[], str]) -> T:
        """Poll ``probe`` until it returns something; VirtualPLCError with ``failed()`` and
        every process's status once ``timeout_s`` has passed.

        The deadline is checked each round and bounds each round's read, so the wait ends by
        it even when a read returns an answer that came with its cancellation (the module's
        docstring)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while loop.time() < deadline:
            try:
                async with asyncio.timeout_at(deadline) as bound:
                    found = await probe()
            except TimeoutError:
                if not bound.expired():
                    raise
                break
            if found is not None:
                return found
            if loop.time() >= deadline:
                break
            # A Modbus client learns only by reading: poll.
            await asyncio.sleep(min(self.poll_s, deadline - loop.time()))
        raise VirtualPLCError(f"{failed()}\n{await self._why()}")

    async def _why(self) -> str:
        """Every process's status, one line each (the why-records a Modbus client can read),
        read within EXPLAIN_S."""
        try:
            async with asyncio.timeout(EXPLAIN_S):
                seen = await self._statuses()
        except (TimeoutError, ModbusException, VirtualPLCError) as exc:
            return f"(the processes' status could not be read in {EXPLAIN_S:g} s: {exc!r})"
        return "\n".join(s.why() for s in seen)

    async def wait_state(self, process: int, state: str | ProcessState,
                         timeout_s: float = 10.0) -> ProcessSeen:
        """Until process k is in ``state``; returns its status then."""
        wanted = state if isinstance(state, ProcessState) else ProcessState[state.upper()]
        last: ProcessSeen | None = None

        async def there() -> ProcessSeen | None:
            nonlocal last
            last = await self.status(process)
            return last if last.state is wanted else None

        return await self._until(there, timeout_s, lambda: (
            f"P{process} not {wanted.name} in {timeout_s:g} s"
            + (f" (it is {last.state.name})" if last is not None else " (no status was read)")))

    async def plc_status(self) -> PlcSeen:
        """The PLC status block (input registers ``modbus.map.plc_status``..+13)."""
        r = await self._input(self.map.PLC_BASE, 14)
        return PlcSeen(PlcState(r[0]), r[1] << 16 | r[2], r[3] << 16 | r[4], r[5] << 16 | r[6],
                       r[7] << 16 | r[8], r[9], r[10] << 16 | r[11], r[12] << 16 | r[13])

    async def command(self, word: int) -> None:
        """1 cycle start, 2 feed hold, 3 reset."""
        await self._write(self.map.COMMAND, [word])

    async def send(self, sender: int, target: int) -> None:
        """An SND in the name of external process ``sender`` (the mailbox)."""
        await self._write(self.map.MAILBOX, [sender, target])

    # -- auxiliary functions ([nc.aux]) ---------------------------------------------------------

    def _aux_place(self, process: int, letter: str) -> tuple[str, int, int]:
        aux = self.config.nc.aux_interface
        if aux is None:
            raise VirtualPLCError("the config has no [nc.aux]: no auxiliary function is output")
        (area, index, _), strobe, ack = aux.place(process, letter.upper())
        return (f"SYVAR{index}" if area == "SYVAR" else f"SK{index}.IN"), strobe, ack

    async def _aux_value(self, first: str) -> int:
        """A value as the NC output it: one word, or (``nc.aux.value_bits = 32``) two, the
        high word first."""
        aux = self.config.nc.aux_interface
        high = await self.get(first)
        if aux is None or aux.words == 1:
            return high
        (area, index, _), _ = parse_assignment(f"{first}=0")
        low = await self.get(f"{area}{index + (2 if area == 'SK' else 1)}"
                             + (".IN" if area == "SK" else ""))
        return high << 16 | low & 0xFFFF

    async def aux_strobes(self) -> list[AuxSeen]:
        """Every auxiliary function whose strobe is up now, process by process (M, S, T, H)."""
        out = []
        for k in range(1, self.config.nc.processes + 1):
            _, first, _ = self._aux_place(k, "M")
            r = await self.client.read_coils(first, count=4, device_id=self.unit)
            self._check(r)
            for letter, up in zip("MSTH", r.bits[:4], strict=True):
                if up:
                    value, _, _ = self._aux_place(k, letter)
                    out.append(AuxSeen(k, letter, await self._aux_value(value)))
        return out

    async def expect_aux(self, code: str, process: int = 1, timeout_s: float = 10.0) -> AuxSeen:
        """Until process k outputs ``code`` (``"M08"``, ``"T5"``) with its strobe up; raises
        VirtualPLCError when another code of that letter is strobed instead, or none comes."""
        found = _AUX_CODE.match(code.strip())
        if found is None:
            raise VirtualPLCError(f"{code!r} is not an auxiliary function (M08, S1000, T5, H2)")
        letter, wanted = found.group(1).upper(), int(found.group(2))
        value, strobe, _ = self._aux_place(process, letter)

        async def strobed() -> AuxSeen | None:
            if not await self.get(f"SA{strobe}"):
                return None
            return AuxSeen(process, letter, await self._aux_value(value))

        seen = await self._until(strobed, timeout_s, lambda: (
            f"P{process} output no {letter} function in {timeout_s:g} s (strobe SA{strobe} "
            f"stayed 0; expected {code})"))
        if seen.value != wanted:
            raise VirtualPLCError(f"P{process} output {seen.code}, not {code}")
        return seen

    async def ack_aux(self, process: int | AuxSeen = 1, letter: str = "M",
                      timeout_s: float = 10.0) -> None:
        """Acknowledge process k's ``letter`` function (or an :class:`AuxSeen`): set the
        acknowledge, wait until the NC drops the strobe, drop the acknowledge."""
        if isinstance(process, AuxSeen):
            letter = process.letter
            process = process.process
        _, strobe, ack = self._aux_place(process, letter[:1])
        await self.set(f"SA{ack}", 1)

        async def dropped() -> bool | None:
            return None if await self.get(f"SA{strobe}") else True

        await self._until(dropped, timeout_s, lambda: (
            f"P{process}'s strobe SA{strobe} did not drop in {timeout_s:g} s after the "
            f"acknowledge SA{ack}"))
        await self.set(f"SA{ack}", 0)

    async def event_counter(self) -> int:
        hi, lo = await self._input(2, 2)
        return hi << 16 | lo

    async def snd_log(self) -> list[SndSeen]:
        """The SND log window: the last 16 SNDs the gateway reports, oldest first."""
        m = self.map
        regs = await self._input(m.SND_LOG_BASE, m.LOG_SIZE)
        out = []
        for at in range(2, m.LOG_SIZE, m.LOG_ENTRY):
            hi, lo, sender, target, n, ident = regs[at:at + m.LOG_ENTRY]
            if hi or lo:
                out.append(SndSeen(sender, target, n, hi << 16 | lo, ident))
        return out[::-1]

    async def next_snd(self, timeout_s: float = 10.0) -> SndSeen:
        """The next SND after the last one this client returned (or, first, after connect).

        It reads the SND log window, so it loses none while fewer than 16 SNDs happen between
        two calls; when more do, the oldest are gone and it raises VirtualPLCError naming how
        many were missed.
        """

        async def unseen() -> SndSeen | None:
            newer = [s for s in await self.snd_log() if s.seq > self._last_seq]
            if not newer:
                return None
            first = newer[0]
            missed = first.seq - self._last_seq - 1
            if missed:
                # Said once: the next call returns the oldest one still there.
                self._last_seq = first.seq - 1
                raise VirtualPLCError(
                    f"{missed} SND(s) after #{first.seq - missed - 1} left the log window "
                    f"before this client read it; next is #{first.seq}")
            self._last_seq = first.seq
            return first

        return await self._until(unseen, timeout_s, lambda: f"no new SND in {timeout_s:g} s")
