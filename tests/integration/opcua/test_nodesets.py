"""The companion specifications' NodeIds and BrowseNames ncgate uses are the published ones:
node-opcua browses the running server, and each node in (or typed by, or named in) the DI,
Machinery, IA, MachineTool and CNC namespaces is checked against the official nodeset XML that
the npm package node-opcua-nodesets ships (read from tests/integration/opcua_client's
node_modules; the files are the OPC Foundation's and are not copied here).

The rules (docs/opcua.md, "What is not the full companion model"):

- a type (ObjectType, VariableType, DataType) with a standard BrowseName has the published
  NodeId, the published supertype, and an enumeration the published values;
- a child of a standard type (an instance declaration, or an enumeration's EnumValues) has
  the published NodeId;
- a child of an instance of a standard type, with a standard BrowseName, is one the type (or
  a supertype) declares, and a variable has the declared DataType;
- any other node with a standard BrowseName has a name the nodeset defines.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from .conftest import CLIENT, IMAGE, UaClient

NODESETS = CLIENT / "node_modules" / "node-opcua-nodesets" / "nodesets"
UA = "http://opcfoundation.org/UA/"
FILES = {  # the companion specifications ncgate's address space names
    "http://opcfoundation.org/UA/DI/": "Opc.Ua.Di.NodeSet2.xml",
    "http://opcfoundation.org/UA/IA/": "Opc.Ua.IA.NodeSet2.xml",
    "http://opcfoundation.org/UA/Machinery/": "Opc.Ua.Machinery.NodeSet2.xml",
    "http://opcfoundation.org/UA/MachineTool/": "Opc.Ua.MachineTool.NodeSet2.xml",
    "http://opcfoundation.org/UA/CNC": "Opc.Ua.CNC.NodeSet.xml",
}
# Names ncgate keeps though no node of the published nodeset carries them, each with why.
NAMED_BY_THE_TEXT = {
    # OPC 40502's entry point under Objects; the nodeset's example instance of
    # CncInterfaceType is called "test".
    ("http://opcfoundation.org/UA/CNC", "CncInterface"),
}
_NS = {"u": "http://opcfoundation.org/UA/2011/03/UANodeSet.xsd"}
_TYPE_CLASSES = {"ObjectType", "VariableType", "DataType"}
# The references from a type to its instance declarations (HasAddIn: DI's Identification).
_CHILD_REFS = {"HasComponent", "HasProperty", "HasAddIn", "HasOrderedComponent", "i=47",
               "i=46", "i=17604", "i=49"}

Id = tuple[str, str]  # (namespace URI, identifier as "i=13" or "s=..."), or ("", alias)


@dataclass
class Published:
    """One node of a published nodeset."""

    node: Id
    cls: str
    name: tuple[str, str]  # (namespace URI, name)
    datatype: Id | None = None
    supertype: Id | None = None
    children: list[Id] = field(default_factory=list)
    enum: list[str] | None = None  # an enumeration's names by value 0, 1, ...


def _parse(path: Path, model: dict[Id, Published]) -> None:
    root = ET.parse(path).getroot()
    uris = [UA] + [u.text or "" for u in root.findall("u:NamespaceUris/u:Uri", _NS)]
    aliases = {a.get("Alias"): a.text or "" for a in root.findall("u:Aliases/u:Alias", _NS)}

    def ident(text: str) -> Id:
        text = aliases.get(text, text)
        found = re.fullmatch(r"(?:ns=(\d+);)?([isgb]=.*)", text)
        assert found, text
        return (uris[int(found.group(1) or 0)], found.group(2))

    def qualified(text: str) -> tuple[str, str]:
        found = re.fullmatch(r"(\d+):(.*)", text)
        return (uris[int(found.group(1))], found.group(2)) if found else (UA, text)

    for element in root:
        cls = element.tag.rsplit("}", 1)[1]
        if not cls.startswith("UA"):
            continue
        node = Published(ident(element.get("NodeId", "")), cls[2:],
                         qualified(element.get("BrowseName", "")))
        if element.get("DataType"):
            node.datatype = ident(element.get("DataType", ""))
        for ref in element.findall("u:References/u:Reference", _NS):
            kind, forward = ref.get("ReferenceType"), ref.get("IsForward") != "false"
            target = ident(ref.text or "")
            if kind == "HasSubtype" and not forward:
                node.supertype = target
            elif kind in _CHILD_REFS and forward:
                node.children.append(target)
        fields = element.findall("u:Definition/u:Field", _NS)
        if cls == "UADataType" and fields and all(f.get("Value") is not None for f in fields):
            by_value = {int(f.get("Value", "")): f.get("Name", "") for f in fields}
            node.enum = [by_value.get(i, "?") for i in range(max(by_value) + 1)]
        model[node.node] = node
    # Children declared by an inverse reference only.
    for element in root:
        for ref in element.findall("u:References/u:Reference", _NS):
            if ref.get("ReferenceType") in _CHILD_REFS and ref.get("IsForward") == "false":
                parent = model.get(ident(ref.text or ""))
                child = ident(element.get("NodeId", ""))
                if parent is not None and child not in parent.children:
                    parent.children.append(child)


@cache
def published() -> dict[Id, Published]:
    model: dict[Id, Published] = {}
    for name in FILES.values():
        _parse(NODESETS / name, model)
    return model


def _missing() -> str | None:
    if not NODESETS.is_dir():
        return f"node-opcua-nodesets is not installed (cd {CLIENT} && npm ci)"
    return None


def _declared(type_id: Id, name: tuple[str, str]) -> Published | None:
    """The instance declaration ``name`` of a type or of one of its supertypes."""
    model = published()
    seen = type_id
    while seen in model:
        for child in model[seen].children:
            if child in model and model[child].name == name:
                return model[child]
        parent = model[seen].supertype
        if parent is None:
            return None
        seen = parent
    return None


@pytest.fixture
def nodesets() -> dict[Id, Published]:
    missing = _missing()
    if missing is not None:
        if os.environ.get("CI"):
            pytest.fail(f"{missing}: CI must install it (.ci/run)")
        pytest.skip(f"{missing}; CI runs this")
    return published()


def problems(walked: list[dict[str, Any]], namespaces: list[str]) -> list[str]:
    """Each node of the walk that breaks one of the module's rules."""
    model = published()

    def ident(text: str) -> Id:
        found = re.fullmatch(r"(?:ns=(\d+);)?([isgb]=.*)", text)
        assert found, text
        return (namespaces[int(found.group(1) or 0)], found.group(2))

    def named(record: dict[str, Any]) -> tuple[str, str]:
        uri, _, name = record["name"].partition("|")
        return (uri, name)

    by_node = {ident(r["node"]): r for r in walked}
    out: list[str] = []
    for r in walked:
        node, parent, name = ident(r["node"]), ident(r["parent"]), named(r)
        standard = name[0] in FILES
        where = f"{name[0]}|{name[1]} ({r['node']})"
        if r["cls"] in _TYPE_CLASSES and standard:
            mine = model.get(node)
            if mine is None or mine.name != name or mine.cls != r["cls"]:
                ids = [p.node for p in model.values() if p.name == name and p.cls == r["cls"]]
                out.append(f"{where}: the published {r['cls']} is {ids}")
                continue
            if ident(r["ref"]) == (UA, "i=45") and mine.supertype != parent:  # HasSubtype
                out.append(f"{where}: published supertype {mine.supertype}, here {parent}")
            if mine.enum is not None and r.get("enum") != mine.enum:
                out.append(f"{where}: published values {mine.enum}, here {r.get('enum')}")
            continue
        parent_record = by_node.get(parent)
        parent_cls = parent_record["cls"] if parent_record else "Object"
        # (A base name, too: an enumeration's EnumValues.)
        if parent_cls in _TYPE_CLASSES and parent[0] in FILES and (standard or name[0] == UA):
            declared = _declared(parent, name)
            if declared is None or declared.node != node:
                out.append(f"{where}: declared by the type as "
                           f"{declared.node if declared else 'nothing'}")
            continue
        if r["cls"] not in ("Object", "Variable") or not standard:
            continue
        type_of_parent = ident(parent_record["type"]) if parent_record else None
        if type_of_parent is not None and type_of_parent[0] in FILES:
            declared = _declared(type_of_parent, name)
            if declared is None:
                out.append(f"{where}: {type_of_parent} declares no such child")
            elif r["cls"] == "Variable" and declared.datatype != ident(r["datatype"]):
                out.append(f"{where}: published DataType {declared.datatype}, "
                           f"here {ident(r['datatype'])}")
            continue
        if name not in NAMED_BY_THE_TEXT and not any(p.name == name for p in model.values()):
            out.append(f"{where}: no node of the published nodeset has this name")
    return out


async def test_every_standard_node_id_and_browse_name_is_the_published_one(
        nodesets: dict[Id, Published], ua_client: UaClient) -> None:
    config = ncgate_test_config(**{"opcua.enabled": True, "opcua.port": 0,
                                   "canopen.enabled": False, "nc.processes": 2})
    async with Gateway(config) as gw:
        namespaces = await ua_client.call("connect", url=gw.opcua_endpoint)
        walked = await ua_client.call("walk", skip=[IMAGE], **{"from": [
            "i=85",    # Objects: the machine, the CNC interface
            "i=58",    # BaseObjectType: the object types
            "i=2041",  # BaseEventType: the event types
            "i=2915",  # AlarmConditionType: AlertType (OPC 40501-1)
            "i=29",    # Enumeration: the enumerations' DataTypes
        ]})
    checked = [r for r in walked if r["name"].split("|")[0] in FILES
               or r["ns"] in FILES]
    assert len(checked) > 20, walked  # the walk reached the companion nodes
    found = problems(walked, namespaces)
    assert not found, "\n".join(found)


def test_the_checker_sees_an_invented_id_a_wrong_supertype_and_a_wrong_data_type(
        nodesets: dict[Id, Published]) -> None:
    # The first version's ChannelMonitoringType (an id of ncgate's), AlertType under
    # BaseEventType, and ActProgramLine as an Int32 under a CncChannelType.
    mt, cnc, own = ("http://opcfoundation.org/UA/MachineTool/", "http://opcfoundation.org/UA/CNC",
                    "urn:ncgate:ua")
    namespaces = [UA, mt, cnc, own]
    walked = [
        {"parent": "i=58", "node": "ns=3;s=ChannelMonitoringType", "ref": "i=45",
         "name": f"{mt}|ChannelMonitoringType", "cls": "ObjectType", "type": "i=0", "ns": own},
        {"parent": "i=2041", "node": "ns=1;i=39", "ref": "i=45", "name": f"{mt}|AlertType",
         "cls": "ObjectType", "type": "i=0", "ns": mt},
        {"parent": "i=85", "node": "ns=3;s=P1", "ref": "i=35", "name": f"{own}|Process 1",
         "cls": "Object", "type": "ns=2;i=1002", "ns": own},
        {"parent": "ns=3;s=P1", "node": "ns=3;s=P1/ActProgramLine", "ref": "i=47",
         "name": f"{cnc}|ActProgramLine", "cls": "Variable", "type": "i=63", "ns": own,
         "datatype": "i=6"},
    ]
    found = problems(walked, namespaces)
    assert [line.split(" (")[0] for line in found] == [
        f"{mt}|ChannelMonitoringType", f"{mt}|AlertType", f"{cnc}|ActProgramLine"], found
