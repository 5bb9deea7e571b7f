"""The Import Mosaic operator: a tiled GeoTIFF orthomosaic of any size -> one relief object per tile.

The core reads the mosaic in windows and builds it tile by tile (cliff_terrain.mosaic.tiles); each tile
comes as an adaptive mesh in metres with its own part of the photo as texture (never larger than the
tile, at most 16384 pixels: GPUs' texture limit), joined to its left and top neighbours by a seam, so
no crack opens where a plant crosses a border (cliff_terrain.mosaic.meshes). This operator only
turns each into an object. The tiles are parented to one empty that carries the georeference (EPSG
code and the map coordinates of the mosaic's top-left corner, as custom properties: map coordinates
in metres are too large for Blender's single-precision positions).
"""

from contextlib import ExitStack, closing
from pathlib import Path

import bpy
import numpy as np
from bpy.props import FloatProperty, IntProperty, StringProperty

from ..cliff_terrain.io.raster.crs import crs_record
from ..scene.datablocks import textured_object
from ..scene.material import image_from_array
from ..scene.mesh_data import mesh_from_arrays
from .file_operator import FileOperator
from .progress import Progress
from .reports import cancel_build

GPU_TEXTURE_LIMIT = 16384


class CLIFF_TERRAIN_OT_import_mosaic(FileOperator, bpy.types.Operator):
    """Build the relief of a tiled GeoTIFF orthomosaic as one adaptive-mesh object per tile"""

    bl_idname = "cliff_terrain.import_mosaic"
    bl_label = "Import Mosaic"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Mosaic", description="A tiled GeoTIFF orthomosaic", subtype="FILE_PATH")
    filter_glob: StringProperty(default="*.tif;*.tiff", options={"HIDDEN"})  # the file browser's
    tile: IntProperty(
        name="Tile",
        description="Side of each tile in mosaic pixels (one object and one texture each)",
        min=256,
        max=GPU_TEXTURE_LIMIT,
        default=4096,
    )
    overlap: IntProperty(
        name="Overlap",
        description="Margin read around each tile: plants narrower than this get no seam",
        min=0,
        max=4096,
        default=512,
    )
    max_error: FloatProperty(
        name="Max Error",
        description="Largest vertical error of each tile's mesh in metres (0 = half a mosaic pixel)",
        min=0.0,
        default=0.0,
        precision=4,
        unit="LENGTH",
    )

    def execute(self, context):
        try:
            from ..cliff_terrain import CliffTerrainError
            from ..cliff_terrain.io.raster.mosaic import MosaicReader
            from ..cliff_terrain.mosaic.meshes import mosaic_max_error, tile_meshes
        except ImportError as exc:
            self.report({"ERROR"}, f"Cliff Terrain cannot load its libraries: {exc}")
            return {"CANCELLED"}
        path = bpy.path.abspath(self.filepath)
        created = []
        try:
            with ExitStack() as stack:
                reader = stack.enter_context(MosaicReader(path))
                gsd = reader.gsd
                if gsd is None:
                    raise CliffTerrainError(f"mosaic {path!r} has no georeference: its pixel size is unknown")
                max_error, rule = mosaic_max_error(gsd, self.max_error if self.max_error > 0 else None)
                tiles = stack.enter_context(
                    closing(
                        tile_meshes(
                            reader, max_error=max_error, pixel_size=gsd, tile=self.tile, overlap=self.overlap
                        )
                    )
                )  # closed before the reader: the tile computed ahead ends while the file is open
                rows = reader.shape[0]
                name = Path(path).stem or "mosaic"
                root = bpy.data.objects.new(name, None)
                created.append(root)
                context.collection.objects.link(root)
                root["cliff_terrain_mosaic"] = {
                    "source": path,
                    "crs": crs_record(reader.crs),  # EPSG code or a user-defined CRS's WKT
                    # Map (x, y) of the mosaic's top-left corner, and the 3x3 pixel -> map transform.
                    "origin": [float(reader.transform[0, 2]), float(reader.transform[1, 2])],
                    "transform": [float(v) for v in np.asarray(reader.transform).ravel()],
                    "gsd": gsd,
                    "shape": list(reader.shape),
                    "max_error": max_error,
                    "max_error_rule": rule,
                }
                count = -(-reader.shape[0] // self.tile) * -(-reader.shape[1] // self.tile)
                progress = stack.enter_context(Progress(context))
                for k, tile in enumerate(tiles):
                    progress(k / count, f"tile {k + 1} of {count}")
                    r0, r1, c0, c1 = tile.core
                    part = f"{name}_{k:04d}"
                    data = mesh_from_arrays(part, tile.mesh)
                    created.append(data)
                    image = image_from_array(part, tile.rgb)
                    created.append(image)
                    obj = textured_object(
                        part, data, image, context.collection, created=created, extension="EXTEND"
                    )
                    obj.parent = root
                    # The tile's bottom-left corner, y up from the mosaic's last row, in metres.
                    obj.location = (c0 * gsd, (rows - r1) * gsd, 0.0)
                    obj["cliff_terrain_tile"] = {
                        "core": [r0, r1, c0, c1],
                        "triangles": len(tile.mesh.front_triangles()),
                    }
        except Exception as exc:
            return cancel_build(self, exc, created)
        for other in context.view_layer.objects.selected:
            other.select_set(False)
        root.select_set(True)
        context.view_layer.objects.active = root
        self.report(
            {"INFO"}, f"Imported {name}: {len(root.children)} tiles, max error {max_error:.3g} m ({rule})"
        )
        return {"FINISHED"}


CLASSES = (CLIFF_TERRAIN_OT_import_mosaic,)

register, unregister = bpy.utils.register_classes_factory(CLASSES)
