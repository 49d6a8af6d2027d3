"""The Blender world -> a constant environment radiance (Background or Emission shader)."""
import numpy as np

from .context import output_priority
from .materials import node_input


def world(ctx, world):
    if world is None:
        return 0.0
    owner = f"world '{world.name}'"
    tree = world.node_tree
    if tree is None:
        return ctx.bands(tuple(world.color))
    outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld"]
    outs.sort(key=output_priority)
    if not outs or not outs[0].inputs["Surface"].is_linked:
        return 0.0
    node = outs[0].inputs["Surface"].links[0].from_node
    if node.bl_idname == "ShaderNodeBackground":
        rgb = np.asarray(node_input(ctx, node.inputs["Color"], "the background colour", owner)[:3])
        return ctx.bands(np.clip(rgb * node_input(ctx, node.inputs["Strength"], "the strength", owner), 0, None))
    if node.bl_idname == "ShaderNodeEmission":
        rgb = np.asarray(node_input(ctx, node.inputs["Color"], "the colour", owner)[:3])
        return ctx.bands(np.clip(rgb * node_input(ctx, node.inputs["Strength"], "the strength", owner), 0, None))
    ctx.report("WARNING", f"{owner}: unsupported world shader ({node.bl_idname}); the world is black")
    return 0.0

