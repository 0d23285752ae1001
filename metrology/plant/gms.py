"""The address space ``metro measure --opcua`` serves: the OPC 40210 (GMS) types metro uses, built
with GMS's own NodeIds and BrowseNames, and metro's instances and events.

Loaded from the standard NodeSets shipped in ``metrology/data/opcua`` (see its SOURCE.md): DI,
Machinery (its ``Machines`` folder) and Machinery Result (OPC 40001-101: ``ResultReadyEventType``,
``ResultEvaluationEnum``). The GMS NodeSet itself is not shipped (no licence notice; its
MachineTool/Jobs dependencies do not import in asyncua): the GMS namespace is registered as a
subset (``IsNamespaceSubset`` true) holding what metro uses, node for node as in GMS 1.0.0:

- ``CharacteristicType`` (i=1009): ``CharacteristicIdentifier`` (6028), ``IsValid`` (6111),
  ``LowerToleranceLimit`` (6042), ``Nominal`` (6044), ``ResultEvaluation`` (6038, Machinery
  Result's ``ResultEvaluationEnum``), ``ResultValue`` (6039), ``UpperToleranceLimit`` (6040);
- ``CorrectionType`` (i=1005): ``CharacteristicIdentifier`` (6009), ``Identifier`` (6002),
  ``CorrectionValueAbsolute`` (6074).

metro's own namespace (``urn:metro:plant``) holds one object per cell under ``Machines`` (its head,
the measuring system), with ``LastResult`` (a GMS characteristic), ``LastCorrection`` (a GMS
correction), ``Calibration`` (SHA-256, file, certificate fields) and two event types:
``HoleResultReadyEventType`` (a concrete subtype of Machinery Result's abstract
``ResultReadyEventType``, carrying the characteristic's fields) and ``DriftAlarmEventType``.
"""

from __future__ import annotations

import gzip
import re
from dataclasses import dataclass

__all__ = ["GMS_URI", "METRO_URI", "RESULT_URI", "EVALUATION", "HOLE_FIELDS", "ALARM_FIELDS", "Space", "build"]

GMS_URI = "http://opcfoundation.org/UA/GMS/"
RESULT_URI = "http://opcfoundation.org/UA/Machinery/Result/"
MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
METRO_URI = "urn:metro:plant"
NODESETS = ("Opc.Ua.Di.NodeSet2.xml.gz", "Opc.Ua.Machinery.NodeSet2.xml.gz", "Opc.Ua.Machinery.Result.NodeSet2.xml.gz")
#: metro's hole status -> Machinery Result's ResultEvaluationEnum (Undefined 0, OK 1, NotOK 2,
#: NotDecidable 3: "not possible due to measurement uncertainty", ISO 14253-1's undecided)
EVALUATION = {"conforms": 1, "fails": 2, "undecided": 3, "not_measured": 0}
#: GMS CharacteristicType's variables metro fills: BrowseName -> (GMS NodeId number, variant type name)
CHARACTERISTIC = {"CharacteristicIdentifier": (6028, "String"), "IsValid": (6111, "Boolean"),
                  "LowerToleranceLimit": (6042, "Double"), "Nominal": (6044, "Double"),
                  "ResultEvaluation": (6038, "Int32"), "ResultValue": (6039, "Double"),
                  "UpperToleranceLimit": (6040, "Double")}
#: GMS CorrectionType's variables metro fills
CORRECTION = {"CharacteristicIdentifier": (6009, "String"), "Identifier": (6002, "String"),
              "CorrectionValueAbsolute": (6074, "Double")}
#: the fields of a hole's result-ready event beyond BaseEventType's (name -> variant type name): GMS's
#: characteristic fields, then metro's (U95, the status in words, the cell, a sequence number from 1)
HOLE_FIELDS = {**{k: v[1] for k, v in CHARACTERISTIC.items()}, "U95": "Double", "Status": "String",
               "CorrectionValueAbsolute": "Double", "Cell": "String", "Sequence": "UInt64", "Line": "Int64"}
#: the fields of a drift alarm event beyond BaseEventType's (its Severity: 700 raised, 800 sized)
ALARM_FIELDS = {"Cell": "String", "Sensor": "String", "HoleId": "String", "Alarm": "String"}


def _nodeset(name: str) -> str:
    """A shipped NodeSet's text; default values that nest an ExtensionObject inside another (asyncua
    2.1 cannot import them: three in Machinery Result, the ResultType variable type's) are left out."""
    from metrology.io.data import data_path

    text = gzip.decompress(data_path("opcua", name).read_bytes()).decode("utf-8")

    def drop(m):
        return "" if re.search(r"<(?:uax:)?Body>(?:(?!</(?:uax:)?Body>).)*?TypeId", m.group(0), re.S) else m.group(0)

    return re.sub(r"<Value>.*?</Value>", drop, text, flags=re.S)


@dataclass
class Space:
    """The nodes the server writes and the events it fires (made by :func:`build`)."""

    server: object
    gms: int
    metro: int
    machines: object
    hole_event: object
    alarm_event: object
    cells: dict
    calibration: dict
    types: tuple


async def build(server, calibration: dict) -> Space:
    """Load the NodeSets into ``server`` (an initialised ``asyncua.Server``), build the GMS subset
    and metro's types; ``calibration``: {"sha256", "file", "certificate": {...}} shown per cell."""
    from asyncua import ua

    for name in NODESETS:
        await server.import_xml(xmlstring=_nodeset(name), strict_mode=False, auto_load_definitions=False)
    gms = await server.register_namespace(GMS_URI)
    await _subset_metadata(server, gms)
    metro = await server.register_namespace(METRO_URI)
    result_ns = await server.get_namespace_index(RESULT_URI)
    machinery_ns = await server.get_namespace_index(MACHINERY_URI)
    base_object = server.get_node(ua.ObjectIds.BaseObjectType)
    char_t = await base_object.add_object_type(ua.NodeId(1009, gms), ua.QualifiedName("CharacteristicType", gms))
    for bname, (num, vt) in CHARACTERISTIC.items():
        v = await char_t.add_variable(ua.NodeId(num, gms), ua.QualifiedName(bname, gms), _zero(vt),
                                      varianttype=getattr(ua.VariantType, vt))
        await v.set_modelling_rule(True)
    corr_t = await base_object.add_object_type(ua.NodeId(1005, gms), ua.QualifiedName("CorrectionType", gms))
    for bname, (num, vt) in CORRECTION.items():
        v = await corr_t.add_variable(ua.NodeId(num, gms), ua.QualifiedName(bname, gms), _zero(vt),
                                      varianttype=getattr(ua.VariantType, vt))
        await v.set_modelling_rule(True)
    ready = server.get_node(ua.NodeId(1002, result_ns))  # Machinery Result's abstract ResultReadyEventType
    # the event types are i=1 and i=2 of metro's namespace (docs/plant.md); their fields named by string
    hole_t = await ready.add_object_type(ua.NodeId(1, metro), ua.QualifiedName("HoleResultReadyEventType", metro))
    alarm_t = await server.get_node(ua.ObjectIds.BaseEventType).add_object_type(
        ua.NodeId(2, metro), ua.QualifiedName("DriftAlarmEventType", metro))
    for t, spec in ((hole_t, HOLE_FIELDS), (alarm_t, ALARM_FIELDS)):
        tname = (await t.read_browse_name()).Name
        for name, vt in spec.items():
            await t.add_property(ua.NodeId(f"{tname}/{name}", metro), ua.QualifiedName(name, metro), _zero(vt),
                                 varianttype=getattr(ua.VariantType, vt))
    machines = server.get_node(ua.NodeId(1001, machinery_ns))  # Machinery's Machines folder
    await _notifier(server, server.get_node(ua.ObjectIds.Server), machines)
    return Space(server, gms, metro, machines, await server.get_event_generator(hole_t, ua.ObjectIds.Server),
                 await server.get_event_generator(alarm_t, ua.ObjectIds.Server), {}, dict(calibration), (char_t, corr_t))


def _zero(vt: str):
    return {"String": "", "Boolean": False, "Double": 0.0, "Int32": 0, "UInt64": 0, "Int64": 0}[vt]


async def _subset_metadata(server, gms: int) -> None:
    """GMS's NamespaceMetadata: its URI and version, and ``IsNamespaceSubset`` true."""
    from asyncua import ua

    ns = server.get_node(ua.ObjectIds.Server_Namespaces)
    meta = await ns.add_object(gms, GMS_URI, ua.ObjectIds.NamespaceMetadataType)
    for name, value, vt in (("NamespaceUri", GMS_URI, ua.VariantType.String),
                            ("NamespaceVersion", "1.0.0", ua.VariantType.String),
                            ("IsNamespaceSubset", True, ua.VariantType.Boolean)):
        await (await meta.get_child(name)).write_value(ua.Variant(value, vt))


async def _notifier(server, parent, child) -> None:
    """``parent`` HasNotifier ``child``, and ``child`` an event notifier: the chain up to Server."""
    from asyncua import ua

    await child.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
    ref = ua.AddReferencesItem()
    ref.SourceNodeId, ref.TargetNodeId = parent.nodeid, child.nodeid
    ref.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasNotifier)
    ref.IsForward, ref.TargetNodeClass = True, ua.NodeClass.Object
    (await server.iserver.isession.add_references([ref]))[0].check()


async def cell_node(space: Space, cell: str):
    """The cell's measuring-system object (made on its first hole): its last result and correction
    (GMS characteristic and correction) and the calibration in use; variables read-only."""
    if cell in space.cells:
        return space.cells[cell]
    from asyncua import ua

    m, g = space.metro, space.gms
    obj = await space.machines.add_object(ua.NodeId(f"cell/{cell}", m), ua.QualifiedName(cell, m))
    await _notifier(space.server, space.machines, obj)
    await obj.add_property(m, "Description", f"cell {cell}: the drilling end-effector's normal-sensor head (metro)")
    char_t, corr_t = space.types
    last = await obj.add_object(ua.NodeId(f"cell/{cell}/LastResult", m), ua.QualifiedName("LastResult", m), char_t.nodeid)
    corr = await obj.add_object(ua.NodeId(f"cell/{cell}/LastCorrection", m), ua.QualifiedName("LastCorrection", m),
                                corr_t.nodeid)
    cal = await obj.add_object(ua.NodeId(f"cell/{cell}/Calibration", m), ua.QualifiedName("Calibration", m))
    c = space.calibration
    await cal.add_property(m, "Sha256", c.get("sha256", ""))
    await cal.add_property(m, "File", c.get("file", ""))
    cert = await cal.add_object(m, "Certificate")
    for k, v in sorted(c.get("certificate", {}).items()):
        await cert.add_property(m, str(k), str(v))
    u95 = await last.add_variable(ua.NodeId(f"cell/{cell}/LastResult/U95", m), ua.QualifiedName("U95", m), 0.0)
    status = await last.add_variable(ua.NodeId(f"cell/{cell}/LastResult/Status", m), ua.QualifiedName("Status", m), "")
    nodes = {"result": {}, "correction": {}, "U95": u95, "Status": status}
    for key, parent, spec in (("result", last, CHARACTERISTIC), ("correction", corr, CORRECTION)):
        for bname in spec:
            nodes[key][bname] = await parent.get_child(ua.QualifiedName(bname, g))
    space.cells[cell] = (obj, nodes)
    return space.cells[cell]
