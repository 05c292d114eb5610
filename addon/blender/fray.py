"""Frayed torn edges: a Geometry Nodes group that grows short loose threads along the torn edges of
a baked Tear Cloth object, and the modifier that applies it.

What this file owns
-------------------
* ``build_group``: the node group "Tear Cloth Frayed Edges", made of stock nodes only (no drivers,
  no Python, no add-on node types), so a .blend that holds it renders on any machine with stock
  Blender, a render farm node without the add-on included. Its inputs are the ``fray`` rows of the
  settings table (default, bounds, description) plus a Material.
* ``add_modifier``: the Geometry Nodes modifier that runs it, placed right after the "Tear Cloth"
  Mesh Sequence Cache modifier (threads are made from the torn mesh the cache plays, and
  modifiers the user put below act on cloth and threads alike).

What the group reads (point attributes the cache carries, readable in stock Blender):
``torn`` (1.0 on a point of a torn edge), ``warp`` (the unit world-space warp direction at the
point; the group turns it into the object's space, where the cache's points are). ``torn_time`` (s) is in the cache too; the group does not need it (a frame shows only
tears that happened up to it).

How the threads are made: the torn boundary (edges with one face whose two points are torn) is
sampled every 1 / density metres; at each sample a thread runs along the warp or the weft
(weft = normal x warp, picked at random half and half) to the outside of the cloth (the side away
from the faces around the point), its direction and length varied by the jitter, swept into a
thin tube of the thread radius with the given material, and joined to the cloth. Without a
``warp`` attribute (a cache baked before it was carried) the threads point straight out of the
edge. The random choices follow the sample's index along the edge, so a tear that grows between
frames may reshuffle the threads near its tip. Blender 4.2's Mesh Sequence Cache reads no
attributes (``modifier.read_data``): there the group finds no torn point and adds nothing.
"""
from __future__ import annotations

import bpy

from .. import settings as table
from . import convert, modifier

GROUP_NAME = "Tear Cloth Frayed Edges"
MODIFIER_NAME = "Tear Cloth Frayed Edges"
# Stored on the group (an ID property, saved in the .blend): a group made by an older version of
# this file is rebuilt rather than reused.
VERSION_KEY = "tearcloth_fray_version"
VERSION = 2
TORN, WARP = "torn", "warp"  # the cache's point attributes


# ---------------------------------------------------------------------------------------------
# Small node helpers (sockets are found by name among the enabled ones: several nodes have
# same-named sockets of different types, of which the node's data type enables one)


def _node(tree, kind, x, y, **props):
    node = tree.nodes.new(kind)
    node.location = (x, y)
    for key, value in props.items():
        setattr(node, key, value)
    return node


def _socket(sockets, name, kind=None):
    for s in sockets:
        if s.name == name and s.enabled and (kind is None or s.type == kind):
            return s
    raise KeyError(f"no enabled socket {name!r} ({kind or 'any type'})")


def _in(node, name, kind=None):
    return _socket(node.inputs, name, kind)


def _out(node, name=None, kind=None):
    if name is None:
        return next(s for s in node.outputs if s.enabled)
    return _socket(node.outputs, name, kind)


def _math(tree, x, y, op, a, b=None, c=None):
    """A float Math node on sockets or constants; returns its output."""
    node = _node(tree, "ShaderNodeMath", x, y, operation=op)
    for i, value in enumerate((a, b, c)):
        if value is None:
            continue
        if isinstance(value, bpy.types.NodeSocket):
            tree.links.new(value, node.inputs[i])
        else:
            node.inputs[i].default_value = value
    return node.outputs[0]


def _vec(tree, x, y, op, a, b=None, scale=None):
    """A Vector Math node; returns its vector output (or the value output for DOT/LENGTH)."""
    node = _node(tree, "ShaderNodeVectorMath", x, y, operation=op)
    inputs = [s for s in node.inputs if s.enabled]
    vectors = [s for s in inputs if s.type == "VECTOR"]
    for socket, value in zip(vectors, (a, b)):
        if value is None:
            continue
        if isinstance(value, bpy.types.NodeSocket):
            tree.links.new(value, socket)
        else:
            socket.default_value = value
    if scale is not None:
        socket = _in(node, "Scale")
        if isinstance(scale, bpy.types.NodeSocket):
            tree.links.new(scale, socket)
        else:
            socket.default_value = scale
    if op in ("DOT_PRODUCT", "LENGTH", "DISTANCE"):
        return _out(node, "Value")
    return _out(node, "Vector")


def _random(tree, x, y, data_type, seed, offset, index, **values):
    node = _node(tree, "FunctionNodeRandomValue", x, y, data_type=data_type)
    kind = {"FLOAT": "VALUE", "FLOAT_VECTOR": "VECTOR", "BOOLEAN": None}[data_type]
    for name, value in values.items():
        _in(node, name, kind if name in ("Min", "Max") else None).default_value = value
    tree.links.new(index, _in(node, "ID"))
    tree.links.new(_math(tree, x - 160, y - 120, "ADD", seed, float(offset)), _in(node, "Seed"))
    return _out(node, "Value")


def _switch(tree, x, y, input_type, switch, false, true):
    node = _node(tree, "GeometryNodeSwitch", x, y, input_type=input_type)
    tree.links.new(switch, _in(node, "Switch"))
    for name, value in (("False", false), ("True", true)):
        if isinstance(value, bpy.types.NodeSocket):
            tree.links.new(value, _in(node, name))
        else:
            _in(node, name).default_value = value
    return _out(node, "Output")


# ---------------------------------------------------------------------------------------------
# The group


def _interface(tree):
    """The group's sockets: Geometry in and out, the fray rows of the table, a Material."""
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    for row in table.rows("fray"):
        kind = "NodeSocketInt" if row.kind == "int" else "NodeSocketFloat"
        socket = tree.interface.new_socket(row.label, in_out="INPUT", socket_type=kind)
        socket.description = row.description
        cast = int if row.kind == "int" else float
        socket.default_value = cast(row.default)
        if row.hard is not None and row.hard.lo is not None:
            socket.min_value = cast(row.hard.lo)
        if row.hard is not None and row.hard.hi is not None:
            socket.max_value = cast(row.hard.hi)
        subtype = {"m": "DISTANCE", "1": "FACTOR" if row.kind == "float" else None}.get(row.unit)
        if subtype and hasattr(socket, "subtype"):  # a length shows in the scene's units (values: Blender units)
            socket.subtype = subtype
    material = tree.interface.new_socket("Material", in_out="INPUT", socket_type="NodeSocketMaterial")
    material.description = "Material of the threads (Add Frayed Edges picks the cloth's own)"


def build_group():
    """A new node group "Tear Cloth Frayed Edges" (see the file head for what it does)."""
    tree = bpy.data.node_groups.new(GROUP_NAME, "GeometryNodeTree")
    tree[VERSION_KEY] = VERSION
    tree.description = "Loose threads along the warp and weft at the torn edges of a Tear Cloth cache"
    _interface(tree)
    nodes, link = tree.nodes, tree.links.new
    group_in = _node(tree, "NodeGroupInput", -2200, 0)
    group_out = _node(tree, "NodeGroupOutput", 1800, 0)
    label = {row.name: row.label for row in table.rows("fray")}
    gin = lambda name: group_in.outputs[label[name] if name in label else name]  # noqa: E731

    # Per point of the cloth: its normal and the way into the cloth (from the point to the mean
    # of the centres of its faces), captured before the torn boundary becomes a curve.
    centres = _node(tree, "GeometryNodeFieldOnDomain", -2000, -300, domain="FACE", data_type="FLOAT_VECTOR")
    link(_node(tree, "GeometryNodeInputPosition", -2200, -300).outputs[0], _in(centres, "Value"))
    position = _node(tree, "GeometryNodeInputPosition", -2000, -450).outputs[0]
    inward = _vec(tree, -1800, -350, "SUBTRACT", _out(centres, "Value"), position)
    capture = _node(tree, "GeometryNodeCaptureAttribute", -1600, 0, domain="POINT")
    capture.capture_items.new("VECTOR", "Normal")
    capture.capture_items.new("VECTOR", "Inward")
    # sockets by name, never by position: Blender 5.3 added a Selection socket before the items
    link(gin("Geometry"), capture.inputs["Geometry"])
    link(_node(tree, "GeometryNodeInputNormal", -1800, -200).outputs["Normal"], capture.inputs["Normal"])
    link(inward, capture.inputs["Inward"])

    # The torn boundary: edges with a single face whose two points are both torn.
    torn = _node(tree, "GeometryNodeInputNamedAttribute", -1800, 300, data_type="FLOAT")
    _in(torn, "Name").default_value = TORN
    on_tear = _node(tree, "FunctionNodeCompare", -1600, 300, data_type="FLOAT", operation="GREATER_THAN")
    link(_out(torn, "Attribute"), _in(on_tear, "A", "VALUE"))
    _in(on_tear, "B", "VALUE").default_value = 0.75  # an edge averages its points: both are torn
    faces = _node(tree, "GeometryNodeInputMeshEdgeNeighbors", -1800, 450)
    boundary = _node(tree, "FunctionNodeCompare", -1600, 450, data_type="INT", operation="EQUAL")
    link(faces.outputs["Face Count"], _in(boundary, "A", "INT"))
    _in(boundary, "B", "INT").default_value = 1
    both = _node(tree, "FunctionNodeBooleanMath", -1400, 350, operation="AND")
    link(_out(on_tear, "Result"), both.inputs[0])
    link(_out(boundary, "Result"), both.inputs[1])
    to_curve = _node(tree, "GeometryNodeMeshToCurve", -1200, 100)
    link(capture.outputs["Geometry"], _in(to_curve, "Mesh"))
    link(_out(both), _in(to_curve, "Selection"))
    samples = _node(tree, "GeometryNodeCurveToPoints", -1000, 100, mode="LENGTH")
    link(_out(to_curve), _in(samples, "Curve"))
    # 1 / density metres between samples (no threads at density 0: a spacing longer than any edge)
    spacing = _math(tree, -1200, -100, "DIVIDE", 1.0, _math(tree, -1400, -100, "MAXIMUM", gin("density"), 1e-6))
    link(spacing, _in(samples, "Length"))

    # Directions at a sample: normal n, warp w (in the tangent plane), weft = n x w, outward o.
    index = _node(tree, "GeometryNodeInputIndex", -1000, -600).outputs[0]
    seed = gin("seed")
    n = _vec(tree, -800, -200, "NORMALIZE", capture.outputs["Normal"])
    warp_attr = _node(tree, "GeometryNodeInputNamedAttribute", -1400, -350, data_type="FLOAT_VECTOR")
    _in(warp_attr, "Name").default_value = WARP
    warp_world = _out(warp_attr, "Attribute")
    # the cache's warp is in world space, the geometry in the object's: turn it by the inverse
    # of the object's own transform
    own = _node(tree, "GeometryNodeObjectInfo", -1400, -500, transform_space="ORIGINAL")
    link(_node(tree, "GeometryNodeSelfObject", -1600, -500).outputs[0], _in(own, "Object"))
    inverse = _node(tree, "FunctionNodeInvertMatrix", -1200, -500)
    link(_out(own, "Transform"), _in(inverse, "Matrix"))
    to_local = _node(tree, "FunctionNodeTransformDirection", -1000, -350)
    link(warp_world, _in(to_local, "Direction"))
    link(_out(inverse, "Matrix"), _in(to_local, "Transform"))
    warp = _out(to_local, "Direction")
    warp_t = _vec(tree, -600, -350, "NORMALIZE", _vec(tree, -800, -350, "SUBTRACT", warp,
                                                      _vec(tree, -1000, -450, "PROJECT", warp, n)))
    weft = _vec(tree, -400, -450, "CROSS_PRODUCT", n, warp_t)
    inward_t = _vec(tree, -800, -550, "SUBTRACT", capture.outputs["Inward"], _vec(tree, -1000, -700, "PROJECT",
                                                                           capture.outputs["Inward"], n))
    outward = _vec(tree, -600, -550, "NORMALIZE", _vec(tree, -800, -700, "SCALE", inward_t, scale=-1.0))
    pick_warp = _random(tree, -400, -200, "BOOLEAN", seed, 0, index, Probability=0.5)
    thread = _switch(tree, -200, -300, "VECTOR", pick_warp, weft, warp_t)
    has_warp = _node(tree, "FunctionNodeCompare", -200, -650, data_type="FLOAT", operation="GREATER_THAN")
    link(_vec(tree, -400, -700, "LENGTH", warp_world), _in(has_warp, "A", "VALUE"))
    _in(has_warp, "B", "VALUE").default_value = 0.5  # a unit vector, or zeros where none is carried
    thread = _switch(tree, 0, -400, "VECTOR", _out(has_warp, "Result"), outward, thread)
    # to the outside of the cloth: the sign of thread . outward (+1 when along the edge)
    side = _math(tree, 200, -500, "MULTIPLY_ADD",
                 _math(tree, 0, -550, "GREATER_THAN", _vec(tree, 0, -700, "DOT_PRODUCT", thread, outward), -1e-6),
                 2.0, -1.0)
    thread = _vec(tree, 400, -400, "SCALE", thread, scale=side)
    # jitter: a random nudge of the direction (up to about 30 degrees at jitter 1) and of the length
    nudge = _random(tree, 400, -650, "FLOAT_VECTOR", seed, 1, index, Min=(-0.4, -0.4, -0.4), Max=(0.4, 0.4, 0.4))
    thread = _vec(tree, 800, -400, "NORMALIZE", _vec(tree, 600, -400, "ADD", thread,
                                                     _vec(tree, 600, -600, "SCALE", nudge, scale=gin("jitter"))))
    spread = _random(tree, 400, -900, "FLOAT", seed, 2, index, Min=-0.5, Max=0.5)
    length = _math(tree, 800, -800, "MULTIPLY", gin("length"),
                   _math(tree, 600, -800, "MULTIPLY_ADD", spread, gin("jitter"), 1.0))

    # One unit line along Z per sample, turned onto the thread and scaled to its length, then
    # swept into a tube.
    line = _node(tree, "GeometryNodeCurvePrimitiveLine", 600, 200)
    _in(line, "Start").default_value = (0.0, 0.0, 0.0)
    _in(line, "End").default_value = (0.0, 0.0, 1.0)
    align = _node(tree, "FunctionNodeAlignRotationToVector", 1000, -400, axis="Z")
    link(thread, _in(align, "Vector"))
    instances = _node(tree, "GeometryNodeInstanceOnPoints", 1000, 100)
    link(_out(samples, "Points"), _in(instances, "Points"))
    link(_out(line), _in(instances, "Instance"))
    link(_out(align), _in(instances, "Rotation"))
    link(length, _in(instances, "Scale"))
    realize = _node(tree, "GeometryNodeRealizeInstances", 1200, 100)
    link(_out(instances), _in(realize, "Geometry"))
    profile = _node(tree, "GeometryNodeCurvePrimitiveCircle", 1200, -150)
    _in(profile, "Resolution").default_value = 6
    link(gin("thread_radius"), _in(profile, "Radius"))
    tube = _node(tree, "GeometryNodeCurveToMesh", 1400, 100)
    link(_out(realize), _in(tube, "Curve"))
    link(_out(profile, "Curve"), _in(tube, "Profile Curve"))
    material = _node(tree, "GeometryNodeSetMaterial", 1600, 100)
    link(_out(tube), _in(material, "Geometry"))
    link(gin("Material"), _in(material, "Material"))
    join = _node(tree, "GeometryNodeJoinGeometry", 1700, 0)
    link(_out(material), join.inputs[0])
    link(gin("Geometry"), join.inputs[0])
    link(_out(join), group_out.inputs[0])
    del nodes
    return tree


def group():
    """The file's frayed-edge group, made if missing or made by an older version of this file."""
    tree = bpy.data.node_groups.get(GROUP_NAME)
    if tree is not None and tree.bl_idname == "GeometryNodeTree" and tree.get(VERSION_KEY) == VERSION:
        return tree
    if tree is not None:
        tree.name = GROUP_NAME + " (old)"  # kept for whatever still uses it; ours takes the name
    return build_group()


# ---------------------------------------------------------------------------------------------
# The modifier


def find_modifier(obj):
    md = obj.modifiers.get(MODIFIER_NAME)
    return md if md is not None and md.type == "NODES" else None


def socket_identifier(tree, name: str) -> str:
    for item in tree.interface.items_tree:
        if item.item_type == "SOCKET" and item.in_out == "INPUT" and item.name == name:
            return item.identifier
    raise KeyError(name)


def _rna_inputs(md):
    """Blender 5.3's modifier inputs (``md.properties.inputs.<identifier>.value``), or None where
    they are ID properties of the modifier (``md[identifier]``, 4.2-5.0): 5.3 refuses the latter."""
    props = getattr(md, "properties", None)
    return getattr(props, "inputs", None) if props is not None else None


def input_value(md, name: str):
    """The modifier's value of the group input labelled ``name``."""
    ident = socket_identifier(md.node_group, name)
    inputs = _rna_inputs(md)
    return getattr(inputs, ident).value if inputs is not None else md[ident]


def set_input(md, name: str, value) -> None:
    """Set the modifier's value of the group input labelled ``name``."""
    ident = socket_identifier(md.node_group, name)
    inputs = _rna_inputs(md)
    if inputs is not None:
        getattr(inputs, ident).value = value
    else:
        md[ident] = value


def add_modifier(obj, scene, material=None):
    """The frayed-edge modifier of ``obj`` right after its "Tear Cloth" modifier, with the table's
    defaults (lengths in the scene's units) and ``material`` for the threads. Returns it (the
    existing one if there is one, unchanged)."""
    md = find_modifier(obj)
    if md is not None:
        return md
    tree = group()
    md = obj.modifiers.new(MODIFIER_NAME, "NODES")
    md.node_group = tree
    # The group works in Blender units: lengths, and the density per length, in the scene's.
    per_unit = {"m": 1.0 / convert.scale_length(scene), "1/m": convert.scale_length(scene)}
    for row in table.rows("fray"):
        value = row.default * per_unit.get(row.unit, 1.0)
        set_input(md, row.label, int(value) if row.kind == "int" else float(value))
    if material is not None:
        set_input(md, "Material", material)
    cache_md = modifier.find_modifier(obj)
    if cache_md is not None:
        obj.modifiers.move(len(obj.modifiers) - 1, modifier.modifier_index(obj, cache_md) + 1)
    return md
