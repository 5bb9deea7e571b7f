"""numpy mesh arrays -> a Blender mesh, by bulk writes only (no per-vertex Python).

The generic attribute API is the fast route (``position``, ``.corner_vert``, a FLOAT2 corner attribute
for the UVs, then ``Mesh.update``): about 1.7 s for 2.7 M vertices and 10.7 M corners, where
``vertices.foreach_set("co")`` + ``loops.foreach_set`` + ``validate`` takes about 6 s. Most of that
1.7 s is ``update(calc_edges=True)`` deriving the edges; when the core gives them (``edges``,
``corner_edges``: ``.edge_verts`` and ``.corner_edge``) the transfer takes about 0.3 s. The same calls
work on Blender 4.2 and 5.0 (face sizes follow from ``loop_start``; a FLOAT2 corner attribute is a UV
map). Used by the build operator (in steps while the core computes the heights:
:func:`allocate_mesh`, :func:`checked_topology`, :func:`fill_topology`, then
:func:`set_positions`) and the render script.
"""

from typing import NamedTuple

import bpy
import numpy as np
from mathutils import Matrix

UV_NAME = "UVMap"
# A smooth face beside flat ones (a dome's rim beside level soil triangles, MeshArrays.flat_faces):
# Blender 4.2-5.0 shade it with its vertices' normals, the average over all their faces; 5.2 splits
# the normals at the flat faces' edges, which leaves the rims steeper. On caliterra the adaptive
# mesh's lit top view is 37.44 dB on 4.2, 4.5 and 5.0 (the grid: 37.02), but 36.04 on 5.2 (36.52
# with the whole front smooth; the grid 37.05). The vertex normals stored as custom normals on the
# vertices (12 bytes each; flat faces stay flat in Cycles, EEVEE and Workbench) render 37.44 on 5.2.
# From 5.1, the first release on 5.2's Python: where a release does not split them, the stored
# normals are the ones it would use anyway.
KEEP_VERTEX_NORMALS = bpy.app.version >= (5, 1, 0)


def mesh_from_arrays(name, mesh_arrays, *, scale=1.0, uv_name=UV_NAME):
    """Create a new mesh datablock from a :class:`cliff_terrain.mesh.grid.MeshArrays`.

    Parameters
    ----------
    name : str
        Name of the new mesh (Blender adds a suffix if it is taken).
    mesh_arrays : MeshArrays
        Vertices, faces (``face_sizes`` + ``corner_verts``) and per-corner UVs.
    scale : float, optional
        Multiplies every vertex position (the relief's size in Blender units per core unit).
    uv_name : str, optional
        Name of the UV map.

    Returns
    -------
    bpy.types.Mesh
        The new mesh, one UV map (active for display and render), the faces of
        ``mesh_arrays.shaded_flat`` flat-shaded and the others smooth (by default the first
        ``n_front_faces`` smooth, the walls and base flat). Where the front mixes flat and smooth
        faces, the smooth ones shade with their vertices' normals on every Blender version (see
        ``KEEP_VERTEX_NORMALS``). Nothing is left behind if this raises.
    """
    topology = checked_topology(mesh_arrays)
    mesh = topology_mesh(name, topology, uv_name=uv_name)
    try:
        set_positions(mesh, mesh_arrays.vertices, scale=scale)
        front_flat = topology.flat_faces[: topology.n_front_faces]
        if KEEP_VERTEX_NORMALS and front_flat.any() and not front_flat.all():
            keep_vertex_normals(mesh)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


class Topology(NamedTuple):
    """Checked, contiguous arrays of a mesh's faces, edges and UVs (from :func:`checked_topology`)."""

    n_vertices: int
    corner_verts: np.ndarray
    face_offsets: np.ndarray
    uvs: np.ndarray
    n_front_faces: int
    edges: np.ndarray | None
    corner_edges: np.ndarray | None
    flat_faces: np.ndarray

    @property
    def n_corners(self):
        return self.corner_verts.shape[0]

    @property
    def n_faces(self):
        return self.face_offsets.shape[0]

    @property
    def n_edges(self):
        """0 without edges: Blender derives them (``update(calc_edges=True)``)."""
        return 0 if self.edges is None else self.edges.shape[0]


def checked_topology(mesh_arrays):
    """Check the indices of `mesh_arrays` and lay them out for Blender (numpy only, no bpy).

    Blender trusts these indices: a bad one would corrupt memory, not raise. Raises ValueError.
    """
    n_vertices = mesh_arrays.vertices.shape[0]
    corner_verts = np.ascontiguousarray(mesh_arrays.corner_verts, dtype=np.int32)
    face_sizes = np.ascontiguousarray(mesh_arrays.face_sizes, dtype=np.int32)
    uvs = np.ascontiguousarray(mesh_arrays.uvs, dtype=np.float32)
    n_corners, n_faces = corner_verts.shape[0], face_sizes.shape[0]
    if mesh_arrays.vertices.ndim != 2 or mesh_arrays.vertices.shape[1] != 3:
        raise ValueError(f"`vertices` must have shape (n, 3), got {mesh_arrays.vertices.shape}")
    if int(face_sizes.sum()) != n_corners or (n_faces and int(face_sizes.min()) < 3):
        raise ValueError("`face_sizes` must be >= 3 and add up to the number of corners")
    if not _indices_below(corner_verts, n_vertices):
        raise ValueError(f"`corner_verts` must index the {n_vertices} vertices")
    if uvs.shape != (n_corners, 2):
        raise ValueError(f"`uvs` must have shape ({n_corners}, 2), got {uvs.shape}")
    edges, corner_edges = mesh_arrays.edges, mesh_arrays.corner_edges
    if edges is not None and corner_edges is not None:
        edges = np.ascontiguousarray(edges, dtype=np.int32)
        corner_edges = np.ascontiguousarray(corner_edges, dtype=np.int32)
        if edges.shape[1:] != (2,) or corner_edges.shape != (n_corners,):
            raise ValueError("`edges` must have shape (n, 2) and `corner_edges` one entry per corner")
        if not _indices_below(edges, n_vertices):
            raise ValueError(f"`edges` must index the {n_vertices} vertices")
        if not _indices_below(corner_edges, edges.shape[0]):
            raise ValueError(f"`corner_edges` must index the {edges.shape[0]} edges")
    else:
        edges = corner_edges = None
    flat_faces = np.ascontiguousarray(mesh_arrays.shaded_flat, dtype=bool)
    if flat_faces.shape != (n_faces,):
        raise ValueError(f"`flat_faces` must have shape ({n_faces},), got {flat_faces.shape}")
    return Topology(
        n_vertices,
        corner_verts,
        mesh_arrays.face_offsets,
        uvs,
        int(mesh_arrays.n_front_faces),
        edges,
        corner_edges,
        flat_faces,
    )


def allocate_mesh(name, sizes):
    """A new mesh with room for `sizes` vertices, corners, faces and edges, none of them written yet.

    `sizes` has ``n_vertices``, ``n_corners``, ``n_faces`` and ``n_edges`` (a
    :class:`cliff_terrain.mesh.grid.MeshSizes` or a :class:`Topology`). Allocating is most of the cost
    of a big mesh (Blender zeroes the memory), so the build operator does it while the core
    decodes the photo; :func:`fill_topology` writes the faces, edges and UVs.
    """
    mesh = bpy.data.meshes.new(name)
    try:
        mesh.vertices.add(sizes.n_vertices)
        mesh.loops.add(sizes.n_corners)
        mesh.polygons.add(sizes.n_faces)
        mesh.edges.add(sizes.n_edges)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


def fill_topology(mesh, topology, *, uv_name=UV_NAME):
    """Write a :class:`Topology`'s faces, edges and UVs into a mesh from :func:`allocate_mesh`.

    The vertices are placed later by :func:`set_positions`. Raises ValueError if the mesh was
    allocated for other sizes.
    """
    allocated = (len(mesh.vertices), len(mesh.loops), len(mesh.polygons), len(mesh.edges))
    if allocated != (topology.n_vertices, topology.n_corners, topology.n_faces, topology.n_edges):
        raise ValueError(
            f"mesh {mesh.name!r} has room for {allocated} vertices, corners, faces and edges; the "
            f"topology has {(topology.n_vertices, topology.n_corners, topology.n_faces, topology.n_edges)}"
        )
    mesh.attributes[".corner_vert"].data.foreach_set("value", topology.corner_verts)
    mesh.polygons.foreach_set("loop_start", topology.face_offsets)
    if topology.edges is not None:
        # The core knows the grid's edges; deriving them is most of update()'s time.
        mesh.attributes[".edge_verts"].data.foreach_set("value", topology.edges.ravel())
        mesh.attributes[".corner_edge"].data.foreach_set("value", topology.corner_edges)
    uv = mesh.attributes.new(uv_name, "FLOAT2", "CORNER")
    uv.data.foreach_set("vector", topology.uvs.ravel())
    uv_layer = mesh.uv_layers[uv_name]
    mesh.uv_layers.active = uv_layer
    uv_layer.active_render = True
    # Smooth relief, crisp walls and base (a face's flat shading also sharpens its edges).
    sharp = topology.flat_faces
    if sharp.any():
        mesh.attributes.new("sharp_face", "BOOLEAN", "FACE").data.foreach_set("value", sharp)
    if topology.edges is None:
        mesh.update(calc_edges=True)


def topology_mesh(name, topology, *, uv_name=UV_NAME):
    """A new mesh with the faces, edges and UVs of a :class:`Topology`; vertices not placed yet."""
    mesh = allocate_mesh(name, topology)
    try:
        fill_topology(mesh, topology, uv_name=uv_name)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


def _indices_below(indices, n):
    """True if every int32 in `indices` is in [0, n): one pass, as negatives read as uint32 are huge."""
    return indices.size == 0 or int(indices.view(np.uint32).max()) < n


def positions(mesh):
    """`mesh`'s vertex positions as an (n, 3) float32 array (one bulk read of ``position``)."""
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", co)
    return co.reshape(-1, 3)


def set_positions(mesh, vertices, *, scale=1.0):
    """Write (n, 3) `vertices` times `scale` into `mesh`'s positions, then update it."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    if vertices.shape != (len(mesh.vertices), 3):
        raise ValueError(f"`vertices` must have shape ({len(mesh.vertices)}, 3), got {vertices.shape}")
    mesh.attributes["position"].data.foreach_set("vector", vertices.ravel())
    if scale != 1.0:
        # Scaled in Blender's own array: a scaled copy here would be 32 MB of fresh memory at 2.7 M
        # vertices, and the first touch of fresh memory is slow.
        mesh.transform(Matrix.Scale(scale, 4))
    mesh.update()


def keep_vertex_normals(mesh):
    """Shade `mesh`'s smooth faces with its vertices' normals, as Blender 4.2-5.0 do beside flat faces.

    The vertex normals (the average over all of a vertex's faces) become custom normals on the
    vertices, in one bulk write; flat faces stay flat. Call it once the vertices are placed: the
    custom normals do not follow later moves.
    """
    normals = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    # Read before the attribute exists: with custom normals on the vertices, these are the custom ones.
    mesh.vertex_normals.foreach_get("vector", normals)
    mesh.attributes.new("custom_normal", "FLOAT_VECTOR", "POINT").data.foreach_set("vector", normals)
