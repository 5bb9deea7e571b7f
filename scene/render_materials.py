"""Materials and colours of the rendered views (the relief's own material is in ``material``).

* The lit views make the relief's material matte: the photo already holds the real light, and a
  4 % white reflection greys every dark pixel.
* **The flat top view** emits the photo as it is (nearest-texel lookups; with the 1-pixel box
  filter of ``render_settings`` the mean of the samples is the photo averaged over each output
  pixel).
* The mesh view colours each vertex by its height (viridis, the core's one height colour map).
"""

from __future__ import annotations

import bpy
import numpy as np

from .material import empty_node_tree
from .mesh_data import positions

HEIGHT_ATTRIBUTE = "Cliff Terrain Height"


def relief_image(obj):
    """The photo a relief's material shows (its Image Texture node's image), or None."""
    material = obj.active_material
    if material is None or material.node_tree is None:
        return None
    for node in material.node_tree.nodes:
        if node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
            return node.image
    return None


def make_matte(material):
    """Switch off the specular layer of every Principled BSDF of `material` (a photo is already lit)."""
    if material is None or material.node_tree is None:
        return
    for node in material.node_tree.nodes:
        if node.bl_idname == "ShaderNodeBsdfPrincipled":
            for name in ("Specular IOR Level", "Specular"):
                socket = node.inputs.get(name)
                if socket is not None:
                    socket.default_value = 0.0
                    break


def flat_material(image, uv_name="UVMap"):
    """A material that emits the photo as it is: the flat top view (no shading at all)."""
    material = bpy.data.materials.get("Cliff Terrain Flat") or bpy.data.materials.new("Cliff Terrain Flat")
    tree = empty_node_tree(material)
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = uv_name
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.extension = "REPEAT"
    # Nearest texels: the 1-pixel box filter then averages the photo over each output pixel, as
    # an area resize does; bilinear lookups would blur it a little more.
    tex.interpolation = "Closest"
    emit = tree.nodes.new("ShaderNodeEmission")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], emit.inputs["Color"])
    tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    # Not a light: Cycles would otherwise build a light distribution over every triangle of the
    # relief before each render (about 5 s for 1.5 M triangles).
    material.cycles.emission_sampling = "NONE"
    return material


def height_material():
    """A matte material coloured by the height colour attribute (the mesh view rendered by Cycles)."""
    material = bpy.data.materials.get("Cliff Terrain Height") or bpy.data.materials.new(
        "Cliff Terrain Height"
    )
    tree = empty_node_tree(material)
    colour = tree.nodes.new("ShaderNodeVertexColor")
    colour.layer_name = HEIGHT_ATTRIBUTE
    bsdf = tree.nodes.new("ShaderNodeBsdfDiffuse")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(colour.outputs["Color"], bsdf.inputs["Color"])
    tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return material


def add_height_colours(mesh):
    """Colour every vertex of `mesh` by its height (z from 0 to the highest vertex) as a colour attribute.

    Returns the attribute (active for display, so Workbench's Attribute colour mode shows it).
    """
    # Colour By's writer, and so the core's map: the colour bar drawn on mesh.png is this view's legend.
    from .colour_by import set_vertex_colours

    z = positions(mesh)[:, 2]
    top = float(z.max(initial=0.0))
    t = np.clip(z / top, 0.0, 1.0) if top > 0 else np.zeros_like(z)
    return set_vertex_colours(mesh, t, name=HEIGHT_ATTRIBUTE)
