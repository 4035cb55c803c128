"""The machine under ``Objects/Machines`` is named for the cell (docs/opcua.md): the config
file's name, or its folder's for an ``ncgate.toml``, so that cells made alike do not all
show a machine ``ncgate``; the application URI keeps the file's name (its certificate's)."""

from __future__ import annotations

from pathlib import Path

from asyncua import Client, ua

from ncgate.gateway import Gateway
from ncgate.gateway.opcua.model import machine_name
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

MACHINERY = "http://opcfoundation.org/UA/Machinery/"


def test_an_ncgate_toml_names_its_machine_after_its_folder(tmp_path: Path) -> None:
    assert machine_name(tmp_path / "press-7" / "ncgate.toml") == "press-7"
    assert machine_name(tmp_path / "press-7" / "lathe.toml") == "lathe"
    assert machine_name(None) == "ncgate"  # the built-in config


async def test_the_server_shows_the_machine_of_an_ncgate_toml_by_its_folders_name(
        tmp_path: Path) -> None:
    config = tmp_path / "press-7" / "ncgate.toml"
    config.parent.mkdir()
    config.write_text("[opcua]\nenabled = true\n[canopen]\nenabled = false\n")
    async with Gateway(ncgate_test_config(config)) as gw, \
            Client(gw.opcua_endpoint) as client:
        machinery = await client.get_namespace_index(MACHINERY)
        machines = await client.nodes.objects.get_child(f"{machinery}:Machines")
        names = [(await m.read_browse_name()).Name for m in await machines.get_children()]
        assert names == ["press-7"]
        machine = (await machines.get_children())[0]
        assert machine.nodeid.Identifier == "Machines/press-7"
        di = await client.get_namespace_index("http://opcfoundation.org/UA/DI/")
        ident = await machine.get_child(f"{di}:Identification")
        model = await (await ident.get_child(f"{di}:Model")).read_value()
        assert model.Text == "press-7"
        uri = await (await ident.get_child(f"{di}:ProductInstanceUri")).read_value()
        assert uri == "urn:ncgate:press-7"  # one per machine (OPC 40001-1)
        server_uri = await client.get_node(
            ua.NodeId(ua.ObjectIds.Server_NamespaceArray)).read_value()
        assert "urn:ncgate:ncgate" in server_uri  # the application URI: the file's name
