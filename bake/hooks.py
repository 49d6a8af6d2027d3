"""Material hooks: node setups that show baked light in EEVEE while Cycles renders the material as it was.

UV lightmap hook (`add_lightmap_hook`): a node group "Photon Lightmap" is added
to each material of a baked object, with its own Material Output for EEVEE
only, so EEVEE and Material Preview show baked light. Every node we add is
named "Photon Lightmap ..." and tagged HOOK_PROP; `remove_lightmap_hook`
deletes exactly those nodes.

Orientation lightmap hook (`add_ol_hook`, thesis ch. 6): every material of the
objects an OL covers (innermost OL, non-backup) gets a frame of nodes: the
shared group "Photon Orientation Lightmap" turns the Geometry node's world
normal into the octahedral (s, t) with math nodes, an Image Texture (Linear,
Extend) reads the OL image there, and the "Photon Lightmap" group multiplies
by the base colour into an EEVEE-only Material Output. No UV layer is needed.
Its nodes carry HOOK_PROP too (so Remove Lightmap Hook treats them as ours)
plus OL_HOOK_PROP = the empty's name, which `remove_ol_hook` uses to delete
exactly them.
"""
from ..export.context import LIGHTMAP_UV, output_priority

HOOK_PROP = "photon_lightmaps_hook"
HOOK_GROUP = "Photon Lightmap"
HOOK_PREFIX = "Photon Lightmap"
OL_HOOK_PROP = "photon_lightmaps_ol_hook"    # on our OL nodes (value: empty name) and on the OL group (1)
OL_GROUP = "Photon Orientation Lightmap"
OL_PREFIX = "Photon Orientation Lightmap"
DIRECTION_GROUP = "Photon Lightmap Direction"
DIRECTION_PROP = "photon_lightmaps_direction_group"
L1_GROUP = "Photon Lightmap L1"
L1_PROP = "photon_lightmaps_l1_group"


def hook_nodes(tree, frame, origin, lookup, vector, image, group, out, surface, tag):
    """Image (read at `vector`, made by node `lookup`) -> lightmap group -> an
    EEVEE-only Material Output beside the user's. Shared by the UV lightmap
    hook and the orientation lightmap hook (add_ol_hook); returns the group node."""
    tex = tag(tree.nodes.new("ShaderNodeTexImage"), "Image")
    tex.image = image
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    grp = tag(tree.nodes.new("ShaderNodeGroup"), "Group")
    grp.node_tree = group
    eo = tag(tree.nodes.new("ShaderNodeOutputMaterial"), "Output")
    eo.target = "EEVEE"
    for n, dx in ((lookup, -700), (tex, -500), (grp, -200), (eo, 0)):
        n.parent = frame
        n.location = (origin[0] + dx, origin[1])
    tree.links.new(vector, tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], grp.inputs["Lightmap"])
    if surface is not None:
        tree.links.new(surface, grp.inputs["Shader"])
    tree.links.new(grp.outputs["Shader"], eo.inputs["Surface"])
    if out is not None:
        for key in ("Volume", "Displacement"):
            src = _source(out.inputs[key])
            if src is not None:
                tree.links.new(src, eo.inputs[key])
    return grp


def _tag(node, role):
    node[HOOK_PROP] = role
    node.name = f"{HOOK_PREFIX} {role}" if role != "Group" else HOOK_PREFIX
    node.label = node.name
    return node


def _sock(sockets, identifier):
    # Mix nodes have several sockets of one name; the identifier tells them apart.
    return next(s for s in sockets if s.identifier == identifier)


def _find_or_new_group(prop, name, description):
    """Our shader node group tagged `prop` (local, not linked) -> (group, made now)."""
    import bpy
    for ng in bpy.data.node_groups:
        if ng.get(prop) and ng.library is None and ng.bl_idname == "ShaderNodeTree":
            return ng, False
    ng = bpy.data.node_groups.new(name, "ShaderNodeTree")
    ng[prop] = 1
    ng.description = description
    return ng, True


def hook_group():
    """The shared node group: mixes emission = base colour x lightmap over the original surface."""
    ng, new = _find_or_new_group(HOOK_PROP, HOOK_GROUP,
                                 "Photon Lightmaps: baked light (base colour x lightmap) shown in EEVEE")
    if not new:
        return ng
    io = ng.interface
    io.new_socket("Shader", in_out="INPUT", socket_type="NodeSocketShader")
    base = io.new_socket("Base Color", in_out="INPUT", socket_type="NodeSocketColor")
    base.default_value = (0.8, 0.8, 0.8, 1.0)
    lmap = io.new_socket("Lightmap", in_out="INPUT", socket_type="NodeSocketColor")
    lmap.default_value = (0.0, 0.0, 0.0, 1.0)
    st = io.new_socket("Strength", in_out="INPUT", socket_type="NodeSocketFloat")
    st.default_value, st.min_value = 1.0, 0.0
    fac = io.new_socket("Factor", in_out="INPUT", socket_type="NodeSocketFloat")
    fac.default_value, fac.min_value, fac.max_value = 1.0, 0.0, 1.0
    fac.subtype = "FACTOR"
    io.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    n, l = ng.nodes, ng.links
    gi, go = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    mul = n.new("ShaderNodeMix")
    mul.data_type, mul.blend_type = "RGBA", "MULTIPLY"
    _sock(mul.inputs, "Factor_Float").default_value = 1.0
    em = n.new("ShaderNodeEmission")
    mix = n.new("ShaderNodeMixShader")
    gi.location, mul.location, em.location, mix.location, go.location = \
        (-500, 0), (-250, -100), (-50, -100), (150, 0), (350, 0)
    l.new(gi.outputs["Base Color"], _sock(mul.inputs, "A_Color"))
    l.new(gi.outputs["Lightmap"], _sock(mul.inputs, "B_Color"))
    l.new(_sock(mul.outputs, "Result_Color"), em.inputs["Color"])
    l.new(gi.outputs["Strength"], em.inputs["Strength"])
    l.new(gi.outputs["Factor"], mix.inputs[0])
    l.new(gi.outputs["Shader"], mix.inputs[1])
    l.new(em.outputs["Emission"], mix.inputs[2])
    l.new(mix.outputs["Shader"], go.inputs["Shader"])
    return ng


def _reader_group(prop, name, description, images):
    """A directional reader's node group: inputs Lightmap, the images' colours
    (`images`: socket names) and Normal, output Lightmap -> (group, its input node,
    output node, Geometry node, vmath), or the existing group alone (its nodes
    made once). vmath(op, a, b=None, scale=None) links a Vector Math node."""
    ng, new = _find_or_new_group(prop, name, description)
    if not new:
        return ng, None
    io = ng.interface
    lm_in = io.new_socket("Lightmap", in_out="INPUT", socket_type="NodeSocketColor")
    lm_in.default_value = (0.0, 0.0, 0.0, 1.0)
    for socket in images:
        io.new_socket(socket, in_out="INPUT", socket_type="NodeSocketColor")
    io.new_socket("Normal", in_out="INPUT", socket_type="NodeSocketVector")
    io.new_socket("Lightmap", in_out="OUTPUT", socket_type="NodeSocketColor")
    n, l = ng.nodes, ng.links

    def vmath(op, a, b=None, scale=None):
        node = n.new("ShaderNodeVectorMath")
        node.operation = op
        l.new(a, node.inputs[0])
        if b is not None:
            l.new(b, node.inputs[1])
        if scale is not None:
            l.new(scale, node.inputs["Scale"])
        return node.outputs["Value"] if op in ("LENGTH", "DOT_PRODUCT") else node.outputs["Vector"]

    nodes = n.new("NodeGroupInput"), n.new("NodeGroupOutput"), n.new("ShaderNodeNewGeometry")
    return ng, nodes + (vmath,)


def direction_group():
    """The shared node group of directional lightmaps: the lightmap scaled to the
    shading normal (engine/transport/directional_lightmap.py's formula):
    E · [k · max(0, n'·s) / max(n·s, MIN_COS) + (1 - k) (1 + n'·n) / 2], with
    u = k s from the direction image and n the surface's true normal."""
    from ..engine.transport.directional_lightmap import MIN_COS
    ng, made = _reader_group(DIRECTION_PROP, DIRECTION_GROUP,
                             "Photon Lightmaps: a directional lightmap read for the shading normal", ("Direction",))
    if made is None:
        return ng
    gi, go, geo, vmath = made
    n, l = ng.nodes, ng.links

    def math(op, a, b=None):
        node = n.new("ShaderNodeMath")
        node.operation = op
        for i, x in enumerate((a, b)):
            if isinstance(x, float):
                node.inputs[i].default_value = x
            elif x is not None:
                l.new(x, node.inputs[i])
        return node.outputs["Value"]

    u, normal, true = gi.outputs["Direction"], gi.outputs["Normal"], geo.outputs["True Normal"]
    k = vmath("LENGTH", u)
    s = vmath("NORMALIZE", u)
    lit = math("DIVIDE", math("MAXIMUM", vmath("DOT_PRODUCT", normal, s), 0.0),
               math("MAXIMUM", vmath("DOT_PRODUCT", true, s), MIN_COS))
    ambient = math("MULTIPLY", math("ADD", vmath("DOT_PRODUCT", normal, true), 1.0), 0.5)
    g = math("ADD", math("MULTIPLY", k, lit), math("MULTIPLY", math("SUBTRACT", 1.0, k), ambient))
    l.new(vmath("SCALE", gi.outputs["Lightmap"], scale=g), go.inputs["Lightmap"])
    return ng


def l1_group():
    """The shared node group of L1 SH lightmaps: per colour, the lightmap moved to
    the shading normal n' by its first-order coefficients,
    max(0, E + L1x (n'x - nx) + L1y (n'y - ny) + L1z (n'z - nz)), n the surface's
    true normal (engine/transport/directional_lightmap.py l1_channels)."""
    ng, made = _reader_group(L1_PROP, L1_GROUP, "Photon Lightmaps: an L1 SH lightmap read for the shading normal",
                             ("L1x", "L1y", "L1z"))
    if made is None:
        return ng
    gi, go, geo, vmath = made
    n, l = ng.nodes, ng.links
    d = n.new("ShaderNodeSeparateXYZ")
    l.new(vmath("SUBTRACT", gi.outputs["Normal"], geo.outputs["True Normal"]), d.inputs[0])
    total = gi.outputs["Lightmap"]
    for a, axis in zip("xyz", "XYZ"):
        total = vmath("ADD", total, vmath("SCALE", gi.outputs["L1" + a], scale=d.outputs[axis]))
    zero = n.new("ShaderNodeVectorMath")
    zero.operation = "MAXIMUM"
    l.new(total, zero.inputs[0])
    zero.inputs[1].default_value = (0.0, 0.0, 0.0)
    l.new(zero.outputs["Vector"], go.inputs["Lightmap"])
    return ng


def _user_output(tree):
    outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial" and not n.get(HOOK_PROP)]
    # The output Cycles renders (the export's rule): the hook shows the light of that surface.
    outs.sort(key=output_priority)
    return outs[0] if outs else None


def _hook_frame_origin(tree):
    """(user output, its surface socket source, origin of our frame below it)."""
    out = _user_output(tree)
    surface = _source(out.inputs["Surface"]) if out is not None else None
    origin = (out.location.x, out.location.y - 400) if out is not None else (300, -400)
    return out, surface, origin


def _hookable(mat, warnings, what):
    """False (with a warning) for a material we cannot edit."""
    if mat.library is not None or mat.node_tree is None:
        why = "is linked from a library" if mat.library is not None else "uses no nodes"
        warnings.append(f"material '{mat.name}' {why}: no {what} hook added")
        return False
    return True


def _material_users(mat):
    import bpy
    return {o.name for o in bpy.data.objects if any(s.material == mat for s in o.material_slots)}


def _source(socket):
    """The output socket feeding `socket`, through reroutes (None if unlinked)."""
    seen = 0
    while socket.is_linked and seen < 64:
        link = socket.links[0]
        if link.from_node.bl_idname != "NodeReroute":
            return link.from_socket
        socket = link.from_node.inputs[0]
        seen += 1
    return None


def remove_hook_nodes(mat):
    """Deletes our nodes from one material -> how many."""
    tree = mat.node_tree
    if tree is None or mat.library is not None:
        return 0
    ours = [n for n in tree.nodes if n.get(HOOK_PROP)]
    for n in ours:
        tree.nodes.remove(n)
    return len(ours)


def add_lightmap_hook(ob, image, baked_objects=(), warnings=None, parts=(), materials=None, direction=None,
                      l1=None):
    """Adds (or refreshes) our hook in every material of `ob`; returns the material names.

    materials: the materials to hook instead of `ob`'s slots (a CSG solid's Boolean
    result also shows its operands' materials); parts: objects whose surface is in
    this image (a CSG solid's operands), so sharing a material with them is fine.
    direction: a directional bake's direction image; the lightmap is then read
    for the shading normal (the BSDF's Normal input, so normal maps show).
    l1: an L1 SH bake's three images (x, y, z), read the same way.
    """
    warnings = warnings if warnings is not None else []
    ng = hook_group()
    done = []
    mats = []
    for m in (materials if materials is not None else [s.material for s in ob.material_slots]):
        if m is not None and m not in mats:
            mats.append(m)
    if not mats:
        warnings.append(f"object '{ob.name}' has no material: no lightmap hook added")
    for mat in mats:
        if not _hookable(mat, warnings, "lightmap"):
            continue
        users = sorted(_material_users(mat) - {ob.name} - set(parts))
        others_baked = [u for u in users if u in baked_objects]
        others = [u for u in users if u not in baked_objects]
        if others:
            warnings.append(f"material '{mat.name}' is shared with objects not baked now "
                            f"({', '.join(others)}): in EEVEE they show '{ob.name}''s lightmap")
        if others_baked:
            warnings.append(f"material '{mat.name}' is shared by baked objects "
                            f"({', '.join([ob.name] + others_baked)}): it can show only one of their "
                            f"lightmaps; give each object its own material")
        remove_hook_nodes(mat)
        tree = mat.node_tree
        out, surface, (x0, y0) = _hook_frame_origin(tree)
        frame = _tag(tree.nodes.new("NodeFrame"), "Frame")
        frame.label = "Photon Lightmap (baked light, EEVEE only; remove with Remove Lightmap Hook)"
        uv = _tag(tree.nodes.new("ShaderNodeUVMap"), "UV")
        uv.uv_map = LIGHTMAP_UV
        grp = hook_nodes(tree, frame, (x0, y0), uv, uv.outputs["UV"], image, ng, out, surface, _tag)
        _link_base_color(tree, surface, grp, mat, warnings)
        if direction is not None:
            _add_direction(tree, frame, (x0, y0), uv, grp, surface, {"Direction": direction},
                           direction_group())
        elif l1 is not None:
            _add_direction(tree, frame, (x0, y0), uv, grp, surface, dict(zip(("L1x", "L1y", "L1z"), l1)),
                           l1_group())
        # EEVEE prefers an output whose target is exactly EEVEE over an "All" one, active
        # or not, so ours needs no active flag (setting it would clear the user's).
        theirs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"
                  and n.target == "EEVEE" and not n.get(HOOK_PROP)]
        if theirs:
            warnings.append(f"material '{mat.name}' has its own EEVEE output ('{theirs[0].name}'), "
                            "which EEVEE keeps using: the lightmap hook is not shown there")
        done.append(mat.name)
    return done


def _add_direction(tree, frame, origin, uv, grp, surface, images, group):
    """Directional lightmap: its images (same UVs; group input name -> image) and
    `group` between the lightmap's image and the hook group."""
    dg = _tag(tree.nodes.new("ShaderNodeGroup"), "Direction")
    dg.node_tree = group
    dg.parent, dg.location = frame, (origin[0] - 350, origin[1] - 150)
    for i, (socket, image) in enumerate(images.items()):
        tex = _tag(tree.nodes.new("ShaderNodeTexImage"), socket + " Image")
        tex.image, tex.interpolation, tex.extension = image, "Linear", "EXTEND"
        tex.parent, tex.location = frame, (origin[0] - 500, origin[1] - 300 - 250 * i)
        tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        tree.links.new(tex.outputs["Color"], dg.inputs[socket])
    lightmap = grp.inputs["Lightmap"].links[0].from_socket
    tree.links.new(lightmap, dg.inputs["Lightmap"])
    node = surface.node if surface is not None else None
    normal = _source(node.inputs["Normal"]) if node is not None and "Normal" in node.inputs else None
    if normal is None:
        geo = _tag(tree.nodes.new("ShaderNodeNewGeometry"), "Geometry")
        geo.parent, geo.location = frame, (origin[0] - 700, origin[1] - 300)
        normal = geo.outputs["Normal"]
    tree.links.new(normal, dg.inputs["Normal"])
    tree.links.new(dg.outputs["Lightmap"], grp.inputs["Lightmap"])


def _link_base_color(tree, surface, grp, mat, warnings):
    node = surface.node if surface is not None else None
    key = {"ShaderNodeBsdfPrincipled": "Base Color", "ShaderNodeBsdfDiffuse": "Color"}.get(
        node.bl_idname if node is not None else None)
    if key is None:
        warnings.append(f"material '{mat.name}': no Principled or Diffuse BSDF on the surface; "
                        "the lightmap hook uses a white base colour")
        grp.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        return
    sock = node.inputs[key]
    src = _source(sock)
    if src is not None:
        tree.links.new(src, grp.inputs["Base Color"])
    else:
        grp.inputs["Base Color"].default_value = tuple(sock.default_value)


def remove_lightmap_hook(materials=None):
    """Removes our hook nodes from `materials` (default: all); drops the group when unused. -> nodes removed."""
    import bpy
    mats = bpy.data.materials if materials is None else materials
    removed = sum(remove_hook_nodes(m) for m in mats)
    for ng in list(bpy.data.node_groups):
        if (ng.get(HOOK_PROP) or ng.get(DIRECTION_PROP) or ng.get(L1_PROP)) and ng.library is None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
    return removed


def _ol_tag(node, role, owner):
    node[HOOK_PROP] = role
    node[OL_HOOK_PROP] = owner
    node.name = f"{OL_PREFIX} {role}"
    node.label = node.name
    return node


def ol_group():
    """The shared group: world normal (Geometry node) -> octahedral (s, t, 0), with math nodes."""
    ng, new = _find_or_new_group(OL_HOOK_PROP, OL_GROUP,
                                 "Photon Lightmaps: octahedral coordinates of the world-space normal, "
                                 "for looking up an orientation lightmap image")
    if not new:
        return ng
    ng.interface.new_socket("Vector", in_out="OUTPUT", socket_type="NodeSocketVector")
    n, links = ng.nodes, ng.links
    geo = n.new("ShaderNodeNewGeometry")
    sep = n.new("ShaderNodeSeparateXYZ")
    links.new(geo.outputs["Normal"], sep.inputs[0])
    col = [0]

    def math_node(op, a, b=None, c=None):
        m = n.new("ShaderNodeMath")
        m.operation = op
        col[0] += 1
        m.location = (200 + 180 * (col[0] // 6), -120 * (col[0] % 6))
        for sock, v in zip(m.inputs, (a, b, c)):
            if v is None:
                continue
            if isinstance(v, (int, float)):
                sock.default_value = float(v)
            else:
                links.new(v, sock)
        return m.outputs[0]

    nx, ny, nz = sep.outputs[0], sep.outputs[1], sep.outputs[2]
    ax, ay, az = (math_node("ABSOLUTE", c) for c in (nx, ny, nz))
    l1 = math_node("ADD", math_node("ADD", ax, ay), az)
    x, y = math_node("DIVIDE", nx, l1), math_node("DIVIDE", ny, l1)
    # sgn with sgn(0) = +1 (the engine's fold): 1 - 2 * (v < 0)
    sx = math_node("MULTIPLY_ADD", math_node("LESS_THAN", x, 0.0), -2.0, 1.0)
    sy = math_node("MULTIPLY_ADD", math_node("LESS_THAN", y, 0.0), -2.0, 1.0)
    fx = math_node("MULTIPLY", math_node("SUBTRACT", 1.0, math_node("ABSOLUTE", y)), sx)
    fy = math_node("MULTIPLY", math_node("SUBTRACT", 1.0, math_node("ABSOLUTE", x)), sy)
    low = math_node("LESS_THAN", nz, 0.0)
    X = math_node("MULTIPLY_ADD", low, math_node("SUBTRACT", fx, x), x)
    Y = math_node("MULTIPLY_ADD", low, math_node("SUBTRACT", fy, y), y)
    s = math_node("MULTIPLY_ADD", X, 0.5, 0.5)
    t = math_node("MULTIPLY_ADD", Y, 0.5, 0.5)
    comb = n.new("ShaderNodeCombineXYZ")
    links.new(s, comb.inputs[0])
    links.new(t, comb.inputs[1])
    go = n.new("NodeGroupOutput")
    links.new(comb.outputs[0], go.inputs["Vector"])
    geo.location, sep.location = (-300, 0), (-100, 0)
    comb.location, go.location = (1400, 0), (1600, 0)
    return ng


def remove_ol_nodes(mat, owner=None):
    """Deletes our OL nodes (of OL `owner`, or all) from one material -> how many."""
    tree = mat.node_tree
    if tree is None or mat.library is not None:
        return 0
    ours = [nd for nd in tree.nodes if nd.get(OL_HOOK_PROP) and (owner is None or nd[OL_HOOK_PROP] == owner)]
    for nd in ours:
        tree.nodes.remove(nd)
    return len(ours)


def add_ol_hook(empty, image, objects, warnings=None):
    """Adds (or refreshes) the OL lookup in every material of `objects`; returns the material names."""
    warnings = warnings if warnings is not None else []
    coords = ol_group()
    shade = hook_group()
    covered = {o.name for o in objects}
    mats = []
    for ob in objects:
        slots = [s.material for s in ob.material_slots]
        if not any(slots):
            warnings.append(f"object '{ob.name}' has no material: no orientation lightmap hook added")
        for m in slots:
            if m is not None and m not in mats:
                mats.append(m)
    done = []
    for mat in mats:
        if not _hookable(mat, warnings, "orientation lightmap"):
            continue
        users = sorted(_material_users(mat) - covered)
        if users:
            warnings.append(f"material '{mat.name}' is shared with objects outside orientation lightmap "
                            f"'{empty.name}' ({', '.join(users)}): in EEVEE they show its light too; "
                            "give the covered objects their own material")
        tree = mat.node_tree
        other = [nd for nd in tree.nodes if nd.get(HOOK_PROP) and nd.get(OL_HOOK_PROP) != empty.name]
        if other:
            warnings.append(f"material '{mat.name}': its earlier Photon Lightmap hook was replaced by "
                            f"orientation lightmap '{empty.name}' (one material shows one baked light)")
        remove_hook_nodes(mat)
        out, surface, (x0, y0) = _hook_frame_origin(tree)
        frame = _ol_tag(tree.nodes.new("NodeFrame"), "Frame", empty.name)
        frame.label = (f"Orientation lightmap '{empty.name}' (baked light by normal, EEVEE only; "
                       "removed with Remove Orientation Lightmap)")
        grp_c = _ol_tag(tree.nodes.new("ShaderNodeGroup"), "Coordinates", empty.name)
        grp_c.node_tree = coords
        grp = hook_nodes(tree, frame, (x0, y0), grp_c, grp_c.outputs["Vector"], image, shade, out,
                           surface, lambda nd, role: _ol_tag(nd, role, empty.name))
        _link_base_color(tree, surface, grp, mat, warnings)
        done.append(mat.name)
    return done


def remove_ol_hook(owner=None, materials=None):
    """Removes OL hook nodes (of OL `owner`, or all) from `materials` (default: all);
    drops our node groups when nothing uses them. -> nodes removed."""
    import bpy
    mats = bpy.data.materials if materials is None else materials
    removed = sum(remove_ol_nodes(m, owner) for m in mats)
    for ng in list(bpy.data.node_groups):
        if ng.get(OL_HOOK_PROP) and ng.library is None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
    remove_lightmap_hook([])   # drops the shading group if it is now unused
    return removed
