"""The timeline picture of a trace (``ncgate sim --gantt``, spec 4.4), as SVG.

One lane per process, coloured by state (derived from the trace's start/wait/resume/end/alarm
events), an arrow for every SND from the sender's lane to the target's, an arrow for every ISG
signal to each channel it is addressed to (a broadcast: to every lane waiting for it, or a
mark where it is stored), a mark on the PLC lane for every write by the PLC, the fieldbus or
the script, and a time axis in seconds.  A #FLUSH wait is a WAIT_COND interval labelled
"#FLUSH".
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from html import escape
from typing import TextIO

from ncgate.interpreter.engine.trace import EventDict

COLOURS = {
    "RUNNING": "#4caf50", "WAIT_PROC": "#ff9800", "WAIT_COND": "#2196f3",
    "WAIT_SND": "#e91e63", "WAIT_EXE": "#9c27b0", "HOLD": "#9e9e9e", "ALARM": "#d32f2f",
}
LABELS = {"RUNNING": "running", "WAIT_PROC": "WAI,n", "WAIT_COND": "WAI,cond",
          "WAIT_SND": "SND waits", "WAIT_EXE": "EXE waits", "HOLD": "feed hold",
          "ALARM": "alarm"}
_ON = {"proc": "WAIT_PROC", "cond": "WAIT_COND", "snd": "WAIT_SND", "exe": "WAIT_EXE",
       "signal": "WAIT_PROC", "flush": "WAIT_COND", "aux": "WAIT_COND"}

LEFT, RIGHT, TOP, LANE, GAP = 150, 30, 50, 34, 14


def state_intervals(events: Iterable[EventDict], processes: int
                    ) -> tuple[dict[int, list[tuple[float, float, str, str]]], float]:
    """Per process: (start, end, state, label) intervals; and the end time."""
    current: dict[int, tuple[float, str, str]] = {}
    out: dict[int, list[tuple[float, float, str, str]]] = {k: [] for k in
                                                           range(1, processes + 1)}
    end_t = 0.0
    # A feed hold (the trace's hold events) shows as HOLD over whatever the process does
    # beneath it (``beneath``), which it shows again when the hold ends.
    held: set[int] = set()
    beneath: dict[int, tuple[str, str]] = {}

    def close(proc: int, t: float) -> None:
        if proc in current:
            start, state, label = current.pop(proc)
            if t > start or state == "ALARM":
                out[proc].append((start, t, state, label))

    for e in events:
        t, proc, kind = e["t"], e["proc"], e["event"]
        end_t = max(end_t, t)
        if proc not in out:
            continue
        if kind == "start":
            close(proc, t)
            current[proc] = (t, "RUNNING", str(e["prog"]))
        elif kind == "wait":
            on_kind = next(iter(e["on"]))
            close(proc, t)
            target = e["on"][on_kind]
            label = f"N{e['n']} " if e.get("n") is not None else ""
            if on_kind == "cond":
                label += e["on"]["cond"]
            elif on_kind == "signal":
                label += f"signal {target}"
            elif on_kind == "flush":
                label += "#FLUSH"
            elif on_kind == "aux":  # an auxiliary function waits for the PLC's acknowledge
                label += f"{target} ack"
            else:
                label += f"{on_kind} P{target}"
            current[proc] = (t, _ON[on_kind], label)
        elif kind == "resume" and proc in current:
            close(proc, t)
            current[proc] = (t, "RUNNING", "")
        elif kind == "end":
            close(proc, t)
        elif kind == "alarm":
            close(proc, t)
            current[proc] = (t, "ALARM", str(e.get("code", "")))
        elif kind == "hold":
            if e["on"]:
                held.add(proc)
            else:
                held.discard(proc)
                if proc in current and current[proc][1] == "HOLD":
                    close(proc, t)
                    current[proc] = (t, *beneath.pop(proc, ("RUNNING", "")))
        if kind == "end":
            beneath.pop(proc, None)
        if proc in held and proc in current and current[proc][1] not in ("HOLD", "ALARM"):
            _, state, label = current[proc]
            beneath[proc] = (state, label)
            close(proc, t)
            current[proc] = (t, "HOLD", "hold")
    end_t = max(end_t, 1e-6)
    for proc in list(current):
        close(proc, end_t)
    return out, end_t


def _text_width(text: str, size: int) -> float:
    """A generous width of ``text`` in a sans-serif font of ``size`` px, so that what is laid
    out by it never overlaps: 0.75 em for a capital or a wide sign, 1 em for M and W, 0.65
    em for the rest -- over DejaVu Sans' and Arial's advance widths (capitals 0.61-0.72 em,
    digits 0.64, "=" 0.84).  0.62 em a character for every glyph was short of "SYVAR5=40"
    (6.1 em drawn, 5.6 laid out), and labels of writes close in time overlapped."""
    return size * sum(1.0 if c in "MWmw@" else 0.85 if c in "=+<>~" else 0.75 if c.isupper()
                      else 0.65 for c in text)


def _ticks(end_t: float) -> list[float]:
    raw = end_t / 10
    magnitude = 10 ** math.floor(math.log10(raw)) if raw > 0 else 1
    step = next(m * magnitude for m in (1, 2, 5, 10) if m * magnitude >= raw)
    return [i * step for i in range(int(end_t / step) + 1)]


# A write's mark by who wrote it: the PLC logic, the plant's models and logic, anyone else
# (a fieldbus client, the API, a script, the console).
WRITERS = {"plc": ("#3f51b5", "PLC"), "plant": ("#8d6e63", "plant"),
           "other": ("#c2185b", "outside")}


def _writer(event: EventDict) -> str:
    who = str(event.get("who", ""))
    if who == "plc" or who.startswith("plc "):
        return "plc"
    if who == "plant" or who.startswith("plant "):
        return "plant"
    return "other"


def write_gantt(events: Sequence[EventDict], processes: int, out: TextIO,
                external: Iterable[int] = (), width: int = 1000) -> None:
    lanes, end_t = state_intervals(events, processes)
    external = set(external)
    plot_w = width - LEFT - RIGHT
    plc_y = TOP
    lane_y = {k: TOP + (LANE + GAP) * k for k in range(1, processes + 1)}
    # The legend's entries, laid out in rows that fit the width (it was one row that ran
    # past the picture's right edge and was cut).
    drawn = {state for lane in lanes.values() for _, _, state, _ in lane}
    writers = {_writer(e) for e in events if e["event"] == "write" and e["proc"] == 0}
    entries = [(COLOURS[state], LABELS[state]) for state in COLOURS
               if state != "HOLD" or "HOLD" in drawn] + [
        ("#222", "\u2192 SND"), ("#00796b", "\u2192 #SIGNAL")] + [
        (colour, f"\u25bc {label} write") for kind, (colour, label) in WRITERS.items()
        if kind in writers or (kind == "plc" and not writers)]
    legend: list[tuple[float, int, str, str]] = []  # x, row, colour, label
    lx, row = float(LEFT), 0
    for colour, label in entries:
        w = 16 + _text_width(label, 12) + 24
        if lx + w > width - 10 and lx > LEFT:
            lx, row = float(LEFT), row + 1
        legend.append((lx, row, colour, label))
        lx += w
    height = TOP + (LANE + GAP) * (processes + 1) + 56 + 18 * (row + 1)

    def x(t: float) -> float:
        return LEFT + plot_w * t / end_t

    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'font-family="sans-serif" font-size="12">',
        '<defs><marker id="arrow" markerWidth="8" markerHeight="8" refX="7" refY="4" '
        'orient="auto"><path d="M0,0 L8,4 L0,8 z" fill="#222"/></marker></defs>',
        f'<rect width="{width}" height="{height}" fill="white"/>',
        f'<text x="{LEFT}" y="22" font-size="15" font-weight="bold">ncgate timeline '
        f'({end_t:.3f} s simulated)</text>',
    ]
    axis_y = TOP + (LANE + GAP) * (processes + 1) - GAP + 6
    for t in _ticks(end_t):
        parts.append(f'<line x1="{x(t):.1f}" y1="{TOP - 6}" x2="{x(t):.1f}" y2="{axis_y}" '
                     'stroke="#ddd"/>')
        parts.append(f'<text x="{x(t):.1f}" y="{axis_y + 14}" text-anchor="middle">'
                     f'{t:g}</text>')
    parts.append(f'<text x="{LEFT + plot_w / 2}" y="{axis_y + 30}" text-anchor="middle">'
                 'time (s)</text>')
    parts.append(f'<text x="10" y="{plc_y + LANE / 2 + 4}">PLC / fieldbus</text>')
    parts.append(f'<rect x="{LEFT}" y="{plc_y}" width="{plot_w}" height="{LANE}" '
                 'fill="#f5f5f5" stroke="#ccc"/>')
    for k, y in lane_y.items():
        name = f"P{k}" + (" (external)" if k in external else "")
        parts.append(f'<text x="10" y="{y + LANE / 2 + 4}">{name}</text>')
        parts.append(f'<rect x="{LEFT}" y="{y}" width="{plot_w}" height="{LANE}" '
                     'fill="#fafafa" stroke="#ccc"/>')
        for start, stop, state, label in lanes[k]:
            w = max(x(stop) - x(start), 2.0)
            title = f"{state} {start:.3f}-{stop:.3f} s {label}".strip()
            parts.append(f'<rect x="{x(start):.1f}" y="{y + 3}" width="{w:.1f}" '
                         f'height="{LANE - 6}" fill="{COLOURS[state]}"><title>{escape(title)}'
                         f'</title></rect>')
            if label and w > 7 * len(label):
                parts.append(f'<text x="{x(start) + 4:.1f}" y="{y + LANE / 2 + 4}" '
                             f'fill="white">{escape(label)}</text>')

    def arrow(t: float, sender: int, target: int, title: str, colour: str = "#222") -> None:
        y1 = lane_y[sender] + LANE / 2
        y2: float = lane_y[target] + (3 if lane_y[target] > y1 else LANE - 3)
        if target == sender:  # a channel's signal to itself: a short hook on its lane
            y2 = y1 - LANE / 2 + 3
        parts.append(f'<line x1="{x(t):.1f}" y1="{y1:.1f}" x2="{x(t) + 6:.1f}" '
                     f'y2="{y2:.1f}" stroke="{colour}" stroke-width="1.5" '
                     f'marker-end="url(#arrow)"><title>{escape(title)}</title></line>')

    waiting: dict[int, dict[str, object]] = {}  # proc -> what it waits on now
    label_end = 0.0  # where the last write label drawn ends
    for e in events:
        kind, proc = e["event"], e["proc"]
        if kind == "wait":
            waiting[proc] = e["on"]
        elif kind in ("resume", "end", "alarm"):
            waiting.pop(proc, None)
        if kind == "snd" and e["to"] in lane_y and proc in lane_y:
            arrow(e["t"], proc, e["to"], f"SND P{proc} -> P{e['to']} at {e['t']:.3f} s")
        elif kind == "signal" and proc in lane_y:
            title = f"#SIGNAL ID{e['id']} P{proc} -> {{}} at {e['t']:.3f} s ({e['level']})"
            if e["to"] == "all":
                takers = [k for k, on in waiting.items() if k in lane_y
                          and on.get("signal") == e["id"] and on.get("from") == "all"]
                for k in takers:
                    arrow(e["t"], proc, k, title.format("all"), "#00796b")
                if not takers:  # stored for later WAITs: a diamond on the sender's lane
                    cx, cy = x(e["t"]), lane_y[proc] + LANE / 2
                    parts.append(f'<path d="M{cx:.1f},{cy - 6:.1f} L{cx + 6:.1f},{cy:.1f} '
                                 f'L{cx:.1f},{cy + 6:.1f} L{cx - 6:.1f},{cy:.1f} z" '
                                 f'fill="#00796b"><title>{escape(title.format("all"))}, '
                                 'stored</title></path>')
            else:
                for k in e["to"]:
                    if k in lane_y:
                        arrow(e["t"], proc, k, title.format(f"P{k}"), "#00796b")
        elif kind in ("aux", "aux_ack") and proc in lane_y:
            # An auxiliary function: up from the lane to the PLC when output, down from the
            # PLC when acknowledged (a strobe and its answer, [nc.aux]).
            cx, up = x(e["t"]), kind == "aux"
            y1, y2 = ((lane_y[proc] + 3, plc_y + LANE - 3) if up
                      else (plc_y + LANE - 3, lane_y[proc] + 3))
            colour = "#ef6c00" if up else "#6a1b9a"
            code, t = str(e["code"]), float(e["t"])
            what = (f"{code} ({e['handshake']})" if up
                    else f"{code} acknowledged by {e['by']}")
            dash = "" if up else ' stroke-dasharray="3,2"'
            title = escape(f"P{proc} {what} at {t:.3f} s")
            parts.append(f'<line x1="{cx:.1f}" y1="{y1:.1f}" x2="{cx:.1f}" y2="{y2:.1f}" '
                         f'stroke="{colour}" stroke-width="1.5" marker-end="url(#arrow)"'
                         f'{dash}><title>{title}</title></line>')
            if up:
                parts.append(f'<text x="{cx + 3:.1f}" y="{lane_y[proc] - 2:.1f}" '
                             f'font-size="10" fill="{colour}">{escape(str(e["code"]))}</text>')
        elif e["event"] == "write" and e["proc"] == 0:
            cx = x(e["t"])
            fill = WRITERS[_writer(e)][0]
            parts.append(f'<path d="M{cx - 5:.1f},{plc_y + 8} L{cx + 5:.1f},{plc_y + 8} '
                         f'L{cx:.1f},{plc_y + 20} z" fill="{fill}"><title>'
                         f'{escape(str(e["who"]))}: {escape(str(e["var"]))}={e["value"]} at '
                         f'{e["t"]:.3f} s</title></path>')
            # A label where it has room: writes close in time had their labels drawn over
            # each other (a smear); every mark keeps its title.
            label = f'{e["var"]}={e["value"]}'
            lw = _text_width(label, 10)
            if cx + 7 >= label_end and cx + 7 + lw <= LEFT + plot_w:
                parts.append(f'<text x="{cx + 7:.1f}" y="{plc_y + 30}" font-size="10" '
                             f'class="write-label">{escape(label)}</text>')
                label_end = cx + 7 + lw + 4
            elif cx - 7 - lw >= max(label_end, LEFT):  # at the right edge: before the mark
                parts.append(f'<text x="{cx - 7:.1f}" y="{plc_y + 30}" font-size="10" '
                             f'text-anchor="end" class="write-label">{escape(label)}</text>')
                label_end = cx - 7 + 4
    legend_y = axis_y + 56
    for lx, row, colour, label in legend:
        y = legend_y + 18 * row
        parts.append(f'<g class="legend"><rect x="{lx:.0f}" y="{y - 10}" width="12" '
                     f'height="12" fill="{colour}"/><text x="{lx + 16:.0f}" y="{y}">'
                     f'{escape(label)}</text></g>')
    parts.append("</svg>")
    out.write("\n".join(parts) + "\n")
