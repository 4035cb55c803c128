"""The NC and the image as Structured Text sees them: the image's areas (``SA``, ``SK``,
``SYVAR``), the NC's status slots a program reads (``NC.P[k].STATE``, ``NC.LAST_SND``) and the
outputs it writes (``NC.START``, ``NC.P[k].MACK`` ..., from the one command table in
:mod:`ncgate.commands`).  The compiler names them, the scan (:mod:`ncgate.plc.scan`) fills and
acts on them, by these slots."""

from __future__ import annotations

from ncgate.commands import BY_WORD, plc_edges, plc_levels

IMAGE_NAMES = ("SA", "SAB", "SK", "SYVAR")

# NC.P[k] members: (index in the snapshot tuple, type).
NC_PROCESS = {"STATE": (0, "INT"), "N": (1, "DINT"), "LINE": (2, "DINT"),
              "WAITING": (3, "BOOL"), "ALARM": (4, "BOOL"), "ALARM_CODE": (5, "INT"),
              "IDLE": (6, "BOOL"), "HELD": (7, "BOOL"),
              # The auxiliary functions ([nc.aux]): the value last output, its strobe.
              "M": (8, "DINT"), "MSTROBE": (9, "BOOL"), "S": (10, "DINT"),
              "SSTROBE": (11, "BOOL"), "T": (12, "DINT"), "TSTROBE": (13, "BOOL"),
              "H": (14, "DINT"), "HSTROBE": (15, "BOOL")}

NC_LAST_SND = {"SENDER": (0, "INT"), "TARGET": (1, "INT"), "SEQ": (2, "UDINT")}

# NC outputs (BOOL, in _NCO), named by the command table (ncgate.commands): the commands that
# act on a rising edge (START, HOLD, RESET), then the switches' levels (OPT_STOP, BLOCK_SKIP),
# then HOLD_LEVEL, a feed-hold interlock.  plc/scan.py reads the words from the same table.
NC_OUTPUTS = {name: slot for slot, name in enumerate(
    [*(name for name, _ in plc_edges()), *(name for name, _, _ in plc_levels()), "HOLD_LEVEL"])}

# NC.P[k] outputs (BOOL, in _NCP[k]): the commands of one process, on a rising edge (those
# of the table that are not the cell's alone); the acknowledges of its auxiliary functions
# ([nc.aux]), levels.
NC_PROCESS_OUTPUTS = {name: slot for slot, name in enumerate(
    [*(name for name, word in plc_edges() if not BY_WORD[word].cell_only),
     "MACK", "SACK", "TACK", "HACK"])}

NC_VALUE_OUTPUTS = {"FEED_OVERRIDE"}  # INT percent: NC.FEED_OVERRIDE, NC.P[k].FEED_OVERRIDE
