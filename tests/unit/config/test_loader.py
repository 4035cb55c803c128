"""The config loader (spec 4.2): defaults, validation naming file and dotted key, overrides."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ncgate.config import ConfigError, SndPolicy, load_config


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(text)
    return path


def test_builtin_default_matches_the_spec() -> None:
    cfg = load_config(None)
    assert cfg.source is None
    # lookahead 0: the built-in cell runs the manual's programs as they are written (a config
    # of the user's gets the key's default, 16; docs/decisions.md, decode time and motion time)
    assert (cfg.nc.processes, cfg.nc.lookahead, cfg.nc.snd, cfg.nc.main) == (
        5, 0, SndPolicy.RENDEZVOUS, "PROG91")
    assert (cfg.plc.sa_bits, cfg.plc.k_bytes, cfg.plc.syvars, cfg.plc.scan_ms) == (
        1024, 512, 256, 10)
    assert (cfg.modbus.host, cfg.modbus.port, cfg.modbus.unit_ids) == ("127.0.0.1", 5020, (1,))
    assert (cfg.canopen.interface, cfg.canopen.channel, cfg.canopen.node_id) == (
        "virtual", "ncgate", 16)
    programs = cfg.nc.storage.devices["MP0"]
    assert {p.name for p in programs.glob("*.nc")} == {"PROG91.nc", "PROG92.nc", "PROG93.nc"}


def test_empty_file_gives_defaults_with_storage_beside_it(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, ""))
    assert cfg.nc.processes == 5
    assert cfg.nc.storage.devices == {"MP0": tmp_path.resolve()}
    assert cfg.source == tmp_path / "gateway.toml"


def test_relative_storage_and_external_processes(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, """
[nc]
processes = 4
snd = "latched"
[nc.storage]
MP0 = "progs"
MP2 = "/abs/where"
default = "mp2"
[[nc.process]]
number = 3
external = true
[[nc.process]]
number = 2
"""))
    assert cfg.nc.storage.devices["MP0"] == (tmp_path / "progs").resolve()
    assert cfg.nc.storage.default == "MP2"
    assert cfg.nc.external == {3}
    assert [p.number for p in cfg.nc.process] == [2, 3]
    assert cfg.nc.snd is SndPolicy.LATCHED


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[modbus]\nport = 70000", "modbus.port: expected an integer 1..65535, got 70000"),
        ("[modbus]\nprot = 1", "modbus.prot: unknown key"),
        ("[nope]\na = 1", "nope: unknown key"),
        ("[nc]\nprocesses = 17", "nc.processes: expected an integer 1..16, got 17"),
        ("[nc]\nprocesses = true", "nc.processes: expected an integer 1..16, got True"),
        ('[nc]\nsnd = "eager"', 'nc.snd: expected "rendezvous" or "latched", got \'eager\''),
        ("[nc]\ntime_scale = 0", "nc.time_scale: expected a number > 0, got 0"),
        ('[nc]\nsync_reads = "yes"', "nc.sync_reads: expected true or false, got 'yes'"),
        ('[nc.storage]\nMP0 = "a"\ndefault = "MP1"', "nc.storage.default: names 'MP1'"),
        ('[nc.storage]\nMP4 = "a"', "nc.storage.MP4: unknown key"),
        ("[[nc.process]]\nnumber = 9", "nc.process[0].number: expected an integer 1..5, got 9"),
        ("[[nc.process]]\nexternal = true", "nc.process[0].number: missing"),
        ("[[nc.process]]\nnumber = 2\n[[nc.process]]\nnumber = 2",
         "nc.process[1].number: process 2 is configured twice"),
        ("[[nc.process]]\nnumber = 1\nexternal = true", "nc.process[0].external: process 1"),
        ("[plc]\nsa_bits = 1001", "plc.sa_bits: expected a multiple of 8, got 1001"),
        ("[modbus]\nunit_ids = []", "modbus.unit_ids: expected a non-empty list"),
        ("[canopen]\nnode_id = 128", "canopen.node_id: expected an integer 1..127, got 128"),
        ("nc = 3", "nc: expected a table, got 3"),
        ("[modbus.map]\nread_only = [\"coils\"]", "modbus.map.read_only: expected a list of"),
        ("[modbus]\nallow = [\"not an ip\"]", "modbus.allow[0]: expected an IP address"),
        ("[nc.limits]\nX = 5", "nc.limits.X: expected [min, max] with min < max"),
        ("[nc.limits]\nC = [10, -10]", "nc.limits.C: expected [min, max] with min < max"),
        ("[nc.limits]\nY = [0, true]", "nc.limits.Y: expected [min, max]"),
        ("[nc.limits]\nQ = [0, 1]", "nc.limits.Q: unknown key"),
        ("[nc.limits]\nblock_s = 0", "nc.limits.block_s: expected a number > 0, got 0"),
        ("[nc]\ntool_change_s = 100\n[nc.limits]\nblock_s = 60",
         "nc.tool_change_s: 100 s is longer than a block may take (nc.limits.block_s = 60)"),
    ],
)
def test_bad_values_name_file_and_dotted_key(tmp_path: Path, text: str, message: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    assert str(caught.value).startswith(f"{path}: ")
    assert message in str(caught.value)


def test_toml_syntax_error_names_the_file(tmp_path: Path) -> None:
    path = write(tmp_path, "[nc\nprocesses = 3")
    with pytest.raises(ConfigError, match=rf"^{path}: .*line 1"):
        load_config(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "absent.toml")


def test_overrides_by_dotted_key_are_validated_too() -> None:
    cfg = load_config(None, overrides={"modbus.port": 0, "nc.processes": 3})
    assert cfg.modbus.port == 0 and cfg.nc.processes == 3
    with pytest.raises(ConfigError, match=r"<built-in default>: nc.lookahead"):
        load_config(None, overrides={"nc.lookahead": -1})
    # Told where an override came from, its error names that, not the file (issue 25.14).
    with pytest.raises(ConfigError, match=r"^--port: modbus.port: expected an integer"):
        load_config(None, overrides={"modbus.port": -1}, origins={"modbus.port": "--port"})



@pytest.mark.parametrize("dotted", ["plant.model.clamp.travel_ms", "plant.model[1].travel_ms",
                                    "plant.model.clamp.travle_ms"])
def test_an_override_of_an_entry_of_an_array_of_tables_names_the_option(
        tmp_path: Path, dotted: str) -> None:
    """An entry named by its name (or index) is read as plant.model[i]: its error names the
    option that set it, not the file (a new user's --set and a sweep's [grid] were blamed
    on the config file)."""
    (tmp_path / "ncgate.toml").write_text(
        '[[plant.model]]\nname = "door"\nkind = "delay"\ninput = "SA1"\noutput = "SA2"\n'
        '[[plant.model]]\nname = "clamp"\nkind = "cylinder"\nextend = "SA3"\n'
        'travel_ms = 300\n')
    with pytest.raises(ConfigError) as caught:
        load_config(tmp_path / "ncgate.toml", overrides={dotted: -5},
                    origins={dotted: "--set"})
    key = dotted.replace(".clamp.", "[1].")
    assert str(caught.value).startswith(f"--set: {key}: "), str(caught.value)



@pytest.mark.parametrize("logic", ['"loop.st"', '["loop.st"]'])
def test_a_symbolic_link_that_loops_is_a_config_error_naming_the_key(
        tmp_path: Path, logic: str) -> None:
    """(A hostile try: Path.resolve's RuntimeError came out as a bug of ncgate, exit 70.)"""
    (tmp_path / "loop.st").symlink_to("loop.st")
    (tmp_path / "ncgate.toml").write_text(f"[plc]\nlogic = {logic}\n")
    key = "plc.logic" if logic.startswith('"') else "plc.logic[0]"
    with pytest.raises(ConfigError, match=rf"ncgate.toml: {re.escape(key)}: cannot follow "
                                          "'loop.st'"):
        load_config(tmp_path / "ncgate.toml")


def test_docs_config_md_is_generated_from_the_schema() -> None:
    from pathlib import Path

    from ncgate.config.schema import config_markdown

    root = Path(__file__).resolve().parents[3]
    assert (root / "docs" / "config.md").read_text() == config_markdown(), (
        "docs/config.md is stale: regenerate it from ncgate.config.schema.config_markdown()")


def test_every_key_of_the_schema_is_read_and_unknown_ones_are_refused(tmp_path: Path) -> None:
    from ncgate.config.schema import Config, keys

    for dotted, _, _ in keys(Config):
        if "[]" in dotted or "MP0 .." in dotted:
            continue
        section, _, name = dotted.rpartition(".")
        if not section:  # [symbols]: a table of the user's own names, each one a key
            continue
        # A table of the user's names ([nc.ve.NAME]): an entry needs its map.
        needed = 'map = "SYVAR1"\n' if section.endswith(".NAME") else ""
        path = write(tmp_path, f"[{section}]\n{needed}{name}_typo = 1\n")
        with pytest.raises(ConfigError, match=rf"{section}\.{name}_typo: unknown key"):
            load_config(path)


def test_nc_limits_reach_the_engine_by_axis(tmp_path: Path) -> None:
    from ncgate.gateway.wiring import runtime_settings

    path = write(tmp_path, "[nc.limits]\nX = [-5, 5.5]\nC = [-inf, inf]\nblock_s = 60")
    settings = runtime_settings(load_config(path), closed=True)
    assert settings.travel_limits[0] == (-5.0, 5.5)
    assert settings.travel_limits[1] == (-100_000.0, 100_000.0)  # Y: the default, +-100 m
    assert settings.travel_limits[8] == (-float("inf"), float("inf"))  # C: no limit
    assert settings.block_limit_s == 60.0
    assert runtime_settings(load_config(None), closed=True).block_limit_s == 86_400.0


def test_an_override_names_an_entry_of_an_array_of_tables(tmp_path: Path) -> None:
    """`--set plant.model.clamp.travel_ms=900` (by name), `plant.model[1]...` (by index),
    `nc.process.2.external` (by number): what a sweep varies of one model or process."""
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 2\n[[nc.process]]\nnumber = 2\nexternal = false\n'
        '[[plant.model]]\nname = "clamp"\nkind = "delay"\ninput = "SA1"\noutput = "SA2"\n'
        'on_ms = 100\n'
        '[[plant.model]]\nname = "door"\nkind = "delay"\ninput = "SA3"\noutput = "SA4"\n'
        'on_ms = 100\n')
    config = load_config(tmp_path / "ncgate.toml", overrides={
        "plant.model.clamp.on_ms": 900, "plant.model[1].on_ms": 50,
        "nc.process.2.external": True})
    delays = {m.name: m.get("on_ms") for m in config.plant.model}
    assert delays == {"clamp": 900, "door": 50}
    assert [(p.number, p.external) for p in config.nc.process] == [(2, True)]
    for dotted, said in (("plant.model.vise.on_ms", "no entry 'vise' (entries: clamp, door)"),
                         ("plant.model[5].on_ms", "plant.model[5]: there are 2 entries"),
                         ("plant.model.on_ms", "plant.model is an array of tables: name one")):
        with pytest.raises(ConfigError) as caught:
            load_config(tmp_path / "ncgate.toml", overrides={dotted: 1})
        assert said in str(caught.value), caught.value
