"""PLCopen TC6 XML -> the Structured Text the compiler reads, every position pointing back
into the XML file.

TC6 XML (PLCopen's exchange format, 2.01 and 2.0) is what CODESYS, TwinCAT, Beremiz and
OpenPLC export a project as.  It holds the project's data types (``types/dataTypes``), its
POUs (``types/pous``: the interface as XML elements, the body as text inside ``<ST>``) and
its global variables (``instances/configurations``, their resources, and the global variable
lists CODESYS and TwinCAT put in the project's ``addData``).  :func:`parse_plcopen` writes
them as one ST text -- ``TYPE``, then ``VAR_GLOBAL``, then each POU in file order -- parses
that with :func:`ncgate.plc.st.parser.parse_source`, and moves every span of the tree (and
of a syntax error) from the ST text back to the XML: a statement of a body to its own line
and column inside the ``<ST>`` element, a declaration to its ``<variable>`` element, a type
to its type element.  A diagnostic or a FAULT then shows the XML file's line.

What is not ST -- an LD, FBD, IL or SFC body, a CODESYS method, property, action or
transition -- is ST031 where its element starts ("not supported: LD in POU X"); a file that
is not well-formed XML, or not a TC6 project, is ST040.  Tasks and program instances of a
configuration are not read: the scan is one cyclic task running the PROGRAMs ``plc.programs``
names (docs/decisions.md).

Stdlib only: ``xml.parsers.expat``, because it tells where each element and each piece of
text starts (``xml.etree`` does not).  A DOCTYPE is refused: a TC6 export has none, and
refusing it keeps entity expansion out.
"""

from __future__ import annotations

import bisect
import dataclasses
import errno
import os
import re
import stat
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.parsers import expat

from ncgate.plc.st import nodes as n
from ncgate.plc.st.diagnostics import LogicError, StCode, StDiagnostic
from ncgate.plc.st.parser import parse_source

TC6_NAMESPACES = ("http://www.plcopen.org/xml/tc6_0201", "http://www.plcopen.org/xml/tc6_0200")
XML_SUFFIX = ".xml"
# An interface's variable lists, as ST sections.
SECTIONS = {"inputVars": "VAR_INPUT", "outputVars": "VAR_OUTPUT", "inOutVars": "VAR_IN_OUT",
            "localVars": "VAR", "tempVars": "VAR_TEMP", "externalVars": "VAR_EXTERNAL",
            "globalVars": "VAR_GLOBAL", "accessVars": "VAR_ACCESS"}
# A variable list's attributes, as ST qualifiers (TwinCAT's persistent too).
QUALIFIERS = (("constant", "CONSTANT"), ("retain", "RETAIN"), ("nonretain", "NON_RETAIN"),
              ("persistent", "PERSISTENT"))
POU_KINDS = {"program": "PROGRAM", "functionBlock": "FUNCTION_BLOCK", "function": "FUNCTION"}
BODY_LANGUAGES = ("IL", "ST", "FBD", "LD", "SFC")
# CODESYS's and TwinCAT's addData: global variable lists, and what ST here cannot hold.
GLOBAL_VARS_DATA = "http://www.3s-software.com/plcopenxml/globalvars"
UNSUPPORTED_DATA = {"method": ("Method", "METHOD"), "property": ("Property", "PROPERTY"),
                    "action": ("Action", "ACTION"), "transition": ("Transition", "TRANSITION")}
# The elementary types' elements whose ST name differs from the element's.
ELEMENTARY_NAMES = {"string": "STRING", "wstring": "WSTRING"}

Where = tuple[int, int]  # line (1-based), column (0-based, in characters) in the XML file
DOCTYPE_COLUMN = -1  # a Where's column: that of "<!DOCTYPE" in its line


# ---- the XML, with positions ---------------------------------------------------------------

@dataclass(slots=True, eq=False)
class _El:
    tag: str  # the local name
    ns: str
    attrs: dict[str, str]
    at: Where  # where its start tag begins
    end: Where = (0, 0)  # where its end tag begins
    children: list[_El] = field(default_factory=list)
    text: list[tuple[str, Where]] = field(default_factory=list)  # its own character data

    def child(self, tag: str) -> _El | None:
        return next((c for c in self.children if c.tag == tag), None)

    def all(self, tag: str) -> list[_El]:
        return [c for c in self.children if c.tag == tag]

    def chunks(self) -> list[tuple[str, Where]]:
        """Its character data and its descendants', in document order (iterative: an
        export may nest deeply)."""
        out: list[tuple[str, Where]] = []
        stack: list[_El | tuple[str, Where]] = [self]
        while stack:
            item = stack.pop()
            if isinstance(item, tuple):
                out.append(item)
                continue
            # Text and children interleave in the file: in the order of their positions.
            inside: list[_El | tuple[str, Where]] = [*item.text, *item.children]
            inside.sort(key=lambda x: x[1] if isinstance(x, tuple) else x.at)
            stack += reversed(inside)
        return out


class _XmlProblem(Exception):
    def __init__(self, message: str, at: Where) -> None:
        super().__init__(message)
        self.message = message
        self.at = at


# Elements kept without what is inside them: nothing in there is read, and an export's
# graphical bodies and layout are most of its size (a tree of them, kept, took 4 GB and
# two minutes for a 50 MB file).
OPAQUE = frozenset(("fileHeader", "contentHeader", "documentation", *BODY_LANGUAGES)) - {"ST"}


def _opaque(el: _El, parent: _El | None) -> bool:
    """Whether nothing inside ``el`` is read: layout, documentation, a body not in ST, an
    ``addData`` item ncgate does not read, a method's (or action's ...) content."""
    if el.tag in OPAQUE:
        return True
    if parent is None or parent.tag != "data":
        return el.tag == "data" and parent is not None and parent.tag == "addData" and not (
            el.attrs.get("name") == GLOBAL_VARS_DATA
            or el.attrs.get("name", "").rpartition("/")[2] in UNSUPPORTED_DATA)
    return parent.attrs.get("name") != GLOBAL_VARS_DATA  # a Method, Property, ...: its name


def _read_xml(data: bytes) -> _El:
    parser = expat.ParserCreate(namespace_separator="}")
    parser.buffer_text = False  # one call per piece of text, so that each has its position
    root: list[_El] = []
    stack: list[_El] = []
    skipping = 0  # > 0: inside an opaque element, this many elements deep (itself 1)
    in_st = 0  # > 0: inside a body's ST element (the only text read)

    def where() -> Where:
        return parser.CurrentLineNumber, parser.CurrentColumnNumber

    def start(name: str, attrs: dict[str, str]) -> None:
        nonlocal skipping, in_st
        if skipping:
            skipping += 1
            return
        ns, _, tag = name.rpartition("}")
        el = _El(tag, ns, attrs, where())
        parent = stack[-1] if stack else None
        if parent is not None:
            parent.children.append(el)
        else:
            root.append(el)
        stack.append(el)
        if in_st or (tag == "ST" and parent is not None and parent.tag == "body"):
            in_st += 1
        elif _opaque(el, parent):
            skipping = 1

    def end(name: str) -> None:
        nonlocal skipping, in_st
        if skipping > 1:
            skipping -= 1
            return
        skipping = 0
        in_st = max(in_st - 1, 0)
        stack.pop().end = where()

    def text(data: str) -> None:
        if in_st:
            stack[-1].text.append((data, where()))

    def doctype(*args: Any) -> None:
        # (expat is past its name: the column is where <!DOCTYPE is in the line's text)
        raise _XmlProblem("a DOCTYPE: a PLCopen export has none (and its entities are not "
                          "read)", (parser.CurrentLineNumber, DOCTYPE_COLUMN))

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = text
    parser.StartDoctypeDeclHandler = doctype
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise _XmlProblem(f"not well-formed XML: {expat.ErrorString(exc.code)}",
                          (exc.lineno, exc.offset)) from None
    return root[0]


# ---- the ST text, and the way back ------------------------------------------------------------

class _Text:
    """The ST text being written, and for each of its lines where its pieces come from."""

    def __init__(self) -> None:
        self.lines: list[str] = [""]
        # Per line: (column in the ST line, XML line, XML column, slides): a piece that
        # slides maps column for column (body text); one that does not maps every column
        # to its element (a generated declaration).
        self.maps: list[list[tuple[int, int, int, bool]]] = [[]]

    def put(self, text: str, at: Where, slides: bool = False) -> None:
        line, column = at
        for k, part in enumerate(text.split("\n")):
            if k:
                self.newline()
                line, column = line + 1, 0
            if part:
                self.maps[-1].append((len(self.lines[-1]), line, column, slides))
                self.lines[-1] += part

    def newline(self) -> None:
        if self.lines[-1]:
            self.lines.append("")
            self.maps.append([])

    def source(self) -> str:
        return "\n".join(self.lines) + "\n"

    def move(self, line: int, column: int) -> Where:
        """An ST position (1-based) -> its XML line and column (1-based)."""
        k = min(max(line, 1), len(self.maps)) - 1
        while k > 0 and not self.maps[k]:  # past the end, or on an empty line
            k -= 1
            column = 1 << 30
        segments = self.maps[k]
        if not segments:
            return 1, 1
        i = max(bisect.bisect_right([s[0] for s in segments], column - 1) - 1, 0)
        start, xml_line, xml_column, slides = segments[i]
        if slides:
            length = (segments[i + 1][0] if i + 1 < len(segments) else len(self.lines[k])
                      ) - start
            xml_column += min(column - 1 - start, max(length - 1, 0))
        return xml_line, xml_column + 1


def _moved(root: Any, move: Callable[[n.Span], n.Span]) -> Any:
    """``root`` with every Span in it moved; iterative, since an expression of 10,000 terms
    nests 10,000 deep."""
    done: dict[int, Any] = {}

    def parts(obj: Any) -> list[Any]:
        if isinstance(obj, tuple | list):
            return [x for x in obj if _container(x)]
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type | n.Span):
            return [v for f in dataclasses.fields(obj)
                    if _container(v := getattr(obj, f.name))]
        return []

    def value(x: Any) -> Any:
        if isinstance(x, n.Span):
            return move(x)
        return done[id(x)] if _container(x) else x

    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        obj, expanded = stack.pop()
        if id(obj) in done:
            continue
        if not expanded:
            stack.append((obj, True))
            stack.extend((p, False) for p in parts(obj) if id(p) not in done)
            continue
        if isinstance(obj, tuple | list):
            done[id(obj)] = type(obj)(value(x) for x in obj)
        else:
            changes = {}
            for f in dataclasses.fields(obj):
                old = getattr(obj, f.name)
                new = value(old)
                if new is not old:
                    changes[f.name] = new
            done[id(obj)] = dataclasses.replace(obj, **changes) if changes else obj
    return done[id(root)] if _container(root) else value(root)


def _container(x: Any) -> bool:
    return isinstance(x, tuple | list) or (
        dataclasses.is_dataclass(x) and not isinstance(x, type | n.Span))


# ---- TC6 -> ST ---------------------------------------------------------------------------------

class _Writer:
    def __init__(self, path: str, lines: _Lines) -> None:
        self.path = path
        self.xml_line = lines
        self.out = _Text()
        self.problems: list[StDiagnostic] = []

    def problem(self, code: StCode, message: str, at: Where) -> None:
        line, column = at
        source = self.xml_line(line)
        if column == DOCTYPE_COLUMN:  # in characters: after a BOM, an umlaut, in UTF-16
            column = max(source.find("<!DOCTYPE"), 0)
        self.problems.append(StDiagnostic(code, message, n.Span(self.path, line, column + 1),
                                          source))

    def unsupported(self, what: str, at: Where) -> None:
        self.problem(StCode.UNSUPPORTED, f"not supported: {what} (ncgate's PLC reads the "
                     "Structured Text of a PLCopen export; docs/plc.md)", at)

    # -- the project ---------------------------------------------------------------------------

    def project(self, root: _El) -> None:
        if root.tag != "project" or root.ns not in TC6_NAMESPACES:
            shown = f"{{{root.ns}}}{root.tag}" if root.ns else root.tag
            raise _XmlProblem(f"not a PLCopen TC6 project: the root element is {shown}, "
                              f"not project in {TC6_NAMESPACES[0]}", root.at)
        types = root.child("types")
        data_types = types.child("dataTypes") if types else None
        for dt in data_types.all("dataType") if data_types else ():
            self.data_type(dt)
        for lists in self._global_lists(root):
            self.var_list(lists, "VAR_GLOBAL")
        pous = types.child("pous") if types else None
        for pou in pous.all("pou") if pous else ():
            self.pou(pou)

    def _global_lists(self, root: _El) -> list[_El]:
        found = []
        for data in self._add_data(root):
            if data.attrs.get("name") == GLOBAL_VARS_DATA:
                found += data.all("globalVars")
        instances = root.child("instances")
        configurations = instances.child("configurations") if instances else None
        for config in configurations.all("configuration") if configurations else ():
            found += config.all("globalVars")
            for resource in config.all("resource"):
                found += resource.all("globalVars")
        return found

    @staticmethod
    def _add_data(el: _El) -> list[_El]:
        add = el.child("addData")
        return add.all("data") if add else []

    # -- declarations ----------------------------------------------------------------------------

    def data_type(self, dt: _El) -> None:
        out = self.out
        out.newline()
        out.put("TYPE ", dt.at)
        out.put(dt.attrs.get("name", ""), dt.at)
        out.put(" :", dt.at)
        base = dt.child("baseType")
        if base is not None:
            self.type_of(base)
        self.initial(dt.child("initialValue"))
        out.put(";", dt.at)
        out.newline()
        out.put("END_TYPE", dt.end)
        out.newline()

    def var_list(self, lst: _El, keyword: str) -> None:
        out = self.out
        out.newline()
        out.put(keyword, lst.at)
        for attr, qualifier in QUALIFIERS:
            if lst.attrs.get(attr) in ("true", "1"):
                out.put(f" {qualifier}", lst.at)
        out.newline()
        for var in lst.all("variable"):
            self.variable(var)
        out.put("END_VAR", lst.end)
        out.newline()

    def variable(self, var: _El) -> None:
        out = self.out
        out.put(var.attrs.get("name", ""), var.at)
        if "address" in var.attrs:
            out.put(f" AT {var.attrs['address']}", var.at)
        out.put(" :", var.at)
        type_el = var.child("type")
        if type_el is not None:
            self.type_of(type_el)
        self.initial(var.child("initialValue"))
        out.put(";", var.at)
        out.newline()

    def type_of(self, holder: _El) -> None:
        """The type held by ``holder`` (a ``type``, ``baseType`` or ``returnType``)."""
        t = next(iter(holder.children), None)
        out = self.out
        if t is None:
            return
        out.put(" ", t.at)
        tag = t.tag
        if tag == "derived":
            out.put(t.attrs.get("name", ""), t.at)
        elif tag in ELEMENTARY_NAMES:
            out.put(ELEMENTARY_NAMES[tag], t.at)
            if "length" in t.attrs:
                out.put(f"({t.attrs['length']})", t.at)
        elif tag == "array":
            bounds = ", ".join(f"{d.attrs.get('lower', '')}..{d.attrs.get('upper', '')}"
                               for d in t.all("dimension"))
            out.put(f"ARRAY [{bounds}] OF", t.at)
            self._base(t)
        elif tag in ("subrangeSigned", "subrangeUnsigned"):
            self._base(t)
            r = t.child("range")
            lo, hi = (r.attrs.get("lower", ""), r.attrs.get("upper", "")) if r else ("", "")
            out.put(f" ({lo}..{hi})", r.at if r else t.at)
        elif tag == "enum":
            # (its baseType is not written: an enumeration's values are integers here, and
            # ST has no place for it -- docs/plc.md)
            values = t.child("values")
            items = []
            for v in values.all("value") if values else ():
                item = v.attrs.get("name", "")
                if "value" in v.attrs:
                    item += f" := {v.attrs['value']}"
                items.append(item)
            out.put(f" ({', '.join(items)})", t.at)
        elif tag == "struct":
            out.put("STRUCT", t.at)
            out.newline()
            for var in t.all("variable"):
                self.variable(var)
            out.put("END_STRUCT", t.end)
        elif tag == "pointer":
            out.put("POINTER TO", t.at)
            self._base(t)
        else:  # an elementary type: <INT/>, <TIME/>, <DT/>, ...
            out.put(tag, t.at)

    def _base(self, t: _El) -> None:
        base = t.child("baseType")
        if base is not None:
            self.type_of(base)

    def initial(self, holder: _El | None) -> None:
        if holder is None or not holder.children:
            return
        self.out.put(" := ", holder.at)
        self.value(holder.children[0])

    def value(self, v: _El) -> None:
        out = self.out
        if v.tag == "simpleValue":
            out.put(v.attrs.get("value", ""), v.at)
        elif v.tag == "arrayValue":
            out.put("[", v.at)
            for i, item in enumerate(v.all("value")):
                if i:
                    out.put(", ", item.at)
                repeat = item.attrs.get("repetitionValue")
                if repeat is not None:
                    out.put(f"{repeat}(", item.at)
                if item.children:
                    self.value(item.children[0])
                if repeat is not None:
                    out.put(")", item.at)
            out.put("]", v.at)
        elif v.tag == "structValue":
            out.put("(", v.at)
            for i, item in enumerate(v.all("value")):
                if i:
                    out.put(", ", item.at)
                out.put(f"{item.attrs.get('member', '')} := ", item.at)
                if item.children:
                    self.value(item.children[0])
            out.put(")", v.at)

    # -- POUs ------------------------------------------------------------------------------------

    def pou(self, pou: _El) -> None:
        name = pou.attrs.get("name", "")
        kind = POU_KINDS.get(pou.attrs.get("pouType", ""))
        if kind is None:
            self.problem(StCode.UNSUPPORTED, f"POU {name}: pouType "
                         f"{pou.attrs.get('pouType', '')!r} is not a program, functionBlock "
                         "or function", pou.at)
            return
        for data in self._add_data(pou):
            self._unsupported_data(data, name)
        for tag, what in (("actions", "action"), ("transitions", "transition")):
            holder = pou.child(tag)
            for item in holder.all(what) if holder else ():
                self.unsupported(f"{what.upper()} {item.attrs.get('name', '')} in POU {name}",
                                 item.at)
        out = self.out
        out.newline()
        out.put(f"{kind} {name}", pou.at)
        interface = pou.child("interface")
        if kind == "FUNCTION":
            returns = interface.child("returnType") if interface else None
            out.put(" :", returns.at if returns else pou.at)
            if returns is not None:
                self.type_of(returns)
        out.newline()
        for section in interface.children if interface else ():
            keyword = SECTIONS.get(section.tag)
            if keyword is not None:
                self.var_list(section, keyword)
            elif section.tag == "addData":
                for data in section.all("data"):
                    self._unsupported_data(data, name)
        for body in pou.all("body"):
            self.body(body, name)
        out.newline()
        out.put(f"END_{kind}", pou.end)
        out.newline()

    def body(self, body: _El, pou: str) -> None:
        for lang in body.children:
            if lang.tag == "ST":
                self.out.newline()
                for text, at in lang.chunks():
                    self.out.put(text, at, slides=True)
                self.out.newline()
            elif lang.tag in BODY_LANGUAGES:
                self.unsupported(f"{lang.tag} in POU {pou}", lang.at)

    def _unsupported_data(self, data: _El, pou: str) -> None:
        kind = data.attrs.get("name", "").rpartition("/")[2]
        if kind in UNSUPPORTED_DATA:
            tag, keyword = UNSUPPORTED_DATA[kind]
            for item in data.all(tag):
                self.unsupported(f"{keyword} {item.attrs.get('name', '')} in POU {pou}",
                                 item.at)


# ---- the entry points ----------------------------------------------------------------------------

def parse_plcopen(data: bytes, path: str) -> n.SourceFile:
    """A TC6 project's POUs, data types and global variables, as one parsed ST file whose
    spans point into the XML.  Raises :class:`LogicError` with every diagnostic found."""
    text = _decoded(data)
    xml_line = _Lines(text)
    writer = _Writer(path, xml_line)
    try:
        writer.project(_read_xml(data))
    except _XmlProblem as exc:
        writer.problems.clear()
        writer.problem(StCode.XML_PROJECT, exc.message, exc.at)
        raise LogicError(writer.problems) from None
    source = writer.out

    def move(span: n.Span) -> n.Span:
        line, column = source.move(span.line, span.column)
        return n.Span(path, line, column)

    problems = list(writer.problems)
    parsed = None
    try:
        parsed = parse_source(source.source(), path)
    except LogicError as exc:
        for d in exc.diagnostics:
            span = move(d.span)
            problems.append(StDiagnostic(d.code, d.message, span, xml_line(span.line)))
    if problems:
        raise LogicError(sorted(problems, key=lambda d: (d.span.line, d.span.column)))
    assert parsed is not None
    # Every part of the parsed file (POUs, types, globals, what the parser adds later), its
    # spans moved; the text is the XML's, for the lines diagnostics and faults show.
    moved: n.SourceFile = _moved(parsed, move)
    return dataclasses.replace(moved, path=path, text=text)


class _Lines:
    """A line of the XML file's text by its number, as expat counts lines (LF, CRLF or CR
    ends one; ``str.splitlines`` also breaks at a form feed or U+2028, which may be in an ST
    comment).  Where each line starts is found at the first diagnostic only: a list of the
    lines of a 50 MB file took 400 MB."""

    def __init__(self, text: str) -> None:
        self.text = text
        self._starts: array[int] | None = None

    def __call__(self, line: int) -> str:
        if self._starts is None:
            self._starts = array("q", [0])
            self._starts.extend(m.end() for m in _LINE_END.finditer(self.text))
        starts = self._starts
        if not 0 < line <= len(starts):
            return ""
        end = starts[line] if line < len(starts) else len(self.text)
        return self.text[starts[line - 1]:end].rstrip("\r\n")


_LINE_END = re.compile(r"\r\n?|\n")


def _decoded(data: bytes) -> str:
    """The file's text, for the lines diagnostics show (expat reads the bytes itself)."""
    head = data[:200]
    for bom, codec in ((b"\xef\xbb\xbf", "utf-8-sig"), (b"\xff\xfe", "utf-16"),
                       (b"\xfe\xff", "utf-16")):
        if head.startswith(bom):
            return data.decode(codec, errors="replace")
    encoding = "utf-8"
    if head.startswith(b"<?xml"):
        declared = head.split(b"?>", 1)[0]
        for quote in (b'"', b"'"):
            key = b"encoding=" + quote
            if key in declared:
                encoding = declared.split(key, 1)[1].split(quote, 1)[0].decode("ascii",
                                                                               "replace")
    try:
        return data.decode(encoding, errors="replace")
    except LookupError:
        return data.decode("utf-8", errors="replace")


def read_logic_file(path: str | Path) -> n.SourceFile:
    """One file of ``[plc] logic``: PLCopen TC6 XML by its ``.xml`` suffix, Structured Text
    otherwise."""
    return logic_from_text(str(path), read_logic_text(path))


def read_logic_text(path: str | Path) -> str:
    """A logic file's content as text that gives its bytes back (``logic_from_text``):
    UTF-8, with any byte that is not kept as a surrogate (a session record carries it).
    Only a regular file is read: a FIFO put in its place (``run --watch`` reloads what
    appears there) is an OSError at once, not a read that waits for a writer for ever."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):  # (as open() says it)
            raise OSError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        if not stat.S_ISREG(mode):
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read()
    except OSError as exc:  # (a read's own error names no file: this one does)
        if exc.filename is not None:
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    finally:
        os.close(fd)
    return data.decode("utf-8", "surrogateescape")


def logic_from_text(path: str, text: str) -> n.SourceFile:
    """:func:`read_logic_file` of a file whose content was ``text`` (``read_logic_text``):
    the logic a session ran, replayed from its record."""
    data = text.encode("utf-8", "surrogateescape")
    if Path(path).suffix.lower() == XML_SUFFIX:
        return parse_plcopen(data, path)
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:  # as parse_file says it
        line = data[:exc.start].count(b"\n") + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise LogicError([StDiagnostic(StCode.NOT_UTF8, f"byte 0x{data[exc.start]:02X} is "
                                       "not UTF-8 (save the file as UTF-8)",
                                       n.Span(path, line, column), "")]) from None
    return parse_source(text.removeprefix("\ufeff"), path)
