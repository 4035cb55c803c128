"""A seeded random-frame fuzz (spec 3.2): after a few thousand frames the server still serves,
and the image holds exactly what the valid writes among them wrote -- according to an oracle
written here from the spec, independent of the server's code."""

from __future__ import annotations

import random
import struct

from ncgate.gateway import Gateway

from .rawclient import Raw, mbap

SA_BITS, K_BYTES, SYVARS, SA_BYTES = 1024, 512, 256, 128
UNITS = (1, 7, 0, 0xFF)  # the configured ids, 0 (not strict) and 0xFF (the server)
BOUNDARIES = [0, 1, 7, 8, 510, 511, 512, 999, 1000, 1255, 1256, 1499, 1500, 1627, 1628, 1999,
              2000, 2001, 2002, 2003, 1023, 1024, 65535]


class Oracle:
    """The image as the spec says the valid requests leave it."""

    def __init__(self) -> None:
        self.sa = [0] * SA_BITS
        self.k = [0] * K_BYTES
        self.syvar = [0] * SYVARS

    def holding(self, address: int, values: list[int]) -> bool:
        """Apply a holding write if it is valid as a whole; False if it must store nothing."""
        plan: list[tuple[str, int, int]] = []
        for i, v in enumerate(values):
            a = address + i
            if a < K_BYTES and v <= 255:
                plan.append(("k", a, v))
            elif 1000 <= a < 1000 + SYVARS:
                plan.append(("s", a - 1000, v - 0x10000 if v & 0x8000 else v))
            elif 1500 <= a < 1500 + SA_BYTES and v <= 255:
                plan.append(("b", a - 1500, v))
            else:
                return False
        for kind, i, v in plan:
            if kind == "k":
                self.k[i] = v
            elif kind == "s":
                self.syvar[i] = v
            else:
                for bit in range(8):
                    self.sa[8 * i + bit] = v >> bit & 1
        return True

    def current(self, address: int) -> int | None:
        if address < K_BYTES:
            return self.k[address]
        if 1000 <= address < 1000 + SYVARS:
            return self.syvar[address - 1000] & 0xFFFF
        if 1500 <= address < 1500 + SA_BYTES:
            i = address - 1500
            return sum(self.sa[8 * i + b] << b for b in range(8))
        return None

    def apply(self, unit: int, p: bytes) -> None:
        if unit not in UNITS or not p:
            return
        fc, n = p[0], len(p)
        if fc == 5 and n == 5:
            a, v = struct.unpack(">HH", p[1:5])
            if a < SA_BITS and v in (0, 0xFF00):
                self.sa[a] = int(v == 0xFF00)
        elif fc == 6 and n == 5:
            a, v = struct.unpack(">HH", p[1:5])
            self.holding(a, [v])
        elif fc == 15 and n >= 6:
            a, q, bc = struct.unpack(">HHB", p[1:6])
            if 1 <= q <= 1968 and bc == (q + 7) // 8 and n == 6 + bc and a + q <= SA_BITS:
                for i in range(q):
                    self.sa[a + i] = p[6 + i // 8] >> (i % 8) & 1
        elif fc == 16 and n >= 6:
            a, q, bc = struct.unpack(">HHB", p[1:6])
            if 1 <= q <= 123 and bc == 2 * q and n == 6 + bc:
                self.holding(a, list(struct.unpack(f">{q}H", p[6:])))
        elif fc == 22 and n == 7:
            a, and_mask, or_mask = struct.unpack(">HHH", p[1:7])
            cur = self.current(a)
            if cur is not None:
                self.holding(a, [(cur & and_mask) | (or_mask & ~and_mask & 0xFFFF)])
        elif fc == 23 and n >= 10:
            ra, rq, wa, wq, bc = struct.unpack(">HHHHB", p[1:10])
            readable = all(a < K_BYTES or 1000 <= a < 1000 + SYVARS or 1500 <= a < 1628
                           or 2000 <= a <= 2002 for a in range(ra, ra + rq))
            if (1 <= rq <= 125 and 1 <= wq <= 121 and bc == 2 * wq and n == 10 + bc
                    and readable):
                self.holding(wa, list(struct.unpack(f">{wq}H", p[10:])))

    def matches(self, gw: Gateway) -> bool:
        sa, k, syvar = gw.image.snapshot()
        bits = [sa[i >> 3] >> (i & 7) & 1 for i in range(SA_BITS)]
        return bits == self.sa and list(k) == self.k and list(syvar) == self.syvar


def random_frame(rng: random.Random) -> tuple[int, bytes, bytes]:
    """(unit, pdu, whole frame); a few frames have a bad MBAP header."""
    unit = rng.choice([1, 1, 1, 7, 0, 3, 0xFF, 2])
    r = rng.random()
    if r < 0.1:  # raw garbage
        p = bytes(rng.randrange(256) for _ in range(rng.randint(1, 20)))
    else:
        fc = rng.choice([1, 2, 3, 4, 5, 6, 15, 16, 22, 23, 7, 43, 0x81])
        a = rng.choice(BOUNDARIES) if rng.random() < 0.7 else rng.randrange(65536)
        q = rng.choice([0, 1, 2, 3, 8, 125, 126, 2000, 2001, rng.randrange(1, 300)])
        if fc in (1, 2, 3, 4):
            p = struct.pack(">BHH", fc, a, q)
        elif fc == 5:
            p = struct.pack(">BHH", fc, a, rng.choice([0, 0xFF00, 1, 0xFFFF]))
        elif fc == 6:
            p = struct.pack(">BHH", fc, a, rng.choice([0, 1, 255, 256, 0xFFFF,
                                                       rng.randrange(65536)]))
        elif fc == 15:
            q = min(q, 200)
            bc = (q + 7) // 8 + rng.choice([0, 0, 0, 1, -1])
            p = struct.pack(">BHHB", fc, a, q, bc & 0xFF) + bytes(
                rng.randrange(256) for _ in range(max(bc, 0)))
        elif fc in (16, 23):
            q = min(q, 100)
            values = [rng.choice([0, 7, 255, 256, 0x8000, rng.randrange(65536)])
                      for _ in range(q)]
            bc = 2 * q + rng.choice([0, 0, 0, 2, -2])
            body = struct.pack(f">{q}H", *values)[:max(bc, 0)]
            if fc == 16:
                p = struct.pack(">BHHB", fc, a, q, bc & 0xFF) + body
            else:
                ra = rng.choice(BOUNDARIES)
                p = struct.pack(">BHHHHB", fc, ra, rng.choice([1, 2, 126]), a, q, bc & 0xFF) + body
        elif fc == 22:
            p = struct.pack(">BHHH", fc, a, rng.randrange(65536), rng.randrange(65536))
        else:
            p = bytes((fc,)) + bytes(rng.randrange(256) for _ in range(4))
    if len(p) > 253:
        p = p[:253]
    if rng.random() < 0.02:  # a bad MBAP header
        return unit, p, mbap(1, unit, p, protocol=rng.choice([1, 0, 0]),
                             length=rng.choice([None, 0, 1, 255, 300]) if rng.random() < .5
                             else 0)
    return unit, p, mbap(rng.randrange(65536), unit, p)


async def test_random_frames(ncgate_gateway: Gateway) -> None:
    rng = random.Random(20261121)
    oracle = Oracle()
    address = ncgate_gateway.modbus_address
    client = await Raw.open(*address)
    closed = answered = 0
    for i in range(3000):
        unit, p, frame = random_frame(rng)
        header_ok = frame[2:4] == b"\0\0" and 2 <= int.from_bytes(frame[4:6], "big") <= 254
        await client.send(frame)
        if not header_ok:
            assert await client.closed_by_peer()
            client.close()
            client = await Raw.open(*address)
            closed += 1
            continue
        tid, _, answer = await client.recv()
        assert tid == int.from_bytes(frame[0:2], "big")
        assert answer[0] & 0x7F == p[0] & 0x7F
        answered += 1
        oracle.apply(unit, p)
        if i % 250 == 0:
            assert oracle.matches(ncgate_gateway), f"after frame {i}: {p.hex()}"
    assert oracle.matches(ncgate_gateway)
    assert closed > 10 and answered > 2500
    assert (await client.ask(bytes((4, 0, 0, 0, 1))))[:2] == b"\x04\x02"  # still serves
    client.close()
