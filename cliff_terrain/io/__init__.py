"""Reading and writing the field's files: photos, GeoTIFFs, plot polygons, camera models."""
