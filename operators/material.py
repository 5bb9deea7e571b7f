"""The relief's material: the full-resolution photo on the top, a darker, greyer copy on walls and base.

Front corners have UVs in [0, 1]^2; walls and base have ``u = x + 1`` (see cliff_terrain.mesh). The
texture repeats, so ``u > 1`` samples the photo at the same ground position, and a ``U > 1`` test
(Separate XYZ -> Math) drives a Hue/Saturation/Value node that darkens and desaturates it there: the
sides read as soil in a section, not as a stretched copy of the top. Used by the build operator and
the render script.
"""

import bpy
import numpy as np

from .mesh_data import UV_NAME

# Walls and base: the photo's colours at this saturation and brightness.
BACK_SATURATION = 0.35
BACK_VALUE = 0.45


def load_photo(path, *, metadata=None, fallback_rgb=None, name=None):
    """Return ``(image, created)``: the photo as a Blender image, reusing one already loaded.

    Blender reads the file at full resolution. It ignores EXIF orientation, so an oriented photo (or
    one Blender cannot read, or whose size differs from `metadata`) is made from `fallback_rgb`
    (the core's decoded RGB array, rows from the top) and packed into the .blend instead.

    Parameters
    ----------
    path : str
        The photo file.
    metadata : cliff_terrain.image_io.ImageMetadata, optional
        The core's metadata (``width``, ``height``, ``orientation``) to check Blender's reading with.
    fallback_rgb : (rows, cols, 3) uint8 array, optional
        Pixels to use when the file itself cannot serve as the texture.
    name : str, optional
        Name of an image made from `fallback_rgb`.

    Returns
    -------
    image : bpy.types.Image
    created : bool
        True if this call added the image to ``bpy.data.images`` (so a failed build removes it).
    """
    orientation = getattr(metadata, "orientation", 1) or 1
    if orientation == 1:
        n_before = len(bpy.data.images)
        try:
            image = bpy.data.images.load(path, check_existing=True)
        except RuntimeError:
            image = None
        if image is not None:
            created = len(bpy.data.images) > n_before
            expected = None if metadata is None else (metadata.width, metadata.height)
            if expected is None or tuple(image.size) == expected:
                return image, created
            if created:
                bpy.data.images.remove(image)
    if fallback_rgb is None:
        raise RuntimeError(f"Blender cannot use {path!r} as a texture and no decoded pixels were given")
    return image_from_array(name or bpy.path.basename(path), fallback_rgb), True


def image_from_array(name, rgb):
    """A packed Blender image from an RGB uint8 array (rows from the top), by one bulk write."""
    rows, cols = rgb.shape[:2]
    image = bpy.data.images.new(name, width=cols, height=rows, alpha=False)
    try:
        pixels = np.ones((rows, cols, 4), dtype=np.float32)
        # Blender's rows run bottom-up.
        pixels[..., :3] = rgb[::-1] / np.float32(255.0)
        image.pixels.foreach_set(pixels.ravel())
        image.pack()
    except BaseException:
        bpy.data.images.remove(image)
        raise
    return image


def relief_material(name, image, *, uv_name=UV_NAME, interpolation="Linear"):
    """Create the relief material for `image`.

    Parameters
    ----------
    name : str
        Name of the new material.
    image : bpy.types.Image
        The photo, at full resolution.
    uv_name : str, optional
        The UV map with front (u <= 1) and back (u > 1) corners.
    interpolation : str, optional
        Texture interpolation ("Linear", "Closest", "Cubic", "Smart").

    Returns
    -------
    bpy.types.Material
        Principled BSDF over the texture; its Image Texture node is the active node, so
        Workbench's Texture colour mode and texture painting use the photo too.
    """
    material = bpy.data.materials.new(name)
    try:
        if bpy.app.version < (5, 0, 0):
            material.use_nodes = True  # always on (and deprecated) from Blender 5.0
        tree = material.node_tree
        nodes, links = tree.nodes, tree.links
        nodes.clear()
        out = nodes.new("ShaderNodeOutputMaterial")
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = uv_name
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.extension = "REPEAT"
        tex.interpolation = interpolation
        split = nodes.new("ShaderNodeSeparateXYZ")
        is_back = nodes.new("ShaderNodeMath")
        is_back.operation = "GREATER_THAN"
        is_back.inputs[1].default_value = 1.0
        is_back.label = "U > 1: walls and base"
        shade = nodes.new("ShaderNodeHueSaturation")
        shade.label = "Walls and base"
        _input(shade, "Saturation").default_value = BACK_SATURATION
        _input(shade, "Value").default_value = BACK_VALUE
        _input(bsdf, "Roughness").default_value = 0.9

        links.new(uv.outputs["UV"], tex.inputs["Vector"])
        links.new(uv.outputs["UV"], split.inputs["Vector"])
        links.new(split.outputs["X"], is_back.inputs[0])
        links.new(is_back.outputs["Value"], _input(shade, "Fac"))
        links.new(tex.outputs["Color"], _input(shade, "Color"))
        links.new(shade.outputs["Color"], _input(bsdf, "Base Color"))
        links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])

        for node, x, y in ((uv, -1000, 0), (tex, -700, 150), (split, -700, -200), (is_back, -500, -200)):
            node.location = (x, y)
        for node, x, y in ((shade, -250, 100), (bsdf, 0, 100), (out, 300, 100)):
            node.location = (x, y)
        nodes.active = tex
    except BaseException:
        bpy.data.materials.remove(material)
        raise
    return material


def _input(node, identifier):
    """A node input by identifier: display names change between versions ("Fac" -> "Factor" in 5.0)."""
    for socket in node.inputs:
        if socket.identifier == identifier:
            return socket
    raise KeyError(f"{node.bl_idname} has no input {identifier!r}")
