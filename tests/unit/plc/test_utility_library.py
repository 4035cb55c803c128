"""An open-source ST utility library loads and its functions return their documented results
(issue 29, "Done when").

The library is Wenger Automation & Engineering's *structured-text-utilities* (MIT, vendored
with its licence in ``library/structured_text_utilities/``, docs/decisions.md): about 3,100
lines of functions on arrays, numbers, strings and times, written "to compile on every device
that complies to IEC 61131-3".  It is written as logi.CAD 3 units (``UNIT``, ``INTERFACE``
with forward declarations and ``USES``, ``IMPLEMENTATION``): that wrapper is no IEC 61131-3,
so :func:`unwrap` blanks those lines (the line numbers stay the file's) and nothing else.

The library is loaded with ``plc.strict = false``, as a CODESYS or logi.CAD user would load
it: it is written in logi.CAD's dialect, and strict IEC refuses five of its spellings that
have an IEC equivalent -- ``ARRAY[..]`` (IEC: ``ARRAY[*]``, 6.5.3), ``_firstIndexOf(a)`` /
``_lastIndexOf(a)`` (IEC: ``LOWER_BOUND(a, 1)`` / ``UPPER_BOUND(a, 1)``), ``FUNCTION F : VOID``
(IEC: no type), a STRING's character ``s[i]`` taken as a BYTE (IEC: a CHAR, converted
with CHAR_TO_BYTE and BYTE_TO_CHAR) -- and its own ``INT_TO_STRING``, ``STRING_TO_INT``, ...
(names IEC reserves for its conversions; the library's compute the same).  That is honest
only if nothing else is let through: ``test_lenient_loading_uses_only_the_logicad_spellings``
checks that every warning is one of those, so no implicit narrowing (SW001) or
enumeration-as-integer (SW003) hides in a function that "loads".

What does not load is listed in ``NOT_LOADED`` with its code and reason, and the test checks
that exactly those functions fail, with those codes: a function ncgate comes to load fails
the test until it is taken off the list.  The rest is called through the scan, and each result
is the one the library's comments document, or the calendar's (ISO 8601) where they name a
date.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.scan import PlcRuntime
from ncgate.plc.st import nodes as n
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_source

from .st_harness import RecordingNc

LIBRARY = Path(__file__).parent / "library" / "structured_text_utilities"
UNITS = ("UTILITIES_STRING", "UTILITIES_TIME", "UTILITIES_MATH", "UTILITIES_ARRAY",
         "UTILITIES_BYTE")
CONTEXT = Context(64, 16, 8, 5, frozenset(), strict=False)  # logi.CAD's spellings: above
# logi.CAD's unit wrapper: a UNIT, INTERFACE/IMPLEMENTATION, USES, forward declarations.
WRAPPER = re.compile(r"^\s*(UNIT\s+\w+\s*;|INTERFACE|END_INTERFACE|IMPLEMENTATION|"
                     r"END_IMPLEMENTATION|USES\s[^;]*;|FUNCTION\s+\w+\s*;)\s*(//.*)?$")
FUNCTION = re.compile(r"^\s*FUNCTION\s+(\w+)\s*:")
END_FUNCTION = re.compile(r"^\s*END_FUNCTION\b")

VENDOR = ("calls ANYTYPE_TO_LITTLEBYTEARRAY / LITTLEBYTEARRAY_TO_ANYTYPE, logi.CAD's own "
          "functions, not IEC 61131-3's")
EXPD = "calls EXPD, logi.CAD's own power of ten, not IEC 61131-3's (EXPT(10.0, x))"
NEEDS = "calls a function above that does not load"
NOT_LOADED: dict[str, tuple[str, str]] = {
    **{name: ("ST012", EXPD) for name in ("ROUND_LREAL", "ROUND_REAL")},
    **{name: ("ST012", VENDOR) for name in (
        "DATE_TO_UDINT_INTERNAL", "UDINT_TO_DATE_INTERNAL", "TIME_OF_DAY_TO_UDINT_INTERNAL",
        "UDINT_TO_TIME_OF_DAY_INTERNAL")},
    **{name: ("ST012", NEEDS) for name in (
        "CREATE_TIME_OF_DAY", "CREATE_DATE", "CREATE_DATE_AND_TIME", "DISSECT_TIME_OF_DAY",
        "DISSECT_DATE", "DISSECT_DATE_AND_TIME", "GET_DAY_OF_WEEK", "GET_DAY_OF_YEAR",
        "GET_WEEK_OF_YEAR", "FORMAT_TIME_OF_DAY", "FORMAT_DATE", "FORMAT_DATE_AND_TIME")},
}
# The warnings of loading it (all SW002, a vendor spelling with IEC's named): what each says.
LOGICAD_SPELLINGS = ("ARRAY[..] is logi.CAD's spelling", "_firstIndexOf is logi.CAD's",
                     "_lastIndexOf is logi.CAD's", ": VOID (IEC: FUNCTION",
                     "is a standard function: this FUNCTION replaces it",
                     "logi.CAD read a STRING's character as a BYTE (IEC: ")


def unwrap(text: str) -> list[str]:
    return ["" if WRAPPER.match(line) else line for line in text.split("\n")]


def functions(lines: list[str]) -> dict[str, tuple[int, int]]:
    """Each FUNCTION's first and last line (0-based)."""
    out: dict[str, tuple[int, int]] = {}
    name, first = None, 0
    for i, line in enumerate(lines):
        found = FUNCTION.match(line)
        if found:
            name, first = found.group(1), i
        elif name is not None and END_FUNCTION.match(line):
            out[name] = (first, i)
            name = None
    return out


class Library:
    """The units, unwrapped; what does not load, found as ncgate loads it."""

    def __init__(self) -> None:
        self.lines = {unit: unwrap((LIBRARY / f"{unit}.st").read_text(encoding="utf-8"))
                      for unit in UNITS}
        self.where = {unit: functions(lines) for unit, lines in self.lines.items()}
        self.failed: dict[str, str] = {}  # function -> the code of its first diagnostic
        # Syntax, one function at a time (blank lines keep its line numbers).
        for unit, found in self.where.items():
            for name, (first, last) in found.items():
                text = "\n" * first + "\n".join(self.lines[unit][first:last + 1])
                try:
                    parse_source(text, unit)
                except LogicError as exc:
                    self.failed[name] = exc.diagnostics[0].code.code
        # Then the checks of the whole, until what is left loads.
        while True:
            try:
                self.logic = compile_logic(self.files(), CONTEXT)
                return
            except LogicError as exc:
                for d in exc.diagnostics:
                    name = self.function_at(d.span.file, d.span.line)
                    assert name is not None, d.render()
                    self.failed.setdefault(name, d.code.code)

    def function_at(self, unit: str, line: int) -> str | None:
        return next((name for name, (first, last) in self.where[unit].items()
                     if first < line <= last + 1), None)

    def files(self, extra: str = "") -> list[n.SourceFile]:
        out = []
        for unit, lines in self.lines.items():
            kept = list(lines)
            for name in self.failed:
                if name in self.where[unit]:
                    first, last = self.where[unit][name]
                    kept[first:last + 1] = [""] * (last + 1 - first)
            out.append(parse_source("\n".join(kept), unit))
        if extra:
            out.append(parse_source(extra, "calls.st"))
        return out


LIB = Library()


def run(body: str, decls: str) -> dict[str, Any]:
    """One scan of a PROGRAM that calls the library; its variables."""
    logic = compile_logic(LIB.files(f"PROGRAM calls\nVAR\n{decls}\nEND_VAR\n{body}\n"
                                    "END_PROGRAM\n"), CONTEXT)
    runtime = PlcRuntime(logic, IOImage(64, 16, 8), RecordingNc(), ["calls"])
    runtime.scan(0)
    names = [decl.split(":")[0].strip() for decl in decls.split(";") if decl.strip()]
    return {name: runtime.read(f"calls.{name}") for name in names}


def test_the_library_is_about_three_thousand_lines_of_ninety_seven_functions() -> None:
    total = sum(len(lines) for lines in LIB.lines.values())
    assert 3000 <= total <= 3200
    assert sum(len(found) for found in LIB.where.values()) == 97


def test_exactly_the_listed_functions_do_not_load_and_for_the_listed_reason() -> None:
    assert {name: code for name, code in LIB.failed.items()} == {
        name: code for name, (code, _) in NOT_LOADED.items()}
    loaded = {name for found in LIB.where.values() for name in found} - set(LIB.failed)
    assert len(loaded) == 79


def test_string_functions_return_what_their_comments_say() -> None:
    got = run("""
c3 := CONCAT3('a', 'b', 'c');
c9 := CONCAT9('1', '2', '3', '4', '5', '6', '7', '8', '9');
starts := STRING_STARTSWITH('ncgate', 'nc');
starts_short := STRING_STARTSWITH('nc', 'ncgate');
ends := STRING_ENDSWITH('ncgate', 'gate');
ends_case := STRING_ENDSWITH('ncgate', 'GATE');
padded := PAD_STRING_LEFT('7', 3, '0');
long_enough := PAD_STRING_LEFT('1234', 3, '0');
right := PAD_STRING_RIGHT('ab', 4, '*');
""", """c3 : STRING; c9 : STRING; starts : BOOL; starts_short : BOOL; ends : BOOL;
ends_case : BOOL; padded : STRING; long_enough : STRING; right : STRING;""")
    assert got == {"c3": "abc", "c9": "123456789", "starts": True, "starts_short": False,
                   "ends": True, "ends_case": False,  # "This function is case-sensitive."
                   "padded": "007",
                   "long_enough": "1234",  # "already equal or greater ... unchanged"
                   "right": "ab**"}


def test_time_functions_return_the_documented_example() -> None:
    """The comments' example: 1 day, 21 h, 34 min, 56.789 s is 'P1DT21H34M56.789S'."""
    got = run("""
t := CREATE_TIME(1, 21, 34, 56, 789);
parts := DISSECT_TIME(T#1d21h34m56s789ms);
iso := FORMAT_TIME(T#1d21h34m56s789ms, TIME_FORMAT#ISO8601);
short := FORMAT_TIME(T#2m, TIME_FORMAT#ISO8601);
tod.hour := 21; tod.minute := 34; tod.second := 56; tod.millisecond := 789;
tod_iso := FORMAT_TIME_OF_DAY_DISSECTED(tod, TIME_OF_DAY_FORMAT#ISO8601);
tod_hhmm := FORMAT_TIME_OF_DAY_DISSECTED(tod, TIME_OF_DAY_FORMAT#ISO8601_HHMM);
tod_nodlm := FORMAT_TIME_OF_DAY_DISSECTED(tod, TIME_OF_DAY_FORMAT#ISO8601_HHMMSS_NODLM);
""", """t : TIME; parts : TIME_DISSECTED; iso : STRING; short : STRING;
tod : TIME_OF_DAY_DISSECTED; tod_iso : STRING; tod_hhmm : STRING; tod_nodlm : STRING;""")
    assert got["t"] == ((24 + 21) * 60 + 34) * 60_000 + 56_789  # TIME in ms
    assert run("parts := DISSECT_TIME(T#1d21h34m56s789ms);\nd := parts.day;\n"
               "h := parts.hour;\nm := parts.minute;\nsec := parts.second;\n"
               "ms := parts.millisecond;",
               "parts : TIME_DISSECTED; d : USINT; h : USINT; m : USINT; sec : USINT; "
               "ms : UINT;") | {"parts": None} == {
        "parts": None, "d": 1, "h": 21, "m": 34, "sec": 56, "ms": 789}
    assert got["iso"] == "P1DT21H34M56.789S" and got["short"] == "PT2M"
    assert (got["tod_iso"], got["tod_hhmm"], got["tod_nodlm"]) == (
        "21:34:56.789", "21:34", "213456")


def test_dates_follow_the_calendar() -> None:
    """2019-10-31 (the comments' example) was a Thursday (ISO day 4), the 304th day of 2019
    and in ISO week 44; 2021-01-01 (a Friday) is in week 53 of 2020."""
    got = run("""
day := CREATE_DATE_INTERNAL(2019, 10, 31);
back := DISSECT_DATE_INTERNAL(day);
weekday := GET_DAY_OF_WEEK_INTERNAL(day);
of_year := GET_DAY_OF_YEAR_INTERNAL(day);
week := GET_WEEK_OF_YEAR_INTERNAL(day);
new_year_week := GET_WEEK_OF_YEAR_INTERNAL(CREATE_DATE_INTERNAL(2021, 1, 1));
iso := FORMAT_DATE_DISSECTED(back, DATE_FORMAT#ISO8601);
din := FORMAT_DATE_DISSECTED(back, DATE_FORMAT#DIN5008);
plain := FORMAT_DATE_DISSECTED(back, DATE_FORMAT#ISO8601_NODLM);
""", """day : UDINT; back : DATE_DISSECTED; weekday : USINT; of_year : UINT; week : USINT;
new_year_week : USINT; iso : STRING; din : STRING; plain : STRING;""")
    assert (got["weekday"], got["of_year"], got["week"], got["new_year_week"]) == (
        4, 304, 44, 53)
    assert (got["iso"], got["din"], got["plain"]) == ("2019-10-31", "31.10.2019", "20191031")


def test_lenient_loading_uses_only_the_logicad_spellings() -> None:
    warnings = LIB.logic.warnings
    assert warnings and all(w.code.code == "SW002" for w in warnings)
    assert [w.render() for w in warnings
            if not any(said in w.message for said in LOGICAD_SPELLINGS)] == []
    # each spelling is met where the library writes it: 45 ARRAY[..] parameters load
    assert sum("ARRAY[..]" in w.message for w in warnings) == 45
    # and 16 places mix a character with a BYTE: UTILITIES_BYTE lines 99-102, 106, 109
    # (BYTES_TO_STRING), 171, 172, 174, 179 (STRING_TO_BYTES); UTILITIES_STRING 209 twice
    # (COMPARE_STRINGS), 322, 325 (ENCODE_STRING), 356, 358 (DECODE_STRING)
    assert sorted((w.span.file, w.span.line) for w in warnings if "as a BYTE" in w.message
                  ) == sorted([*(("UTILITIES_BYTE", line) for line in (
                      99, 100, 101, 102, 106, 109, 171, 172, 174, 179)), *(
                      ("UTILITIES_STRING", line) for line in (209, 209, 322, 325, 356, 358))])


def test_sort_reverse_and_search_take_an_array_of_any_bounds() -> None:
    """SORT_x_ARRAY sorts in place (ascending: CALCULATE_STATISTICS sorts with it and takes
    the first element as the "minimal value"); REVERSE_x_ARRAY reverses in place;
    GET_FIRST_INDEX_OF_x_IN_ARRAY: "return its index.  If number is not present in array,
    the lowest index minus 1 is returned"."""
    got = run("""
SORT_INT_ARRAY(si); SORT_LREAL_ARRAY(sl); SORT_USINT_ARRAY(su);
REVERSE_DINT_ARRAY(rd); REVERSE_STRING_ARRAY(rs); REVERSE_WORD_ARRAY(rw);
found := GET_FIRST_INDEX_OF_INT_IN_ARRAY(30, fi);
missing := GET_FIRST_INDEX_OF_INT_IN_ARRAY(99, fi);
found_s := GET_FIRST_INDEX_OF_STRING_IN_ARRAY('b', fs);
missing_s := GET_FIRST_INDEX_OF_STRING_IN_ARRAY('z', fs);
found_r := GET_FIRST_INDEX_OF_REAL_IN_ARRAY(2.5, fr);
""", """si : ARRAY[-2..2] OF INT := [3, -1, 20, -7, 0]; sl : ARRAY[1..4] OF LREAL :=
[2.5, -1.0, 1.0E10, 0.0]; su : ARRAY[0..2] OF USINT := [255, 0, 7];
rd : ARRAY[5..8] OF DINT := [1, 2, 3, 4]; rs : ARRAY[1..3] OF STRING := ['a', 'b', 'c'];
rw : ARRAY[0..4] OF WORD := [1, 2, 3, 4, 5];
fi : ARRAY[-5..-1] OF INT := [10, 30, 20, 30, 40]; found : DINT; missing : DINT;
fs : ARRAY[3..5] OF STRING := ['a', 'b', 'b']; found_s : DINT; missing_s : DINT;
fr : ARRAY[1..3] OF REAL := [1.5, 2.5, 3.5]; found_r : DINT;""")
    assert got["si"] == [-7, -1, 0, 3, 20] and got["su"] == [0, 7, 255]
    assert got["sl"] == [-1.0, 0.0, 2.5, 1.0e10]
    assert got["rd"] == [4, 3, 2, 1] and got["rs"] == ["c", "b", "a"]
    assert got["rw"] == [5, 4, 3, 2, 1]  # an odd count: the middle one stays
    assert (got["found"], got["missing"]) == (-4, -6)  # the first 30; -5 - 1
    assert (got["found_s"], got["missing_s"], got["found_r"]) == (4, 2, 2)


def test_statistics_are_the_documented_ones() -> None:
    """FLOAT_ARRAY_STATISTICS / INTEGRAL_ARRAY_STATISTICS's comments: count, sum, minimal,
    maximal, median ("(lower) median" of integers), average, "sum of squares" (to the mean,
    as its function's comment says), standard deviation (of the population: the comment's
    SQRT(sum of squares / count)); "given array will be sorted"."""
    got = run("""
f := CALCULATE_STATISTICS_OF_LREAL_ARRAY(fl);
fc := f.count; fsum := f.sum; fmin := f.min_val; fmax := f.max_val; fmed := f.med_val;
favg := f.avg_val; fsq := f.sum_sqr; fdev := f.std_dev;
i := CALCULATE_STATISTICS_OF_INT_ARRAY(il);
ic := i.count; isum := i.sum; imin := i.min_val; imax := i.max_val; imed := i.med_val;
iavg := i.avg_val; isq := i.sum_sqr; idev := i.std_dev;
e := CALCULATE_STATISTICS_OF_DINT_ARRAY(el); emed := e.med_val;
u := CALCULATE_STATISTICS_OF_USINT_ARRAY(ul); usum := u.sum; umed := u.med_val;
umax := u.max_val;
""", """fl : ARRAY[1..4] OF LREAL := [8.0, 2.0, 6.0, 4.0]; f : FLOAT_ARRAY_STATISTICS;
fc : UDINT; fsum : LREAL; fmin : LREAL; fmax : LREAL; fmed : LREAL; favg : LREAL;
fsq : LREAL; fdev : LREAL;
il : ARRAY[0..4] OF INT := [5, 1, 4, 2, 3]; i : INTEGRAL_ARRAY_STATISTICS; ic : UDINT;
isum : DINT; imin : DINT; imax : DINT; imed : DINT; iavg : LREAL; isq : LREAL; idev : LREAL;
el : ARRAY[1..4] OF DINT := [40, 10, 30, 20]; e : INTEGRAL_ARRAY_STATISTICS; emed : DINT;
ul : ARRAY[1..3] OF USINT := [200, 100, 250]; u : UNSIGNED_INTEGRAL_ARRAY_STATISTICS;
usum : UDINT; umed : UDINT; umax : UDINT;""")
    # 2, 4, 6, 8: mean 5, squares 9 + 1 + 1 + 9 = 20, deviation sqrt(20 / 4)
    assert (got["fc"], got["fsum"], got["fmin"], got["fmax"], got["fmed"], got["favg"],
            got["fsq"]) == (4, 20.0, 2.0, 8.0, 5.0, 5.0, 20.0)
    assert got["fdev"] == pytest.approx(math.sqrt(5.0), rel=1e-12)
    assert got["fl"] == [2.0, 4.0, 6.0, 8.0]  # "given array will be sorted"
    # 1..5: mean 3, squares 4 + 1 + 0 + 1 + 4 = 10, deviation sqrt(2)
    assert (got["ic"], got["isum"], got["imin"], got["imax"], got["imed"], got["iavg"],
            got["isq"]) == (5, 15, 1, 5, 3, 3.0, 10.0)
    assert got["idev"] == pytest.approx(math.sqrt(2.0), rel=1e-12)
    assert got["emed"] == 20  # 10 20 30 40: the lower median
    assert (got["usum"], got["umed"], got["umax"]) == (550, 200, 250)  # no USINT wrap


def test_the_librarys_own_conversions_give_the_standards_results() -> None:
    """The library's INT_TO_STRING, STRING_TO_INT, ... replace IEC's (SW002): they must
    compute what IEC 61131-3's conversions do (6.6.2.5.x: the decimal text of the value)."""
    got = run("""
a := USINT_TO_STRING(255); b := SINT_TO_STRING(-128); c := UINT_TO_STRING(65535);
d := INT_TO_STRING(-32768); e := STRING_TO_USINT('200'); f := STRING_TO_SINT('-100');
g := STRING_TO_UINT('60000'); h := STRING_TO_INT('-12345');
""", """a : STRING; b : STRING; c : STRING; d : STRING; e : USINT; f : SINT; g : UINT;
h : INT;""")
    assert got == {"a": "255", "b": "-128", "c": "65535", "d": "-32768", "e": 200, "f": -100,
                   "g": 60000, "h": -12345}


def test_base64_gives_rfc_4648s_test_vectors() -> None:
    """BYTES_TO_STRING / STRING_TO_BYTES: "Base 64 Encoding as specified by RFC 4648".  Its
    section 10 test vectors ('f' is 'Zg==', 'fo' 'Zm8=', 'foobar' 'Zm9vYmFy'); 16#FB 16#FF
    is 111110 111111 1111(00): 62, 63, 60 -- '+/8=' in Table 1, '-_8=' in the URL
    alphabet of Table 2.  STRING_TO_BYTES: "remaining bytes will be set to NULL (0)"."""
    got = run("""
f := BYTES_TO_STRING(b_f, BINARY_ENCODING#BASE64);
fo := BYTES_TO_STRING(b_fo, BINARY_ENCODING#BASE64);
foobar := BYTES_TO_STRING(b_foobar, BINARY_ENCODING#BASE64);
plain := BYTES_TO_STRING(b_high, BINARY_ENCODING#BASE64);
url := BYTES_TO_STRING(b_high, BINARY_ENCODING#BASE64_URL);
STRING_TO_BYTES('Zm9vYmFy', BINARY_ENCODING#BASE64, decoded);
STRING_TO_BYTES('-_8=', BINARY_ENCODING#BASE64_URL, decoded_url);
""", """b_f : ARRAY[1..1] OF BYTE := [102]; b_fo : ARRAY[0..1] OF BYTE := [102, 111];
b_foobar : ARRAY[1..6] OF BYTE := [102, 111, 111, 98, 97, 114];
b_high : ARRAY[1..2] OF BYTE := [16#FB, 16#FF]; f : STRING; fo : STRING; foobar : STRING;
plain : STRING; url : STRING; decoded : ARRAY[1..8] OF BYTE; decoded_url : ARRAY[0..1] OF BYTE;""")
    assert (got["f"], got["fo"], got["foobar"]) == ("Zg==", "Zm8=", "Zm9vYmFy")
    assert (got["plain"], got["url"]) == ("+/8=", "-_8=")
    assert got["decoded"] == [102, 111, 111, 98, 97, 114, 0, 0]
    assert got["decoded_url"] == [0xFB, 0xFF]


def test_encode_and_decode_string_as_their_comments_say() -> None:
    """ENCODE_STRING: ASCII puts '?' (63) for a character past 127, "remaining bytes will
    be set to NULL (0)", a target too small cuts the string; DECODE_STRING "stops on first
    NULL (0)" and, ASCII, reads a byte past 127 as '?'.  'é' is 16#E9 in ISO 8859-1."""
    got = run("""
ENCODE_STRING('Aé', STRING_ENCODING#ASCII, ascii);
ENCODE_STRING('Aé', STRING_ENCODING#ISO8859_1, latin);
ENCODE_STRING('ABCDE', STRING_ENCODING#ISO8859_1, short);
text := DECODE_STRING(bytes, STRING_ENCODING#ISO8859_1);
text_ascii := DECODE_STRING(bytes, STRING_ENCODING#ASCII);
whole := DECODE_STRING(short, STRING_ENCODING#ISO8859_1);
""", """ascii : ARRAY[1..4] OF BYTE; latin : ARRAY[1..4] OF BYTE; short : ARRAY[0..2] OF BYTE;
bytes : ARRAY[1..5] OF BYTE := [110, 16#E9, 99, 0, 65]; text : STRING; text_ascii : STRING;
whole : STRING;""")
    assert got["ascii"] == [65, 63, 0, 0] and got["latin"] == [65, 0xE9, 0, 0]
    assert got["short"] == [65, 66, 67]
    assert (got["text"], got["text_ascii"], got["whole"]) == ("n\u00e9c", "n?c", "ABC")


def test_compare_strings_faults_on_its_character_0() -> None:
    """COMPARE_STRINGS loads but cannot run: its loop starts at ``in1[0]`` (UTILITIES_STRING
    line 208), and a string's first character is 1 (IEC 61131-3; its sister functions
    ENCODE_STRING and DECODE_STRING count from 1 too).  An index outside the string faults
    as one outside an array does; SORT_STRING_ARRAY, which calls it, faults there too."""
    for body in ("r := COMPARE_STRINGS('a', 'b');", "SORT_STRING_ARRAY(names);"):
        logic = compile_logic(LIB.files(f"PROGRAM calls\nVAR\nr : INT; names : ARRAY[1..2] OF "
                                        f"STRING := ['b', 'a'];\nEND_VAR\n{body}\n"
                                        "END_PROGRAM\n"), CONTEXT)
        runtime = PlcRuntime(logic, IOImage(64, 16, 8), RecordingNc(), ["calls"])
        runtime.scan(0)
        fault = runtime.status.fault
        assert fault is not None and fault.span is not None
        assert (fault.span.file, fault.span.line) == ("UTILITIES_STRING", 208)
        assert "character 0 of a string" in fault.message
