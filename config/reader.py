"""The config reader: a TOML file (or the built-in default) and the command line's dotted
overrides, walked table by table against the schema (:mod:`ncgate.config.schema`), each value
validated as it is read; then the checks across keys (:mod:`ncgate.config.checks`).

An unknown key or a bad value raises :class:`~ncgate.config.schema.ConfigError` naming the
file (or the option that set it, ``--set``) and the dotted key.  Relative paths are resolved
against the config file's folder, or the current folder for a value given on the command
line."""

from __future__ import annotations

import dataclasses
import difflib
import enum
import re
import stat
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from ncgate.config.checks import _check_config
from ncgate.config.schema import (
    _TOML_AT,
    BUILT_IN,
    Config,
    ConfigError,
    StorageConfig,
    _fields,
    _section_type,
    default_config_path,
)


def load_config(
    path: str | Path | None = None, overrides: Mapping[str, Any] | None = None,
    origins: Mapping[str, str] | None = None, *, serving: bool = True,
) -> Config:
    """Load a config file (None: the built-in default), then apply dotted-key overrides.

    ``origins`` maps an overridden dotted key to where it came from (``"--set"``,
    ``"--port"``): an error in that key names it instead of the file.
    ``serving=False``: the caller opens no server (``check``, ``sim``), so what only a
    server needs is not checked (the console's bind beyond loopback without a token)."""
    source = Path(path) if path is not None else default_config_path()
    raw = read_toml(source)
    file = str(source) if path is not None else BUILT_IN
    given = dict(origins or {})
    for dotted, value in (overrides or {}).items():
        where = _set_dotted(raw, dotted, value, given.get(dotted, file))
        if dotted in given:  # an error in it names the option, under the key the reader
            given.setdefault(where, given[dotted])  # knows it by (plant.model[0]...)
    reader = _Reader(file, source.parent, given)
    config: Config = reader.section(Config, raw, "")
    _check_config(reader, config, serving, source.stem if path is not None else "ncgate")
    return dataclasses.replace(config, source=source if path is not None else None)


def read_toml(source: Path) -> dict[str, Any]:
    """A TOML file as a table; a missing or malformed file is a ConfigError naming it."""
    try:
        return tomllib.loads(source.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{source}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{source}: is a folder, not a config file (give its TOML file, "
                          f"e.g. {source / 'ncgate.toml'})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{source}: not UTF-8 text ({exc.reason} at byte "
                          f"{exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        twice = _given_twice(source, str(exc))
        raise ConfigError(twice or f"{source}: {exc}") from exc


_TOML_HEADER: Final = re.compile(r"^\s*\[(\[?)\s*([^\]]+?)\s*\]")


def _given_twice(source: Path, message: str) -> str | None:
    """tomllib's words for a key or table given twice ("Cannot overwrite a value (at line 3,
    column 11)") with the dotted key they leave out: "ncgate.toml:3: nc.main is given twice"."""
    found = _TOML_AT.match(message)
    if found is None or not found["what"].startswith("Cannot "):
        return None
    what, line = found["what"], int(found["line"])
    named = re.search(r"\((.*)\)", what)
    if named is not None:  # Cannot declare ('nc',) twice; Cannot redefine namespace (...)
        dotted = ".".join(re.findall(r"'([^']*)'", named[1]))
        return (f"{source}:{line}: {dotted} is given twice: a TOML table or key is given once "
                "(put its keys together)")
    try:
        lines = source.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    if not 1 <= line <= len(lines):
        return None
    table = ""
    for text in lines[:line - 1]:
        header = _TOML_HEADER.match(text)
        if header is not None:
            table = header[2].replace('"', "").replace(" ", "")
    key = lines[line - 1].split("=", 1)[0].strip().replace('"', "").replace(" ", "")
    dotted = f"{table}.{key}" if table else key
    return f"{source}:{line}: {dotted} is given twice: a TOML key is given once"


def _table_of(dotted: str) -> str:
    """The top table a dotted key is in: ``opcua`` of ``opcua.host``, ``plant`` of
    ``plant.model[0].name``."""
    return re.split(r"[.\[]", dotted, maxsplit=1)[0]


def _set_dotted(raw: dict[str, Any], dotted: str, value: Any, origin: str) -> str:
    """Set ``dotted`` in the raw tables.  In an array of tables (``[[plant.model]]``,
    ``[[nc.process]]``) an entry is named by its ``name`` or ``number`` key, or by its index
    in brackets: ``plant.model.clamp.travel_ms``, ``nc.process.2.external``,
    ``plant.model[0].travel_ms`` -- what a sweep varies of one model or process.  Returns the
    key as the reader names it (each entry by its index: ``plant.model[0].travel_ms``)."""
    parts = [p for part in dotted.split(".") for p in _indexed(part)]
    *parents, last = parts
    table: Any = raw
    canonical: list[str] = []
    for i, name in enumerate(parents):
        above = ".".join(parents[:i + 1]).replace(".[", "[")
        if isinstance(table, list):  # an array of tables: the entry that name or index names
            entries = table
            table = _entry_of(entries, name, dotted, above, origin)
            canonical.append(f"[{next(j for j, e in enumerate(entries) if e is table)}]")
            continue
        canonical.append(name)
        table = table.setdefault(name, {})
        if not isinstance(table, dict | list):
            raise ConfigError(f"{origin}: {dotted}: {above} is a value, not a table")
    if isinstance(table, list):
        raise ConfigError(f"{origin}: {dotted}: {'.'.join(parents).replace('.[', '[')} is an "
                          "array of tables: "
                          "name one of its entries (by its name, number or [index])")
    table[last] = value
    return ".".join([*canonical, last]).replace(".[", "[")


def _indexed(part: str) -> list[str]:
    """``model[0]`` as ``model``, ``[0]``."""
    found = re.fullmatch(r"(.+?)\[(\d+)\]", part)
    return [found.group(1), f"[{found.group(2)}]"] if found else [part]


def _entry_of(entries: list[Any], name: str, dotted: str, above: str,
              origin: str) -> dict[str, Any]:
    index = re.fullmatch(r"\[(\d+)\]", name)
    if index is not None:
        i = int(index.group(1))
        if i < len(entries) and isinstance(entries[i], dict):
            return entries[i]  # type: ignore[no-any-return]
        raise ConfigError(f"{origin}: {dotted}: {above}: there are {len(entries)} entries")
    for entry in entries:
        if isinstance(entry, dict) and name in (str(entry.get("name")),
                                                str(entry.get("number"))):
            return entry
    known = [str(e.get("name", e.get("number"))) for e in entries if isinstance(e, dict)]
    raise ConfigError(f"{origin}: {dotted}: no entry {name!r} (entries: "
                      f"{', '.join(known) or 'none'})")


class _Reader:
    """Reads one table at a time, naming the dotted key of anything wrong."""

    def __init__(self, file: str, base: Path, given: Mapping[str, str] | None = None) -> None:
        self.file = file
        self.base = base
        self.given = given or {}  # overridden dotted key -> where it was given (--set)

    def fail(self, key: str, message: str) -> ConfigError:
        return ConfigError(f"{self._origin(key)}: {key}: {message}")

    def base_of(self, key: str) -> Path:
        """What a relative path of ``key`` is relative to: the config file's folder, or, for
        a value given on the command line (``--set nc.storage.MP0=.``), the current folder,
        as a shell user means it."""
        return Path.cwd() if key in self.given else self.base

    def path(self, key: str, text: str, where: str | None = None) -> Path:
        """``text``, a file or folder name of ``key``, as an absolute path (relative to
        :meth:`base_of`); one that cannot be resolved (a symbolic link that loops) is a
        ConfigError naming ``where`` (an entry of the key's list) or the key."""
        try:
            return (self.base_of(key) / text).resolve()
        except (RuntimeError, OSError) as exc:  # (3.11: a loop is a RuntimeError)
            raise self.fail(where or key, f"cannot follow {text!r}: {exc}") from None

    def path_name(self, value: Any, key: str, what: str = "a file name") -> str:
        """``value``, given for ``key`` as the name of a file or folder: a string, and not
        empty -- "" would be the config's own folder, which no file key means, and which a
        folder key names as "." (docs/decisions.md)."""
        if value == "":
            raise self.fail(key, f"empty: give {what}")
        return self.str_(value, key)

    def existing_file(self, key: str, text: str, where: str | None = None) -> Path:
        """``text``, the name of a file that ``key`` reads, as an absolute path (:meth:`path`)
        to a regular file; what it is instead is a ConfigError naming ``where`` or the key."""
        if not text:  # (would be the config's own folder)
            raise self.fail(where or key, "empty: give a file name")
        return self.regular(where or key, self.path(key, text, where))

    def regular(self, key: str, path: Path) -> Path:
        """``path`` when it is a regular file; else a ConfigError that says what it is: no
        such file, a folder, or not a regular file (``/dev/null``, a pipe)."""
        try:
            mode = path.stat().st_mode
        except (FileNotFoundError, NotADirectoryError):  # (NotADirectory: under a file)
            raise self.fail(key, f"no such file: {path}") from None
        except OSError as exc:
            raise self.fail(key, f"cannot read {path}: {exc.strerror}") from None
        if stat.S_ISDIR(mode):
            raise self.fail(key, f"is a folder, not a file: {path}")
        if not stat.S_ISREG(mode):
            raise self.fail(key, f"is not a regular file: {path}")
        return path

    def folder(self, key: str, value: Any) -> Path:
        """``value``, the name of a folder of ``key``, as an absolute path (:meth:`path`);
        what is there instead of a folder is a ConfigError that says what it is: a file, or
        another kind (``/dev/null``).  A folder that does not exist is the caller's to judge
        (``run --allow-missing`` starts without a storage folder: its programs arrive later);
        a file there is a mistake, whenever the folder comes."""
        path = self.path(key, self.path_name(value, key, "a folder"))
        try:
            mode = path.stat().st_mode
        except OSError:  # nothing there (or nothing to see): the caller's
            return path
        if stat.S_ISREG(mode):
            raise self.fail(key, f"is a file, not a folder: {path}")
        if not stat.S_ISDIR(mode):
            raise self.fail(key, f"is not a folder: {path}")
        return path

    def file_or_folder(self, key: str, path: Path) -> Path:
        """``path`` when it is a regular file or a folder; else a ConfigError that says what
        it is: nothing, or another kind (``/dev/null``, a pipe)."""
        try:
            mode = path.stat().st_mode
        except (FileNotFoundError, NotADirectoryError):
            raise self.fail(key, f"no such file or folder: {path}") from None
        except OSError as exc:
            raise self.fail(key, f"cannot read {path}: {exc.strerror}") from None
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            raise self.fail(key, f"is neither a regular file nor a folder: {path}")
        return path

    def _origin(self, key: str) -> str:
        """The override that set ``key`` (or a table above it, or a key below it), else the
        file."""
        for dotted, origin in self.given.items():
            if key == dotted or key.startswith((f"{dotted}.", f"{dotted}[")) or \
                    dotted.startswith(f"{key}."):
                return origin
        if self.given and self.file == BUILT_IN:
            # The built-in default is sound on its own: what went wrong came with the
            # overrides (--web 0.0.0.0:8080 without a token fails on web.token) -- those of
            # the key's own section when there are any (opcua.security refused for the
            # opcua.host of --set and the --opcua given: not also --port and --no-web).
            section = _table_of(key)
            near = {origin for dotted, origin in self.given.items()
                    if _table_of(dotted) == section}
            return " ".join(sorted(near or set(self.given.values())))
        return self.file

    def section(self, cls: type, raw: Any, key: str,
                hi: Mapping[str, int] | None = None) -> Any:
        """A dataclass of the schema, read from its table (``hi``: bounds known only now)."""
        known = {f.name for f in _fields(cls)} if cls is not StorageConfig else set(
            StorageConfig.KEYS)
        t = self._table(raw, key, known)
        values: dict[str, Any] = {}
        for f in _fields(cls):
            dotted = f"{key}.{f.name}" if key else f.name
            nested = _section_type(f)
            meta = f.metadata
            if meta.get("parse") is not None:
                values[f.name] = meta["parse"](self, t, dotted, values)
            elif nested is not None:
                values[f.name] = self.section(nested, t.get(f.name), dotted)
            else:
                values[f.name] = self._value(f, t.get(f.name, f.default), dotted,
                                             (hi or {}).get(f.name, meta.get("hi")))
        return cls(**values)

    def _table(self, raw: Any, key: str, known: set[str]) -> dict[str, Any]:
        if raw is None:
            return {}
        if not isinstance(raw, dict):
            raise self.fail(key, f"expected a table, got {raw!r}")
        for name in raw:
            if name not in known:
                near = difflib.get_close_matches(name, sorted(known), n=1)
                hint = f" (did you mean {near[0]}?)" if near else ""
                raise self.fail(f"{key}.{name}" if key else name, f"unknown key{hint}")
        return raw

    def _value(self, f: dataclasses.Field[Any], value: Any, key: str, hi: Any) -> Any:
        default, meta = f.default, f.metadata
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise self.fail(key, f"expected true or false, got {value!r}")
            return value
        if isinstance(default, int):
            return self.int_(value, key, meta["lo"], hi)
        if isinstance(default, float):
            return self.float_(value, key, meta["lo"], meta["positive"])
        if isinstance(default, str):
            return self.str_(value, key)
        if isinstance(default, enum.Enum):
            choices = type(default)
            try:
                return choices(value.value if isinstance(value, choices) else value)
            except ValueError:
                names = " or ".join(f'"{c.value}"' for c in choices)
                raise self.fail(key, f"expected {names}, got {value!r}") from None
        raise AssertionError(f"{key}: no reader for {f.type}")  # a schema without a parser

    def int_(self, value: Any, key: str, lo: Any, hi: Any = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < lo or (
            hi is not None and value > hi
        ):
            bounds = f"{lo}..{hi}" if hi is not None else f">= {lo}"
            raise self.fail(key, f"expected an integer {bounds}, got {value!r}")
        return value

    def float_(self, value: Any, key: str, lo: float, positive: bool) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or value < lo or (
            positive and value <= 0
        ):
            what = "a number > 0" if positive else f"a number >= {lo:g}"
            raise self.fail(key, f"expected {what}, got {value!r}")
        return float(value)

    def str_(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a non-empty string, got {value!r}")
        return value
