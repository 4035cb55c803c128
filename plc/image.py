"""The I/O image the soft PLC owns (spec 3.1): SA bits, K bytes, SYVARs.

A variable is named by its area (``"SA"``, ``"SK"``, ``"SYVAR"``), an index and a view
(``"bit"``, ``"BY"``, ``"IN"``; spec 1.3).  Writes name their writer and are applied atomically:
every value of a request is validated, then stored, and only then are waits woken.  Waits are
indexed by the storage they look at (a bit, a byte, a SYVAR), so a write evaluates only the
waits on what it changed and its cost does not grow with the number of waits elsewhere.

The image lives on one thread (the asyncio loop in the gateway); it does no locking, but for
its :class:`FrozenImage`: the image as of one write, immutable, taken lazily (copied when it is
first read, or just before the image's next write if something still holds it then), which
any thread may read.  Stdlib only: the interpreter reaches it through its own protocol, the
gateway wires them together.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Iterable, Sequence
from typing import Final, NamedTuple

from ncgate.errors import NcgateError

AREAS: Final = ("SA", "SK", "SYVAR")
VIEWS: Final = ("bit", "BY", "IN")

class PlcError(NcgateError):
    """Root of the soft PLC's exceptions."""


class ImageAddressError(PlcError, IndexError):
    """A variable outside the image (area, index or view)."""


class ImageValueError(PlcError, ValueError):
    """A value the variable's type cannot hold (never wrapped silently)."""


class Change(NamedTuple):
    """One stored value: what a listener of the image is told.  (A NamedTuple: one is made
    for every value of every fieldbus write.)"""

    area: str
    index: int  # type: ignore[assignment]  # (shadows tuple.index, as the field name it is)
    view: str
    value: int
    old: int


_new = tuple.__new__  # a Change without NamedTuple's generated __new__ (the write hot path)


Listener = Callable[[Sequence[Change], str], None]
Predicate = Callable[[int], bool]  # a wait's condition on the variable's current value
_Key = tuple[str, int]  # ("SA", byte) / ("SAb", bit) / ("SK", byte) / ("SYVAR", n)


class Watch:
    """A generation of part of the image (:meth:`IOImage.watch`)."""

    __slots__ = ("_image", "areas", "generation", "keys")

    def __init__(self, image: IOImage, keys: Iterable[_Key], areas: Iterable[str]) -> None:
        self._image = image
        self.keys = frozenset(keys)
        self.areas = frozenset(areas)
        self.generation = 0

    def sees(self, touched: set[_Key]) -> bool:
        """Whether a write that changed ``touched`` changed what this watches."""
        if self.areas and any(key[0] in self.areas for key in touched):  # (a bit changed
            return True  # touches its byte's key too)
        return not self.keys.isdisjoint(touched)

    def close(self) -> None:
        if self in self._image._watches:
            self._image._watches.remove(self)


class Wait:
    """A registered condition; :meth:`cancel` removes it."""

    __slots__ = ("_image", "area", "index", "keys", "on_true", "test", "view")

    def __init__(self, image: IOImage, area: str, index: int, view: str, test: Predicate,
                 keys: tuple[_Key, ...], on_true: Callable[[], None]) -> None:
        self._image = image
        self.area, self.index, self.view, self.test = area, index, view, test
        self.keys = keys
        self.on_true = on_true

    def holds(self) -> bool:
        return self.test(self._image.read(self.area, self.index, self.view))

    def cancel(self) -> None:
        self._image._unregister(self)


def _pieces(view: str, index: int, value: int) -> list[tuple[int, int, int]]:
    """The bytes an SA or SK variable covers: (byte, mask, the value's bits there)."""
    if view == "bit":
        return [(index >> 3, 1 << (index & 7), (value & 1) << (index & 7))]
    if view == "BY":
        return [(index, 0xFF, value)]
    word = value & 0xFFFF
    return [(index, 0xFF, word & 0xFF), (index + 1, 0xFF, word >> 8)]


def _kept(change: tuple[str, int, str, int], by_byte: dict[tuple[str, int], tuple[int, int]],
          by_syvar: dict[int, int]) -> int:
    """What a write stores of ``change``'s value under per-byte (mask, bits) and per-SYVAR
    values that win over it (forces, holds)."""
    area, index, view, value = change
    if area == "SYVAR":
        return by_syvar.get(index, value)
    if view == "bit":
        mask, bits = by_byte.get((area, index >> 3), (0, 0))
        bit = 1 << (index & 7)
        return (1 if bits & bit else 0) if mask & bit else value
    if view == "BY":
        mask, bits = by_byte.get((area, index), (0, 0))
        return (value & ~mask) | bits
    word = value & 0xFFFF
    lo_mask, lo_bits = by_byte.get((area, index), (0, 0))
    hi_mask, hi_bits = by_byte.get((area, index + 1), (0, 0))
    # (Each byte on its own: the low byte's masks once worked on the whole word, and a word
    # write set bits of a held or forced high byte.)
    kept = (((word >> 8) & ~hi_mask | hi_bits) << 8) | ((word & 0xFF & ~lo_mask) | lo_bits)
    return kept - 0x10000 if kept & 0x8000 else kept


def overlap(a: tuple[str, int, str], b: tuple[str, int, str]) -> bool:
    """Two variables share a bit (SA37 and SA4.BY; SK2.IN and SK3)."""
    if a[0] != b[0]:
        return False
    if a[0] == "SYVAR":
        return a[1] == b[1]
    mine = {byte: mask for byte, mask, _ in _pieces(a[2], a[1], 0)}
    return any(mine.get(byte, 0) & mask for byte, mask, _ in _pieces(b[2], b[1], 0))


class IOImage:
    """SA packet (bits), K packet (bytes) and SYVARs (int16), with writers and waits."""

    def __init__(self, sa_bits: int = 1024, k_bytes: int = 512, syvars: int = 256) -> None:
        if sa_bits % 8:
            raise ValueError("sa_bits must be a multiple of 8")
        self.sa = bytearray(sa_bits // 8)
        self.k = bytearray(k_bytes)
        self.syvar = [0] * syvars
        self._waits: dict[_Key, set[Wait]] = {}
        self._writers: dict[_Key, tuple[int, str]] = {}  # key -> (write number, writer)
        self._listeners: list[Listener] = []
        # Forcing: the forced variables, as given, and what they make of each write -- per
        # SA/SK byte the bits forced and their values, the SYVARs forced.  ``on_overridden``
        # hears every write a force changed or dropped: (area, index, view, value tried).
        self.forced: dict[tuple[str, int, str], int] = {}
        self._force_bytes: dict[tuple[str, int], tuple[int, int]] = {}
        self._force_syvars: dict[int, int] = {}
        self._forced_bytes: dict[tuple[str, int], tuple[int, int]] = {}  # the forces alone
        self._forced_syvars: dict[int, int] = {}
        self._held_masks: dict[tuple[str, int], int] = {}  # the holds alone: bits held
        self._held_syvars: set[int] = set()
        self.on_overridden: Callable[[list[tuple[str, int, str, int]], str], None] | None = None
        # Held variables: an injected fault (a stuck sensor, a wire break) holds what every
        # reader sees, whatever writes it, as a force does; a force wins over a hold.  The
        # writes of a held variable are kept aside, not stored (write), and the last is
        # given back when the hold ends (unhold).
        self.held: dict[tuple[str, int, str], int] = {}
        self._hold_writers: dict[tuple[str, int, str], str] = {}  # who placed each hold
        # While something is held: the image as its writers wrote it, holds aside (a copy
        # written beside this one), so that a clear gives back what the writers' last writes
        # make of a held variable -- a wire mended (unhold).
        self._unheld: IOImage | None = None
        self._placing = False  # a hold's own write (hold): the one a held variable takes
        self.generation = 0  # +1 on every write that changed something
        self._watches: list[Watch] = []  # (see watch)
        self._write_number = 0
        # The frozen image of the image as it is (frozen()), not taken yet; and who drops
        # what it holds of one before a write (what is dropped is not copied).
        self._frozen: weakref.ref[FrozenImage] | None = None
        self._before_freeze: list[Callable[[], None]] = []
        self._freeze_lock = threading.Lock()

    def watch(self, keys: Iterable[_Key] = (), areas: Iterable[str] = ()) -> Watch:
        """A generation of some of the image: +1 on every write that changed one of
        ``keys`` (("SA", byte), ("SK", byte), ("SYVAR", n)) or anything in ``areas``
        ("SA", "SK", "SYVAR") -- what one reader reads (PLC logic: a still scan's inputs).
        Dropped with :meth:`Watch.close`."""
        watch = Watch(self, keys, areas)
        self._watches.append(watch)
        return watch

    @property
    def sa_bits(self) -> int:
        return len(self.sa) * 8

    @property
    def writes(self) -> int:
        """The write counter: +1 on every write, changed or not (a writer is stored even
        when the value is not), but one a hold keeps aside whole; a :class:`FrozenImage`'s
        ``version``."""
        return self._write_number

    # -- the image as of now, immutable ----------------------------------------------------

    def frozen(self) -> FrozenImage:
        """The image as it is now (values and last writers), never to change: nothing is
        copied until it is read, or until the image is about to be written while something
        still holds it (copy on write).  The same object until the next write."""
        ref = self._frozen
        found = ref() if ref is not None else None
        if found is None:
            found = FrozenImage(self)
            self._frozen = weakref.ref(found)
        return found

    def before_freeze(self, callback: Callable[[], None]) -> Callable[[], None]:
        """Call ``callback()`` before a write while a frozen image of the image as it is
        exists and is not taken: a holder that would drop it after the write (its moment is
        over) drops it then, and it is copied only if something else still holds it.
        Returns the unsubscribe."""
        self._before_freeze.append(callback)
        return lambda: self._before_freeze.remove(callback)

    def _freeze(self) -> None:
        """Before the image changes: the frozen image of it as it is, if still held, takes
        its copy now."""
        ref, self._frozen = self._frozen, None
        if ref is None or ref() is None:
            return  # (dropped: nothing to copy, nobody to tell)
        for callback in list(self._before_freeze):
            callback()
        found = ref()  # still held by someone after the callbacks dropped theirs
        if found is not None:
            found._take_all()

    # -- reading --------------------------------------------------------------------------

    def read(self, area: str, index: int, view: str) -> int:
        """The value of a variable (raises :class:`ImageAddressError` outside the image)."""
        if area == "SYVAR":
            if 0 <= index < len(self.syvar):
                return self.syvar[index]
        else:
            data = self.sa if area == "SA" else self.k if area == "SK" else None
            if data is not None:
                if view == "bit" and area == "SA":
                    if 0 <= index < len(data) * 8:
                        return (data[index >> 3] >> (index & 7)) & 1
                elif view == "BY":
                    if 0 <= index < len(data):
                        return data[index]
                elif view == "IN" and 0 <= index < len(data) - 1:
                    word = data[index] | data[index + 1] << 8
                    return word - 0x10000 if word & 0x8000 else word
        raise ImageAddressError(f"{_name(area, index, view)} is outside the image")

    def last_writer(self, area: str, index: int, view: str) -> str | None:
        """Who last wrote any part of the variable (a bit's byte, a byte's bits, …); the
        fault that holds all of it, while one does."""
        if self.held and self._absorbed((area, index, view, 0)):
            covering = [writer for key, writer in self._hold_writers.items()
                        if overlap(key, (area, index, view))]
            if covering:
                return covering[-1]  # (the latest placed: the one whose bits show)
        found = [self._writers[k] for k in self._related_keys(area, index, view)
                 if k in self._writers]
        return max(found)[1] if found else None

    # -- writing --------------------------------------------------------------------------

    def check(self, area: str, index: int, view: str, value: int) -> None:
        """Raise if the write could not be stored; stores nothing."""
        self.read(area, index, view)  # the address
        low, high = value_range(area, view)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ImageValueError(
                f"{_name(area, index, view)} holds {low}..{high}, not {value!r}")

    def write(self, changes: Iterable[tuple[str, int, str, int]], writer: str,
              checked: bool = False) -> list[Change]:
        """Store every value, then wake the waits they satisfy.  All or nothing.

        Returns what actually changed.  Listeners hear every value written, changed or not
        (a program writing SYVAR1=0 twice wrote twice); only changes wake waits.
        ``checked``: the caller has run :meth:`check` on every change (the gateway's door).
        """
        items = list(changes)
        if not checked:
            for area, index, view, value in items:
                self.check(area, index, view, value)
        if self._unheld is not None and not self._placing:
            # (As the forces let it through: what a force refused is nobody's wish either.)
            forced = (self._forced_bytes, self._forced_syvars)
            wished = items if not (forced[0] or forced[1]) else [
                (*c[:3], _kept(c, *forced)) for c in items]
            self._unheld.write(wished, writer, checked=True)
        if self.held and not self._placing:
            # A write whose every bit a fault holds takes nothing: kept aside (above) for the
            # clear, it is neither stored, nor heard, nor its writer's -- the trace said "plc
            # wrote 1" each scan for a chatter the logic never wrote, and a verdict named the
            # PLC.  (One that is partly held is stored with the held bits kept.)
            items = [c for c in items if not self._absorbed(c)]
            if not items:
                return []
        if self.forced or self.held:
            items = self._apply_forces(items, writer)
        if self._frozen is not None:
            self._freeze()
        done: list[Change] = []
        written: list[Change] = []
        touched: set[_Key] = set()
        self._write_number += 1
        stamp = (self._write_number, writer)
        syvar, writers = self.syvar, self._writers
        try:
            for area, index, view, value in items:
                if area == "SYVAR" and 0 <= index < len(syvar):  # (the samples of a plant's
                    old = syvar[index]  # ramps and lags: read, _store and _keys inline)
                    key = ("SYVAR", index)
                    writers[key] = stamp
                    change = _new(Change, (area, index, view, value, old))
                    written.append(change)
                    if value != old:
                        syvar[index] = value
                        touched.add(key)
                        done.append(change)
                    continue
                old = self.read(area, index, view)
                keys = self._store(area, index, view, value, old)
                for key in self._keys(area, index, view):
                    self._writers[key] = stamp
                change = _new(Change, (area, index, view, value, old))
                written.append(change)
                if keys:
                    touched.update(keys)
                    done.append(change)
        except BaseException:
            # A value the caller said was checked and was not: those before it are stored.
            # Whoever keeps what it read at a generation (the Modbus server's answers, the
            # PLC's still scans) must read again.
            self.generation += 1
            for watch in self._watches:
                watch.generation += 1
            raise
        if done:
            self.generation += 1
            for watch in self._watches:
                if watch.sees(touched):
                    watch.generation += 1
        # Listeners (the trace) hear of the write before any wait it satisfies is woken,
        # so that cause comes before effect in everything they record.
        for listener in list(self._listeners):
            listener(written, writer)
        if touched:
            self._wake(touched)
        return done

    # -- forcing --------------------------------------------------------------------------

    def force(self, area: str, index: int, view: str, value: int, writer: str) -> None:
        """Force a variable to ``value``: stored now, and kept whatever writes it after
        (PLC logic, the fieldbus, programs) until :meth:`unforce`."""
        self.check(area, index, view, value)
        self.forced[(area, index, view)] = value
        self._force_index()
        self.write([(area, index, view, value)], writer, checked=True)

    def unforce(self, area: str | None = None, index: int = 0, view: str = "") -> None:
        """Release one forced variable (``area`` None: every one); its value stays."""
        if area is None:
            self.forced.clear()
        else:
            self.forced.pop((area, index, view), None)
        self._force_index()
        # What a fault holds under it shows the fault's value again (a write would not put
        # it back: it is kept aside while held).
        self._reassert_holds()

    def hold(self, area: str, index: int, view: str, value: int, writer: str) -> None:
        """Hold a variable at ``value`` (a fault): stored now, and kept whatever writes it
        until :meth:`unhold`; a force of it wins."""
        self.check(area, index, view, value)
        if self._unheld is None:
            self._unheld = self._copy()
        key = (area, index, view)
        # The latest hold wins where holds overlap (and last_writer names it): placed again
        # (a chatter's toggle, a fault replaced) it moves to the end.
        self.held.pop(key, None)
        self._hold_writers.pop(key, None)
        self.held[key] = value
        self._hold_writers[key] = writer
        self._force_index()
        self._place(area, index, view, value, writer)

    def _place(self, area: str, index: int, view: str, value: int, writer: str) -> None:
        """The image's own write (a hold placed, a value given back): through the forces and
        holds, never kept aside nor absorbed, no ``forced`` event."""
        self._placing = True
        try:
            self.write([(area, index, view, value)], writer, checked=True)
        finally:
            self._placing = False

    def _reassert_holds(self) -> None:
        """Every hold shows what the holds and forces make of it (after a force or a hold
        over some of its bits went: nothing else puts it back, its writes being kept
        aside)."""
        both = (self._force_bytes, self._force_syvars)
        for (a, i, v), value in list(self.held.items()):
            if self.read(a, i, v) != _kept((a, i, v, value), *both):
                self._place(a, i, v, value, self._hold_writers[(a, i, v)])

    def _stamp(self, area: str, index: int, view: str, writer: str) -> None:
        """``writer`` as the variable's last, its value unchanged (nothing to trace)."""
        if self._frozen is not None:
            self._freeze()
        self._write_number += 1
        for key in self._keys(area, index, view):
            self._writers[key] = (self._write_number, writer)

    def unhold(self, area: str, index: int, view: str, give_back: str | None = None) -> None:
        """Release a held variable.  With ``give_back`` (a writer's name for a variable
        nobody wrote), what its writers' writes make of it -- their last, or what it held
        before the hold -- is written back now, in the last writer's name (or, the same
        value, that writer named again); without, what it shows stays until written.  Other
        holds over some of its bits show theirs again either way."""
        self.held.pop((area, index, view), None)
        self._hold_writers.pop((area, index, view), None)
        self._force_index()
        unheld = self._unheld
        if not self.held:
            self._unheld = None
        if unheld is not None and give_back is not None:
            value = unheld.read(area, index, view)
            writer = unheld.last_writer(area, index, view) or give_back
            if value != self.read(area, index, view):
                self._place(area, index, view, value, writer)
            else:
                self._stamp(area, index, view, writer)
        self._reassert_holds()

    def _copy(self) -> IOImage:
        """A copy of the values and writers (no waits, listeners, forces or holds)."""
        copy = IOImage(len(self.sa) * 8, len(self.k), len(self.syvar))
        copy.sa[:], copy.k[:], copy.syvar[:] = self.sa, self.k, self.syvar
        copy._writers = dict(self._writers)
        copy._write_number = self._write_number
        return copy

    def forced_over(self, area: str, index: int, view: str) -> tuple[str, int, str] | None:
        """Another forced variable with bits of this one (SA1.BY over a forced SA10), or
        None: two forces of one bit would make the force list say what the image does not."""
        if area == "SYVAR":
            return None  # a SYVAR has one view: forcing it again is the same variable
        mine = (area, index, view)
        return next((key for key in self.forced if key != mine and overlap(key, mine)), None)

    def _force_index(self) -> None:
        """Per SA/SK byte and SYVAR what the holds and forces make of a write (holds first,
        then forces over them: a force wins), and each alone: the holds' masks (what a write
        cannot change), the forces' (what is told to on_overridden)."""
        for table in (self._force_bytes, self._force_syvars, self._forced_bytes,
                      self._forced_syvars, self._held_masks):
            table.clear()
        self._held_syvars.clear()
        for (area, index, view), value in self.held.items():
            if area == "SYVAR":
                self._held_syvars.add(index)
            else:
                for byte, mask, _ in _pieces(view, index, value):
                    self._held_masks[(area, byte)] = self._held_masks.get((area, byte), 0) | mask
        for tables, entries in (((self._force_bytes, self._force_syvars),
                                 [*self.held.items(), *self.forced.items()]),
                                ((self._forced_bytes, self._forced_syvars),
                                 list(self.forced.items()))):
            by_byte, by_syvar = tables
            for (area, index, view), value in entries:
                if area == "SYVAR":
                    by_syvar[index] = value
                    continue
                for byte, mask, bits in _pieces(view, index, value):
                    old_mask, old_bits = by_byte.get((area, byte), (0, 0))
                    by_byte[(area, byte)] = (old_mask | mask, (old_bits & ~mask) | bits)

    def _apply_forces(self, items: list[tuple[str, int, str, int]],
                      writer: str) -> list[tuple[str, int, str, int]]:
        """The writes as the forces and holds let them through: forced and held bits (and
        SYVARs) are written with their values whatever the write said; every write a
        *force* changed is told to ``on_overridden`` (a hold's are not: the fault says why)."""
        out = []
        overridden = []
        both, forces = (self._force_bytes, self._force_syvars), (self._forced_bytes,
                                                                 self._forced_syvars)
        for change in items:
            kept = _kept(change, *both)
            if (forces[0] or forces[1]) and _kept(change, *forces) != change[3]:
                overridden.append(change)
            out.append(change if kept == change[3] else (*change[:3], kept))
        if overridden and self.on_overridden is not None and not self._placing:
            self.on_overridden(overridden, writer)  # (the image's own writes: none)
        return out

    def _absorbed(self, change: tuple[str, int, str, int]) -> bool:
        """Every bit of the write is held by a fault and none forced: it stores nothing."""
        area, index, view, _ = change
        if area == "SYVAR":
            return index in self._held_syvars and index not in self._forced_syvars
        held, forced = self._held_masks, self._forced_bytes
        for byte, mask, _ in _pieces(view, index, 0):
            if held.get((area, byte), 0) & mask != mask or forced.get((area, byte),
                                                                       (0, 0))[0] & mask:
                return False
        return True

    def _store(self, area: str, index: int, view: str, value: int, old: int) -> list[_Key]:
        """Store one value; the keys whose storage changed."""
        if value == old:
            return []
        if area == "SYVAR":
            self.syvar[index] = value
            return [("SYVAR", index)]
        data = self.sa if area == "SA" else self.k
        if view == "bit":
            byte = index >> 3
            data[byte] ^= 1 << (index & 7)
            return [("SA", byte), ("SAb", index)]
        if view == "BY":
            before = data[index]
            data[index] = value
            return self._byte_keys(area, index, before ^ value)
        word = value & 0xFFFF
        lo_before, hi_before = data[index], data[index + 1]
        data[index], data[index + 1] = word & 0xFF, word >> 8
        return (self._byte_keys(area, index, lo_before ^ data[index])
                + self._byte_keys(area, index + 1, hi_before ^ data[index + 1]))

    @staticmethod
    def _byte_keys(area: str, byte: int, flipped: int) -> list[_Key]:
        if not flipped:
            return []
        keys: list[_Key] = [(area, byte)]
        if area == "SA":
            base = byte * 8
            keys.extend(("SAb", base + bit) for bit in range(8) if flipped >> bit & 1)
        return keys

    # -- waiting --------------------------------------------------------------------------

    def wait(self, area: str, index: int, view: str, test: Predicate,
             on_true: Callable[[], None]) -> Wait | None:
        """Level-triggered: None if ``test(value)`` holds now, else a registered :class:`Wait`.

        The test is the caller's (the interpreter's comparison): the image knows no operators.

        ``on_true`` is called once, from inside the write that makes the condition true,
        after every value of that write is stored; the wait is then already removed.
        """
        if test(self.read(area, index, view)):
            return None
        keys = tuple(self._keys(area, index, view))
        wait = Wait(self, area, index, view, test, keys, on_true)
        for key in keys:
            self._waits.setdefault(key, set()).add(wait)
        return wait

    def _unregister(self, wait: Wait) -> None:
        for key in wait.keys:
            bucket = self._waits.get(key)
            if bucket is not None:
                bucket.discard(wait)
                if not bucket:
                    del self._waits[key]

    def _wake(self, touched: set[_Key]) -> None:
        candidates: list[Wait] = []
        seen: set[int] = set()
        waits = self._waits
        for key in touched:
            for wait in waits.get(key, ()):
                if id(wait) not in seen:
                    seen.add(id(wait))
                    candidates.append(wait)
        if not candidates:  # (the common case: a value nobody waits on)
            return
        # Wake in registration-independent, deterministic order.
        candidates.sort(key=lambda w: (AREAS.index(w.area), w.index, VIEWS.index(w.view)))
        ready = [w for w in candidates if w.holds()]
        for wait in ready:
            self._unregister(wait)
        for wait in ready:
            wait.on_true()

    @property
    def wait_count(self) -> int:
        return len({id(w) for bucket in self._waits.values() for w in bucket})

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener(values, writer)`` after every write, before waits are woken."""
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener)

    def _keys(self, area: str, index: int, view: str) -> list[_Key]:
        if area == "SYVAR":
            return [("SYVAR", index)]
        if view == "bit":
            return [("SAb", index)]
        if view == "BY":
            return [(area, index)]
        return [(area, index), (area, index + 1)]

    def _related_keys(self, area: str, index: int, view: str) -> list[_Key]:
        if area == "SA" and view == "bit":
            return [("SAb", index), ("SA", index >> 3)]
        keys = self._keys(area, index, view)
        if area == "SA":
            keys += [("SAb", k[1] * 8 + b) for k in list(keys) for b in range(8)]
        return keys

    # -- snapshots (tests, status) -----------------------------------------------------------

    def writers(self) -> dict[str, dict[int, str]]:
        """Who last wrote each variable written so far: ``{"SA": {bit: writer}, "SK": {byte:
        writer}, "SYVAR": {n: writer}}`` (a byte write to the SA packet counts for its
        bits); the console shows it beside each value."""
        return _writers(self._writers)

    def snapshot(self) -> tuple[bytes, bytes, tuple[int, ...]]:
        return bytes(self.sa), bytes(self.k), tuple(self.syvar)


class FrozenImage:
    """The image as of one write (``version``: :attr:`IOImage.writes` then), immutable: its
    values (:attr:`sa`, :attr:`k`, :attr:`syvar`) and its last writers (:meth:`writers`).

    Taken lazily (:meth:`IOImage.frozen`): the values and the writers are each copied from
    the image when first read, and whatever is not taken yet is taken just before the image's
    next write if the frozen image is still held then; one dropped unread costs no copy.  Any
    thread may read it: a copy from another thread holds the image's lock, which the loop
    takes before it writes to a frozen image's image, so it never sees half a write."""

    __slots__ = ("__weakref__", "_areas", "_image", "_lock", "_stamps", "sa_bits", "version")

    def __init__(self, image: IOImage) -> None:
        self._image: IOImage | None = image
        self._lock = image._freeze_lock
        self.version = image._write_number
        self.sa_bits = image.sa_bits
        self._areas: tuple[bytes, bytes, tuple[int, ...]] | None = None
        self._stamps: dict[_Key, tuple[int, str]] | None = None

    def _take_areas(self) -> tuple[bytes, bytes, tuple[int, ...]]:
        with self._lock:
            if self._areas is None:
                image = self._image
                assert image is not None
                self._areas = (bytes(image.sa), bytes(image.k), tuple(image.syvar))
                if self._stamps is not None:
                    self._image = None  # (all taken: the live image is not needed)
            return self._areas

    def _take_stamps(self) -> dict[_Key, tuple[int, str]]:
        with self._lock:
            if self._stamps is None:
                image = self._image
                assert image is not None
                self._stamps = dict(image._writers)
                if self._areas is not None:
                    self._image = None
            return self._stamps

    def _take_all(self) -> None:
        if self._areas is None:
            self._take_areas()
        if self._stamps is None:
            self._take_stamps()

    @property
    def sa(self) -> bytes:
        """The SA packet, bit 0 of byte 0 first."""
        areas = self._areas
        return (areas if areas is not None else self._take_areas())[0]

    @property
    def k(self) -> bytes:
        areas = self._areas
        return (areas if areas is not None else self._take_areas())[1]

    @property
    def syvar(self) -> tuple[int, ...]:
        areas = self._areas
        return (areas if areas is not None else self._take_areas())[2]

    def writers(self) -> dict[str, dict[int, str]]:
        """Who last wrote each variable (:meth:`IOImage.writers`), as of this image."""
        stamps = self._stamps
        return _writers(stamps if stamps is not None else self._take_stamps())

    def __repr__(self) -> str:
        return f"<FrozenImage version {self.version}>"


def _writers(stamps: dict[_Key, tuple[int, str]]) -> dict[str, dict[int, str]]:
    """:meth:`IOImage.writers` of these stamps (key -> (write number, writer))."""
    sa: dict[int, tuple[int, str]] = {}
    out: dict[str, dict[int, str]] = {"SA": {}, "SK": {}, "SYVAR": {}}
    for (area, index), stamp in stamps.items():
        if area == "SAb":
            bits = [index]
        elif area == "SA":
            bits = list(range(index * 8, index * 8 + 8))
        else:
            out[area][index] = stamp[1]
            continue
        for bit in bits:
            if bit not in sa or sa[bit] < stamp:
                sa[bit] = stamp
    out["SA"] = {bit: stamp[1] for bit, stamp in sorted(sa.items())}
    return out


def value_range(area: str, view: str) -> tuple[int, int]:
    if area == "SYVAR" or view == "IN":
        return -32768, 32767
    if view == "bit":
        return 0, 1
    return 0, 255


def _name(area: str, index: int, view: str) -> str:
    if area == "SYVAR" or (area == "SA" and view == "bit") or (area == "SK" and view == "BY"):
        return f"{area}{index}"
    return f"{area}{index}.{view}"
