"""The stable codes of the Structured Text front end, and its diagnostics and exceptions.

Codes are ``STnnn``; tests and users match on code + position, never on the message.  A
diagnostic renders as every ncgate diagnostic does (spec 1.6): ``file:line:col: error CODE:
message``, the source line, a caret.  Stdlib only (the PLC package does not import the
interpreter's table; ``docs/diagnostics.md`` shows both).
"""

from __future__ import annotations

import difflib
import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from ncgate.errors import render_diagnostic
from ncgate.plc.image import PlcError
from ncgate.plc.st.nodes import Span


class StCode(enum.Enum):
    """(code, summary)."""

    # -- syntax ----------------------------------------------------------------------------------
    UNEXPECTED_CHARACTER = ("ST001", "a character that starts no item")
    UNEXPECTED_TOKEN = ("ST002", "an item where the syntax does not allow it")
    UNEXPECTED_END = ("ST003", "the file ends inside a declaration or statement")
    NOT_UTF8 = ("ST004", "a logic file that is not UTF-8")
    BAD_LITERAL = ("ST005", "a literal that is malformed or too large")
    # -- names -----------------------------------------------------------------------------------
    UNKNOWN_NAME = ("ST010", "a variable that is not declared")
    UNKNOWN_TYPE = ("ST011", "a type that is neither elementary nor a function block")
    UNKNOWN_CALL = ("ST012", "a call of something that is not a function or function block")
    DUPLICATE_NAME = ("ST013", "a name declared twice, or a reserved name (SA, SK, NC, …)")
    UNKNOWN_MEMBER = ("ST014", "a member that the instance, NC or NC.P[k] does not have")
    # -- types -----------------------------------------------------------------------------------
    TYPE_MISMATCH = ("ST020", "a value of a type the place does not take (no implicit narrowing)")
    CONSTANT_RANGE = ("ST021", "a constant that does not fit its type")
    INDEX_RANGE = ("ST022", "a constant index outside the array, image or process count")
    READ_ONLY = ("ST023", "a write to an NC input, a CONSTANT, an output or a loop variable")
    BAD_ARGUMENTS = ("ST024", "arguments missing, unknown, repeated or of the wrong form")
    NOT_CALLABLE = ("ST025", "a call statement on a variable that is no function block")
    EXIT_OUTSIDE_LOOP = ("ST026", "EXIT or CONTINUE outside FOR, WHILE or REPEAT")
    DIVISION_BY_ZERO = ("ST027", "a division or MOD by the constant 0")
    NOT_CONSTANT = ("ST028", "an initial value or CASE label that is not a constant")
    # -- structure -------------------------------------------------------------------------------
    RECURSION = ("ST030", "a function or function block that calls or contains itself")
    UNSUPPORTED = ("ST031", "a construct outside ncgate's ST subset")
    DUPLICATE_POU = ("ST032", "two POUs with one name")
    EXTERNAL_SENDER = ("ST033", "NC.SEND from a process that is not external")
    DUPLICATE_LABEL = ("ST034", "a CASE value listed twice")
    # -- what CODESYS, TwinCAT and matiec write beyond the subset: each its own code --------
    INHERITANCE = ("ST035", "EXTENDS or IMPLEMENTS: a function block that inherits "
                   "(object-oriented ST)")
    QUALIFIED_TYPE = ("ST036", "a namespace-qualified type (Tc2_Standard.TON, Lib.T_Type)")
    FB_INIT = ("ST037", "arguments for an instance's FB_init at its declaration "
               "(fb : FB_Axis(nId := 1))")
    FB_ARRAY_INIT = ("ST038", "FB_init arguments for an array of function blocks "
                     "(ARRAY[1..2] OF FB_Axis[(nId := 1), (nId := 2)])")
    TYPED_ENUM = ("ST039", "an enumeration with a base type ((A, B) DINT; INT (A := 1, B))")
    ACCESS_SPECIFIER = ("ST041", "an access specifier or modifier on a POU (FUNCTION_BLOCK "
                        "PUBLIC, ABSTRACT, FINAL)")
    STRAY_SEMICOLON = ("ST042", "a ';' where none may stand (after END_PROGRAM, a POU's name, "
                       "another ';' in a declaration)")
    # -- warnings (plc.strict = false: CODESYS's leniencies load, the IEC spelling said) ----
    IMPLICIT_NARROWING = ("SW001", "an implicit narrowing conversion (IEC: DINT_TO_INT …)")
    VENDOR_EXTENSION = ("SW002", "a vendor extension (E.RUN, AND_THEN, OR_ELSE): IEC's "
                        "spelling given")
    ENUM_AS_INTEGER = ("SW003", "an enumeration value used as an integer, or the reverse")
    UNKNOWN_PRAGMA = ("SW004", "a pragma ncgate does not know (matiec's inline C {{ … }}, "
                      "a CODESYS conditional {IF …}): ignored, in strict mode too")
    RETAIN_IN_PLANT = ("SW005", "VAR RETAIN in the plant's logic ([plant] logic): ignored, the "
                       "plant keeps nothing across a restart")
    SHARED_OUTPUT = ("SW006", "an image variable the logic writes that another writer of the "
                     "cell writes too (the PLC's logic, the plant's logic, a plant model): "
                     "each overwrites the other")
    # -- PLCopen XML -------------------------------------------------------------------------------
    XML_PROJECT = ("ST040", "a PLCopen XML file that is not well-formed or not a TC6 project")

    @property
    def code(self) -> str:
        return self.value[0]

    @property
    def summary(self) -> str:
        return self.value[1]

    @property
    def is_error(self) -> bool:
        return not self.value[0].startswith("SW")


@dataclass(frozen=True, slots=True)
class StDiagnostic:
    code: StCode
    message: str
    span: Span
    source_line: str

    @property
    def is_error(self) -> bool:
        return self.code.is_error

    def render(self) -> str:
        s = self.span
        return render_diagnostic(s.file, s.line, s.column,
                                 "error" if self.is_error else "warning", self.code.code,
                                 self.message, self.source_line)

    def __str__(self) -> str:
        return self.render()


class LogicError(PlcError, SyntaxError):
    """PLC logic that cannot load: it carries every diagnostic found."""

    def __init__(self, diagnostics: Sequence[StDiagnostic]) -> None:
        self.diagnostics = tuple(diagnostics)
        text = "\n".join(d.render() for d in self.diagnostics)
        super().__init__(text)
        first = self.diagnostics[0] if self.diagnostics else None
        self.msg = first.message if first else "invalid logic"
        if first is not None:
            self.filename, self.lineno = first.span.file, first.span.line
            self.offset, self.text = first.span.column, first.source_line

    def __str__(self) -> str:
        return "\n".join(d.render() for d in self.diagnostics)


def did_you_mean(word: str, candidates: Iterable[str]) -> str:
    """`` (did you mean X?)`` for the closest candidate, or ""."""
    pool = {c.upper(): c for c in candidates}
    found = difflib.get_close_matches(word.upper(), list(pool), n=1, cutoff=0.6)
    return f" (did you mean {pool[found[0]]}?)" if found else ""


def codes_markdown() -> str:
    lines = ["", "## Structured Text (PLC logic)", "",
             "Generated from `plc/st/diagnostics.py`. SW codes are warnings: SW001..SW003 "
             "are given only with `plc.strict = false` (where strict IEC refuses the "
             "construct), SW004 always, SW005 in the plant's logic, SW006 where a logic and "
             "another writer share a variable.", "",
             "| code | what |", "|---|---|"]
    lines += [f"| {c.code} | {c.summary} |" for c in StCode]
    return "\n".join(lines) + "\n"
