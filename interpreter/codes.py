"""The one table of stable diagnostic and alarm codes.

Tests and users match on these codes (and on positions), never on message prose: a code, once
published, keeps its meaning.  Check-time diagnostics are ``NCnnn`` (errors) and ``NWnnn``
(warnings); runtime alarms are numbered ``AL<n>`` and their number is what the fieldbus status
registers carry.

Must not import anything from ``plc`` or ``gateway``.
"""

from __future__ import annotations

import enum


class Severity(enum.Enum):
    ERROR = "error"
    WARNING = "warning"


class DiagnosticCode(enum.Enum):
    """Check-time diagnostics (spec 1.6). The value is ``(code, severity, summary)``."""

    # -- syntax (the parser) --------------------------------------------------------------
    UNEXPECTED_CHARACTER = ("NC001", Severity.ERROR, "a character that starts no item")
    UNEXPECTED_TOKEN = ("NC002", Severity.ERROR, "an item where the syntax does not allow it")
    WORD_WITHOUT_VALUE = ("NC003", Severity.ERROR, "an address letter with no value (GXY)")
    UNKNOWN_CODE = ("NC004", Severity.ERROR, "a three-letter code that is not in the language")
    MISSING_COMPARISON = ("NC006", Severity.ERROR, "a WAI condition without = # > <")
    UNTERMINATED_STRING = ("NC010", Severity.ERROR, "a label or text without its closing quote")
    MISSING_CLOSE_PAREN = ("NC012", Severity.ERROR, "a code without its closing ')'")
    EXPRESSION_TOO_DEEP = ("NC013", Severity.ERROR, "an expression nested deeper than 64 levels")
    NUMBER_OUT_OF_RANGE = ("NC014", Severity.ERROR, "a number too large to represent")
    NOT_UTF8 = ("NC015", Severity.ERROR, "a program file that is not UTF-8")
    # -- semantics (the checker) ----------------------------------------------------------
    PROCESS_OUT_OF_RANGE = ("NC020", Severity.ERROR, "a process number that is not configured")
    WAIT_FOR_SELF = ("NC021", Severity.ERROR, "(WAI,n) on the process's own number")
    EXE_ON_SELF = ("NC022", Severity.ERROR, "(EXE,n,…) on the process's own number")
    EXE_ON_EXTERNAL = ("NC023", Severity.ERROR, "(EXE,n,…) on an external process")
    SND_TO_SELF = ("NC024", Severity.ERROR, "(SND,n) to the process's own number")
    COMPARE_BIT_ORDER = ("NC030", Severity.ERROR, "> or < on a bit variable")
    INDEX_OUT_OF_RANGE = ("NC031", Severity.ERROR, "a constant index outside the configured size")
    WRITE_TO_PLC_PACKET = ("NC032", Severity.ERROR, "a program writing SA or SK (PLC-owned)")
    BIT_VALUE = ("NC033", Severity.ERROR, "a bit compared with a value other than 0 or 1")
    FEED_NOT_POSITIVE = ("NC034", Severity.ERROR, "a feed (F) of zero or less")
    REPEATED_WORD = ("NC035", Severity.ERROR,
                     "an address twice in one block (X10X20, F100F5000, G1G1)")
    MODAL_CONFLICT = ("NC036", Severity.ERROR,
                      "two G or M codes of one modal group in one block (G0G1, M3M5)")
    UNKNOWN_LABEL = ("NC040", Severity.ERROR, "a jump to a label the program does not define")
    DUPLICATE_LABEL = ("NC041", Severity.ERROR, "a label defined twice")
    UNBALANCED_REPEAT = ("NC042", Severity.ERROR, "RPT without ERP, or ERP without RPT")
    REPEAT_TOO_DEEP = ("NC043", Severity.ERROR, "RPT bodies nested deeper than 16 levels")
    PROGRAM_NOT_FOUND = ("NC050", Severity.ERROR, "EXE of a program missing from its device")
    UNKNOWN_DEVICE = ("NC051", Severity.ERROR, "EXE naming a storage device not configured")
    # -- warnings -------------------------------------------------------------------------
    SYVAR_WITHOUT_INDEX = ("NW001", Severity.WARNING, "SYVAR with no index reads SYVAR0")
    UNMODELLED_CODE = ("NW002", Severity.WARNING, "an NC-110 code the simulator keeps inert")
    CONDITION_NEVER_HOLDS = ("NW003", Severity.WARNING, "a WAI value outside the variable's range")
    CYRILLIC_LOOKALIKE = ("NW004", Severity.WARNING, "Cyrillic look-alikes read as Latin (Е4)")
    UNKNOWN_G_OR_M = ("NW005", Severity.WARNING,
                      "a G or M code the language does not know (G999, M1.5): no effect")
    JUMP_INTO_REPEAT = ("NW006", Severity.WARNING,
                        "a jump from outside an RPT body into it: its ERP has no RPT running")
    # -- the ISG dialect (spec 5) ---------------------------------------------------------
    ISG_SYNTAX = ("IS001", Severity.ERROR, "ISG: an item where the block syntax does not allow it")
    ISG_UNKNOWN_COMMAND = ("IS002", Severity.ERROR, "ISG: a #command or $word not in the dialect")
    ISG_WORD_WITHOUT_VALUE = ("IS003", Severity.ERROR, "ISG: an address letter with no value")
    ISG_MISSING_BRACKET = ("IS004", Severity.ERROR, "ISG: a [ without its closing ]")
    ISG_BAD_SYNC_ARGUMENT = ("IS005", Severity.ERROR,
                             "ISG: a #SIGNAL/#WAIT argument that is not ID COUNT P[i] CH …")
    ISG_WAIT_SYN_PARAMS = ("IS006", Severity.ERROR,
                           "ISG: #WAIT SYN with parameters (only the decoder takes them)")
    ISG_UNKNOWN_EXTERNAL = ("IS007", Severity.ERROR, "ISG: a V.E. name [nc.ve] does not declare")
    ISG_UNDECLARED_VARIABLE = ("IS008", Severity.ERROR,
                               "ISG: a V.P. variable read but never declared or assigned")
    ISG_CHANNEL_OUT_OF_RANGE = ("IS009", Severity.ERROR, "ISG: a channel that is not configured")
    ISG_PARAM_INDEX = ("IS010", Severity.ERROR,
                       "ISG: a signal parameter P[i] outside 0..nc.isg.signal_params-1")
    ISG_UNBALANCED = ("IS011", Severity.ERROR,
                      "ISG: $IF/$ELSE/$ENDIF, $WHILE/$ENDWHILE or #VAR/#ENDVAR unbalanced")
    ISG_WRITE_PLC_OWNED = ("IS012", Severity.ERROR,
                           "ISG: a write of a V.E. variable mapped to SA or SK (PLC-owned)")
    ISG_COMMAND_NOT_ALONE = ("IS013", Severity.ERROR,
                             "ISG: a # or $ command sharing its block with other words")
    ISG_BAD_NUMBER = ("IS014", Severity.ERROR,
                      "ISG: a signal number, COUNT or channel that is not a positive integer")
    ISG_PARAM_OUT_OF_RANGE = ("IS015", Severity.ERROR,
                              "ISG: a P parameter outside P0..nc.e_params-1")
    ISG_BAD_REMOVE = ("IS016", Severity.ERROR,
                      "ISG: #SIGNAL REMOVE with ID and IDMIN/IDMAX, or IDMAX without IDMIN")
    ISG_REPEATED_WORD = ("IS017", Severity.ERROR, "ISG: an address twice in one block (X10 X20)")
    ISG_MODAL_CONFLICT = ("IS018", Severity.ERROR,
                          "ISG: two G or M codes of one modal group in one block (G00 G01)")
    ISG_SYNC_READ_IN_TRC = ("IS019", Severity.ERROR,
                            "ISG: a synchronous V.E. read while cutter compensation (G41/G42) "
                            "is on (the control's error 20651)")
    ISG_BUFFERED_SELF_SIGNAL = ("IW001", Severity.WARNING,
                                "ISG: a #WAIT for this channel's own #SIGNAL SYN with no #FLUSH "
                                "between: the buffer effect deadlocks it")
    ISG_UNKNOWN_G_OR_M = ("IW002", Severity.WARNING,
                          "ISG: a G or M code the subset does not implement (G41, G999): "
                          "no effect")

    @property
    def code(self) -> str:
        return self.value[0]

    @property
    def severity(self) -> Severity:
        return self.value[1]

    @property
    def summary(self) -> str:
        return self.value[2]


class AlarmCode(enum.IntEnum):
    """Runtime alarms (spec 2.6). The number is the fieldbus alarm code."""

    DIVISION_BY_ZERO = 101
    INDEX_OUT_OF_RANGE = 102
    VALUE_OUT_OF_RANGE = 103
    BAD_ARGUMENT = 104
    PROCESS_OUT_OF_RANGE = 110
    SND_TO_IDLE = 111
    EXE_ON_SELF = 112
    EXE_ON_EXTERNAL = 113
    WAIT_FOR_SELF = 114
    PROGRAM_NOT_FOUND = 120
    PROGRAM_INVALID = 121
    UNKNOWN_LABEL = 122
    REPEAT_MISMATCH = 123
    NO_FEED = 130
    SOFT_LIMIT = 131  # a move past an axis's soft travel limit (nc.limits.X ..)
    BLOCK_TOO_LONG = 132  # a move or dwell longer than nc.limits.block_s
    DEADLOCK = 140
    ORPHAN_WAIT = 141
    STALL = 142
    WAIT_TIMEOUT = 143
    RUNAWAY = 144
    AUX_TIMEOUT = 145  # no acknowledge of an auxiliary function within nc.aux.timeout_s
    MASTER_LOST = 150  # a fieldbus master's heartbeat stopped (CANopen 0x1016)
    PLC_FAULT = 160  # the PLC logic stopped on a runtime error (ST: file:line:col)
    SIGNAL_STORE_FULL = 170  # ISG: one signal more than nc.isg.max_events stored
    SIGNAL_PARAM_MISSING = 171  # ISG: a #WAIT's P[i] that no received signal carried
    UNDEFINED_VARIABLE = 172  # ISG: a V.P. variable read before any value was given

    @property
    def label(self) -> str:
        return f"AL{int(self)}"


# Codes of the NC-110 language that the simulator parses but does not model (spec 1.5).
UNMODELLED_CODES: frozenset[str] = frozenset(
    {
        "UAO", "UOT", "UIO", "URT", "MIR", "UCG", "SCF", "RQO", "RQU", "SPG", "DSP",
        "DLO", "EPP", "RQP", "UCV", "TMR", "GTO", "CLS", "CLD", "SOL", "PRO", "ISO",
    }
)
# Codes the language models, for "did you mean" suggestions.
MODELLED_CODES: frozenset[str] = frozenset(
    {"EXE", "REL", "WAI", "SND", "BNC", "BEQ", "BNE", "BGT", "BGE", "BLT", "BLE", "RPT", "ERP",
     "DLY", "DIS"}
)


def codes_markdown() -> str:
    """The table of codes as Markdown (``docs/diagnostics.md`` is this, kept in sync by a test)."""
    lines = [
        "# Diagnostic and alarm codes",
        "",
        "Generated from `interpreter/codes.py` (the one table); tests assert on these codes and on",
        "positions, never on message text. A published code keeps its meaning.",
        "",
        "| code | severity | what |",
        "|---|---|---|",
    ]
    lines += [f"| {c.code} | {c.severity.value} | {c.summary} |" for c in DiagnosticCode]
    lines += ["", "## Runtime alarms", "", "| code | name |", "|---|---|"]
    lines += [f"| {a.label} | {a.name.lower().replace('_', ' ')} |" for a in AlarmCode]
    return "\n".join(lines) + "\n"
