"""The standard types of the served OPC UA model: OPC 10000-100 (DI) and OPC 40010-1 (Robotics).

The official NodeSet2 files of both companion specifications ship in ``nodesets/`` (OPC Foundation MIT
License 1.00, their headers kept; docs/sources.md) and are imported into the server's address space
before the agent's own nodes, so a client sees the standard ObjectTypes and finds our nodes by them:

- ``FlangeLoad`` is an instance of Robotics ``LoadType`` (ns Robotics, i=1018): ``Mass``
  (AnalogUnitType, EngineeringUnits kg), ``CenterOfMass`` (3DFrameType: ``CartesianCoordinates`` X, Y, Z
  in mm from the flange with LengthUnit, ``Orientation`` A, B, C of the principal axes of inertia in
  degrees with AngleUnit, intrinsic z-y'-x'' as OPC 10000-210's RpyOrientationType) and ``Inertia``
  (3DVectorType: the principal moments X, Y, Z in kg·m² with VectorUnit, BadWaitingForInitialData while
  unknown). Each structured variable carries its whole value (3DFrame, 3DVector) and its components;
- ``Tools``, ``LastResult``, ``Handshake`` and each handshake block are DI ``FunctionalGroupType``
  instances: DI's way of grouping the parameters and methods of one function.

Browse names follow the types: Mass, CenterOfMass and Inertia in the Robotics namespace, the spatial
components (CartesianCoordinates, X, ..., A, ..., EngineeringUnits) in namespace 0, the agent's own
additions (ToolName, the tools, results and handshakes) in ``urn:payload-agent:plc``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from asyncua import ua

NODESET_DIR = Path(__file__).resolve().parent / "nodesets"
NODESETS = ("Opc.Ua.Di.NodeSet2.xml", "Opc.Ua.Robotics.NodeSet2.xml")  # DI first: Robotics builds on it
DI_URI = "http://opcfoundation.org/UA/DI/"
ROBOTICS_URI = "http://opcfoundation.org/UA/Robotics/"
LOAD_TYPE_ID = 1018  # Robotics LoadType
FUNCTIONAL_GROUP_TYPE_ID = 1005  # DI FunctionalGroupType
_UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
UNITS = {"kg": ("KGM", "kg", "kilogram"), "mm": ("MMT", "mm", "millimetre"), "deg": ("DD", "°", "degree"),
         "kgm2": ("B32", "kg·m²", "kilogram metre squared")}


def unit(code: str) -> ua.EUInformation:
    """EUInformation of a UNECE unit (OPC 10000-8 §5.6.3: UnitId from the common code's characters)."""
    unece, shown, text = UNITS[code]
    unit_id = 0
    for ch in unece:
        unit_id = (unit_id << 8) | ord(ch)
    return ua.EUInformation(NamespaceUri=_UNECE, UnitId=unit_id, DisplayName=ua.LocalizedText(shown),
                            Description=ua.LocalizedText(text))


@dataclass(frozen=True)
class Namespaces:
    own: int
    di: int
    robotics: int


async def load_standard_types(server, own_uri: str) -> Namespaces:
    """Import the DI and Robotics nodesets, register the agent's namespace; their indexes."""
    importer_log = logging.getLogger("asyncua.common.xmlimporter")
    level = importer_log.level
    importer_log.setLevel(logging.ERROR)  # DI's structures make the importer log notes that are not problems
    try:
        for name in NODESETS:
            await server.import_xml(str(NODESET_DIR / name))
    finally:
        importer_log.setLevel(level)
    own = await server.register_namespace(own_uri)
    return Namespaces(own, await server.get_namespace_index(DI_URI), await server.get_namespace_index(ROBOTICS_URI))


async def add_group(parent, ns: Namespaces, name: str):
    """A DI FunctionalGroupType object (its optional placeholders left out)."""
    return await parent.add_object(ns.own, name, objecttype=ua.NodeId(FUNCTIONAL_GROUP_TYPE_ID, ns.di),
                                   instantiate_optional=False)


@dataclass(frozen=True)
class LoadNodes:
    """The variables of one LoadType instance the server writes."""

    mass: object
    center_of_mass: object
    cartesian: object
    orientation: object
    inertia: object
    xyz: tuple
    abc: tuple
    moments: tuple


async def add_flange_load(parent, ns: Namespaces) -> LoadNodes:
    """``FlangeLoad``: a Robotics LoadType instance with every optional part, units set."""
    load = await parent.add_object(ns.own, "FlangeLoad", objecttype=ua.NodeId(LOAD_TYPE_ID, ns.robotics))
    mass = await load.get_child(f"{ns.robotics}:Mass")
    await (await mass.get_child("0:EngineeringUnits")).write_value(unit("kg"))
    com = await load.get_child(f"{ns.robotics}:CenterOfMass")
    cart = await com.get_child("0:CartesianCoordinates")
    orient = await com.get_child("0:Orientation")
    inertia = await load.get_child(f"{ns.robotics}:Inertia")
    await cart.add_property(0, "LengthUnit", unit("mm"))
    await orient.add_property(0, "AngleUnit", unit("deg"))
    await inertia.add_property(0, "VectorUnit", unit("kgm2"))
    xyz = tuple([await cart.get_child(f"0:{a}") for a in "XYZ"])
    abc = tuple([await orient.get_child(f"0:{a}") for a in "ABC"])
    moments = tuple([await inertia.get_child(f"0:{a}") for a in "XYZ"])
    return LoadNodes(mass, com, cart, orient, inertia, xyz, abc, moments)


async def write_load(nodes: LoadNodes, mass_kg: float, cog_mm, orientation_deg, moments_kgm2) -> None:
    """Write one payload: the structured values and their components alike (``moments_kgm2`` None: the
    inertia is not known, every part of Inertia BadWaitingForInitialData)."""
    D = ua.VariantType.Double
    await nodes.mass.write_value(ua.Variant(float(mass_kg), D))
    x, y, z = (float(v) for v in cog_mm)
    a, b, c = (float(v) for v in orientation_deg)
    cart = ua.ThreeDCartesianCoordinates(X=x, Y=y, Z=z)
    orient = ua.ThreeDOrientation(A=a, B=b, C=c)
    await nodes.center_of_mass.write_value(ua.Variant(ua.ThreeDFrame(CartesianCoordinates=cart, Orientation=orient)))
    await nodes.cartesian.write_value(ua.Variant(cart))
    await nodes.orientation.write_value(ua.Variant(orient))
    for node, v in zip(nodes.xyz + nodes.abc, (x, y, z, a, b, c)):
        await node.write_value(ua.Variant(v, D))
    known = moments_kgm2 is not None
    values = [float(v) for v in moments_kgm2] if known else [math.nan] * 3
    status = ua.StatusCode(ua.StatusCodes.Good if known else ua.StatusCodes.BadWaitingForInitialData)
    await nodes.inertia.write_value(ua.DataValue(ua.Variant(ua.ThreeDVector(X=values[0], Y=values[1], Z=values[2])),
                                                 StatusCode=status))
    for node, v in zip(nodes.moments, values):
        await node.write_value(ua.DataValue(ua.Variant(v, D), StatusCode=status))
