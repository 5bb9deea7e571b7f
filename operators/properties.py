"""Settings of a relief build, stored once per scene as ``bpy.types.Scene.cliff_terrain``.

The build parameters are declared once (:class:`ReliefParameters`) and shared by the scene settings
and the build operator, so the panel, scripts and the Adjust Last Operation panel agree.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

# Identifiers match the core's choices (cliff_terrain.segmentation.METHODS, heights.PROFILES).
SEGMENTATIONS = (
    (
        "vegetation",
        "Vegetation",
        "Plants found by a vegetation index (also false-colour NIR photos), split into single plants",
    ),
    (
        "paper",
        "Paper (Otsu)",
        "The paper's method: Otsu threshold of the quaternion-filtered photo (bright objects rise)",
    ),
)
PROFILES = (
    ("circular", "Circular", "Each region rises as a dome with a circular cross-section"),
    ("poisson", "Poisson", "Each region rises as a smooth membrane (a solution of Poisson's equation)"),
)

# Names of the parameters passed to the core's build_relief (besides the image path).
PARAMETER_NAMES = ("segmentation", "profile", "max_size", "exaggeration", "gsd", "two_sided")


class ReliefParameters:
    """The parameters of one relief build (a mixin: Blender collects annotations from bases)."""

    filepath: StringProperty(
        name="Photo",
        description="UAV photo to turn into a relief (JPEG, PNG or TIFF)",
        subtype="FILE_PATH",
    )
    segmentation: EnumProperty(
        name="Segmentation",
        description="How the regions that rise are found",
        items=SEGMENTATIONS,
        default="vegetation",
    )
    profile: EnumProperty(
        name="Profile",
        description="Shape of each raised region",
        items=PROFILES,
        default="circular",
    )
    max_size: IntProperty(
        name="Max Size",
        description="Longest side of the processing grid in pixels (the mesh has about max size squared "
        "vertices; the texture always uses the full-resolution photo)",
        min=16,
        max=8000,
        default=1000,
    )
    exaggeration: FloatProperty(
        name="Exaggeration",
        description="Multiplies every height",
        min=0.01,
        soft_max=10.0,
        default=1.0,
    )
    gsd: FloatProperty(
        name="GSD (m/px)",
        description="Ground sampling distance of the original photo in metres per pixel. 0 = unknown: "
        "taken from the GeoTIFF or DJI metadata when present, otherwise the relief is built in "
        "normalised units (longest side 10 Blender units)",
        min=0.0,
        soft_max=1.0,
        default=0.0,
        precision=4,
        step=0.1,
    )
    two_sided: BoolProperty(
        name="Closed Solid",
        description="Close the relief with side walls and a flat base (textured darker), so it "
        "can be viewed from any side or printed",
        default=True,
    )

    def core_kwargs(self):
        """Keyword arguments for ``cliff_terrain.pipeline.build_relief`` (GSD 0 means unknown)."""
        kwargs = {name: getattr(self, name) for name in PARAMETER_NAMES}
        kwargs["gsd"] = kwargs["gsd"] if kwargs["gsd"] > 0.0 else None
        return kwargs


class CliffTerrainSettings(ReliefParameters, bpy.types.PropertyGroup):
    """Cliff Terrain settings of a scene: build parameters, render folder and the last evaluation."""

    output_dir: StringProperty(
        name="Output Folder",
        description="Folder for rendered views and figures",
        subtype="DIR_PATH",
        default="//cliff_terrain_renders/",
    )
    # Results of the last Evaluate (shown in the panel, written by the evaluate operator).
    psnr: FloatProperty(name="PSNR (dB)", description="PSNR of the top view against the photo", default=0.0)
    ssim: FloatProperty(name="SSIM", description="SSIM of the top view against the photo", default=0.0)


CLASSES = (CliffTerrainSettings,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.cliff_terrain = PointerProperty(type=CliffTerrainSettings)


def unregister():
    del bpy.types.Scene.cliff_terrain
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
