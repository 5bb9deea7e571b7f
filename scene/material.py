"""The relief's material: the full-resolution photo on the top, soil-coloured walls and base.

Front corners have UVs in [0, 1]^2; walls and base have ``u = x + 1`` (see cliff_terrain.mesh.grid). The
texture repeats, so ``u > 1`` samples the photo at the same ground position, and a ``U > 1`` test
(Separate XYZ -> Math) mixes in a soil colour and darkens and desaturates the result there: the
sides read as soil in a section, not as the border pixels stretched down. Used by the build
operator and the render script.
"""

import bpy
import numpy as np

from .mesh_data import UV_NAME

# Walls and base: this much soil colour mixed into the photo, then this saturation and brightness.
SOIL_COLOUR = (0.20, 0.13, 0.08, 1.0)
SOIL_MIX = 0.6
BACK_SATURATION = 0.6
BACK_VALUE = 0.6
# Formats Blender reads as the core does, so the photo is not decoded to check it (see load_photo);
# "MPO" is a JPEG with extra frames (DJI's), whose first frame both read.
LAZY_FORMATS = ("JPEG", "MPO", "PNG")


def load_photo(path, *, metadata=None, fallback_rgb=None, name=None):
    """Return ``(image, created)``: the photo as a Blender image, reusing one already loaded.

    Blender reads the file at full resolution. It ignores EXIF orientation, so an oriented photo (or
    one Blender cannot read, or whose size differs from `metadata`) is made from decoded pixels
    instead - `fallback_rgb` if it is the full-resolution photo, else the core decodes the file
    again at full resolution - and packed into the .blend.

    A JPEG or PNG is left to load when first shown, as Blender loads every image: the core has just
    decoded the same file with the same libraries (libjpeg-turbo, libpng), and checking Blender's
    reading means decoding it now (0.04 s for 8 MP, seconds and gigabytes for 100 MP), which Solid
    shading never needs. Other formats (TIFF above all) are checked now.

    Parameters
    ----------
    path : str
        The photo file.
    metadata : cliff_terrain.io.photo.ImageMetadata, optional
        The core's metadata (``width``, ``height``, ``orientation``) to check Blender's reading with.
    fallback_rgb : (rows, cols, 3) uint8 array, optional
        The core's decoded, oriented pixels (rows from the top), used when at full resolution.
    name : str, optional
        Name of an image made from decoded pixels.

    Returns
    -------
    image : bpy.types.Image
    created : bool
        True if this call added the image to ``bpy.data.images`` (so a failed build removes it).
    """
    orientation = getattr(metadata, "orientation", 1) or 1
    expected = None if metadata is None else (metadata.width, metadata.height)
    if orientation == 1:
        n_before = len(bpy.data.images)
        try:
            image = bpy.data.images.load(path, check_existing=True)
        except RuntimeError:
            image = None
        if image is not None:
            created = len(bpy.data.images) > n_before
            trusted = getattr(metadata, "format", None) in LAZY_FORMATS
            # Blender reads float TIFFs (OpenDroneMap's orthophotos hold 0-255 floats) unscaled.
            # (is_float loads the pixels: asked of TIFFs only, so JPEGs and PNGs stay lazy.)
            unscaled = getattr(metadata, "format", None) == "TIFF" and image.is_float
            if (expected is None or trusted or tuple(image.size) == expected) and not unscaled:
                return image, created
            if created:
                bpy.data.images.remove(image)
    full_size = fallback_rgb is not None and (
        expected is None or (fallback_rgb.shape[1], fallback_rgb.shape[0]) == expected
    )
    if not full_size:
        # Rare (rotated or unusual files): decode again, oriented and at full resolution.
        from ..cliff_terrain.io.photo import load_image

        fallback_rgb, _ = load_image(bpy.path.abspath(path))
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


def relief_material(name, image, *, uv_name=UV_NAME, interpolation="Linear", extension="REPEAT"):
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
    extension : {"REPEAT", "EXTEND"}, optional
        "REPEAT" for a two-sided relief, whose back corners have u = x + 1. "EXTEND" for a
        one-sided tile of a mosaic: its border texels then blend with nothing, where "REPEAT"
        would blend them with the opposite border's and draw a line along every tile border.

    Returns
    -------
    bpy.types.Material
        Principled BSDF over the texture; its Image Texture node is the active node, so
        Workbench's Texture colour mode and texture painting use the photo too.
    """
    material = bpy.data.materials.new(name)
    try:
        tree = empty_node_tree(material)
        nodes, links = tree.nodes, tree.links
        out = nodes.new("ShaderNodeOutputMaterial")
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = uv_name
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.extension = extension
        tex.interpolation = interpolation
        split = nodes.new("ShaderNodeSeparateXYZ")
        is_back = nodes.new("ShaderNodeMath")
        is_back.operation = "GREATER_THAN"
        is_back.inputs[1].default_value = 1.0
        is_back.label = "U > 1: walls and base"
        soil_amount = nodes.new("ShaderNodeMath")
        soil_amount.operation = "MULTIPLY"
        soil_amount.inputs[1].default_value = SOIL_MIX
        soil = nodes.new("ShaderNodeMix")
        soil.data_type = "RGBA"
        soil.label = "Soil on walls and base"
        _input(soil, "B_Color").default_value = SOIL_COLOUR
        shade = nodes.new("ShaderNodeHueSaturation")
        shade.label = "Walls and base"
        _input(shade, "Saturation").default_value = BACK_SATURATION
        _input(shade, "Value").default_value = BACK_VALUE
        _input(bsdf, "Roughness").default_value = 0.9

        links.new(uv.outputs["UV"], tex.inputs["Vector"])
        links.new(uv.outputs["UV"], split.inputs["Vector"])
        links.new(split.outputs["X"], is_back.inputs[0])
        links.new(is_back.outputs["Value"], _input(shade, "Fac"))
        links.new(is_back.outputs["Value"], soil_amount.inputs[0])
        links.new(soil_amount.outputs["Value"], _input(soil, "Factor_Float"))
        links.new(tex.outputs["Color"], _input(soil, "A_Color"))
        links.new(_output(soil, "Result_Color"), _input(shade, "Color"))
        links.new(shade.outputs["Color"], _input(bsdf, "Base Color"))
        links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])

        layout = (
            (uv, -1200, 0),
            (tex, -900, 200),
            (split, -900, -200),
            (is_back, -700, -200),
            (soil_amount, -500, -200),
            (soil, -450, 150),
            (shade, -250, 100),
            (bsdf, 0, 100),
            (out, 300, 100),
        )
        for node, x, y in layout:
            node.location = (x, y)
        nodes.active = tex
    except BaseException:
        bpy.data.materials.remove(material)
        raise
    return material


def empty_node_tree(material):
    """The material's node tree, switched on and emptied, ready for new nodes."""
    if bpy.app.version < (5, 0, 0):
        material.use_nodes = True  # always on (and deprecated) from Blender 5.0
    tree = material.node_tree
    tree.nodes.clear()
    return tree


def _input(node, identifier):
    """A node input by identifier: display names change between versions ("Fac" -> "Factor" in 5.0)."""
    for socket in node.inputs:
        if socket.identifier == identifier:
            return socket
    raise KeyError(f"{node.bl_idname} has no input {identifier!r}")


def _output(node, identifier):
    for socket in node.outputs:
        if socket.identifier == identifier:
            return socket
    raise KeyError(f"{node.bl_idname} has no output {identifier!r}")
