"""The adaptive mesh: a TIN whose vertical error at every pixel centre is bounded, closed into a solid.

The error is measured at every pixel centre, against the height raster, by two independent routes:
cliff_terrain.mesh.tin_sample.tin_error (integer edge functions, vectorised) and, on small rasters, a plain
per-pixel loop written here.
"""

import sys

import numpy as np
import pytest
from conftest import REPO, uav_image

import cliff_terrain.mesh.tin as tin_module
from cliff_terrain import CliffTerrainError, build_relief
from cliff_terrain.mesh.adaptive import adaptive_mesh, choose_mesh
from cliff_terrain.mesh.grid import grid_mesh
from cliff_terrain.mesh.tin import Tin, default_max_error, triangulate
from cliff_terrain.mesh.tin_sample import sample_tin, tin_error
from cliff_terrain.settings import DEFAULT_MAX_ERROR_FLOOR_M, DEFAULT_MAX_ERROR_PIXELS

EX2 = REPO.parent / "shared" / "data" / "dsm" / "fieldimager_ex2"


def _loop_error(heights, tin):
    """Reference: for each pixel centre, the triangles containing it (barycentric coordinates by a
    2x2 solve, tolerance 1e-9) and the largest |interpolated - height| among them."""
    error = np.full(heights.shape, np.nan)
    pts = np.stack([tin.rows, tin.cols], axis=1).astype(np.float64)
    for r in range(heights.shape[0]):
        for c in range(heights.shape[1]):
            for tri in tin.triangles:
                p0, p1, p2 = pts[tri]
                m = np.array([p1 - p0, p2 - p0]).T
                b1, b2 = np.linalg.solve(m, np.array([r, c], float) - p0)
                b0 = 1.0 - b1 - b2
                if min(b0, b1, b2) >= -1e-9:
                    z = b0 * tin.z[tri[0]] + b1 * tin.z[tri[1]] + b2 * tin.z[tri[2]]
                    e = abs(float(z) - float(heights[r, c]))
                    error[r, c] = e if np.isnan(error[r, c]) else max(error[r, c], e)
    return error


def _rough_raster(shape, seed):
    rng = np.random.default_rng(seed)
    rows, cols = np.indices(shape)
    dome = np.clip(8.0 - np.hypot(rows - shape[0] / 2, cols - shape[1] / 3), 0, None)
    return (dome + rng.normal(0, 0.3, shape) * (dome > 0)).astype(np.float32)


def test_the_error_measure_agrees_with_a_per_pixel_loop():
    heights = _rough_raster((17, 23), seed=1)
    tin = triangulate(heights, max_error=0.5)
    assert 4 < len(tin.z) < heights.size  # simplified, not the whole raster
    fast, slow = tin_error(heights, tin), _loop_error(heights, tin)
    assert not np.isnan(slow).any()
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-9)
    assert np.nanmax(fast) <= 0.5


def test_the_error_measure_sees_a_wrong_vertex():
    heights = _rough_raster((17, 23), seed=2)
    tin = triangulate(heights, max_error=0.3)
    z = tin.z.copy()
    k = int(np.argmax(z))
    z[k] += 2.0  # one vertex 2 units too high: its pixel is 2 off
    error = tin_error(heights, tin._replace(z=z))
    assert error[tin.rows[k], tin.cols[k]] == pytest.approx(2.0)
    np.testing.assert_allclose(error, _loop_error(heights, tin._replace(z=z)), atol=1e-9)


def test_a_plane_needs_two_triangles_and_a_flat_raster_has_no_error():
    rows, cols = np.indices((30, 45))
    plane = (0.25 * rows - 0.5 * cols + 3).astype(np.float32)
    tin = triangulate(plane, max_error=1e-3)
    assert len(tin.triangles) == 2 and len(tin.z) == 4
    assert np.nanmax(tin_error(plane, tin)) <= 1e-5
    # The vertices are the corner pixels with their own heights.
    assert sorted(zip(tin.rows.tolist(), tin.cols.tolist(), strict=True)) == [
        (0, 0),
        (0, 44),
        (29, 0),
        (29, 44),
    ]
    np.testing.assert_array_equal(tin.z, plane[tin.rows, tin.cols])


@pytest.mark.parametrize(
    "relative",
    ["broccoli/01_clip_raw_test.jpg", "caliterra/IMG_9370.jpg", "seneca_nir/IMG_0505.jpg"],
)
def test_real_reliefs_stay_within_max_error_at_every_pixel_centre(relative):
    relief = build_relief(uav_image(relative), max_size=600)
    heights = relief.heights
    assert heights.max() > 0
    # The default (half a pixel: these photos have no scale) and a tight bound.
    for max_error in (default_max_error()[0], 0.002 * float(heights.max())):
        tin = triangulate(heights, max_error=max_error)
        error = tin_error(heights, tin)
        assert not np.isnan(error).any(), "every pixel centre is covered"
        assert error.max() <= max_error
        # The bound is used, not met by keeping every pixel: far fewer vertices than pixels.
        assert len(tin.z) < 0.2 * heights.size
        # Vertices keep their pixel's height, but for those added on blocks' borders (at the
        # height of the border edge they split, within the bound).
        moved = tin.z != heights[tin.rows, tin.cols]
        assert moved.mean() < 0.05 and _on_block_borders(tin)[moved].all()
        assert tin.rows.dtype == tin.cols.dtype == tin.triangles.dtype == np.int32


def _block_lines(n):
    """The last line of each block before a cut and the first after it (tin._tile_edges' cuts)."""
    cuts = tin_module._tile_edges(n)[1:-1]
    return np.concatenate([cuts - 1, cuts])


def _on_block_borders(tin):
    return np.isin(tin.rows, _block_lines(tin.shape[0])) | np.isin(tin.cols, _block_lines(tin.shape[1]))


@pytest.mark.parametrize("tile", [16, 5])
def test_blocks_meet_vertex_for_vertex_so_no_strip_triangle_smears_a_plant(tile, monkeypatch):
    """Across a cut between two blocks, each border vertex has a partner at the same position on
    the other side. Zipped between unmatched borders, a strip triangle reached from a plant's rim
    vertex far along the other side, half the plant's height over a long sliver: a dark line along
    the blocks' border in the lit views."""
    monkeypatch.setattr(tin_module, "_TILE", tile)
    heights = _rough_raster((40, 57), seed=4)
    tin = triangulate(heights, max_error=0.05)
    vertices = set(zip(tin.rows.tolist(), tin.cols.tolist(), strict=True))
    blocks_r = np.searchsorted(tin_module._tile_edges(40), tin.rows, side="right")
    blocks_c = np.searchsorted(tin_module._tile_edges(57), tin.cols, side="right")
    block = (blocks_r * 1000 + blocks_c)[tin.triangles]
    joins = tin.triangles[(block != block[:, :1]).any(axis=1)]
    assert len(joins) > 0
    for line, n in ((0, 40), (1, 57)):
        cuts = tin_module._tile_edges(n)[1:-1]
        across = {**{c - 1: c for c in cuts}, **{c: c - 1 for c in cuts}}
        for k in np.unique(joins):
            r, c = int(tin.rows[k]), int(tin.cols[k])
            own = (r, c)[line]
            if own in across:
                partner = (across[own], c) if line == 0 else (r, across[own])
                assert partner in vertices, f"vertex {(r, c)} of a strip has no partner at {partner}"
    # So along the middle of every strip the surface is the mean of its two borders, within the
    # bound (sampled on the half-pixel lattice, where the middle is an odd line); zipped between
    # unmatched borders it was 0.079 off here.
    half = sample_tin(Tin(2 * tin.rows, 2 * tin.cols, tin.z, tin.triangles, (79, 113)))
    for cut in tin_module._tile_edges(40)[1:-1]:
        middle, sides = half[2 * cut - 1, ::2], half[[2 * cut - 2, 2 * cut], ::2]
        assert np.abs(middle - sides.mean(axis=0)).max() <= 0.05
    for cut in tin_module._tile_edges(57)[1:-1]:
        middle, sides = half[::2, 2 * cut - 1], half[::2, [2 * cut - 2, 2 * cut]]
        assert np.abs(middle - sides.mean(axis=1)).max() <= 0.05
    error = tin_error(heights, tin)
    assert not np.isnan(error).any() and error.max() <= 0.05
    assert _on_block_borders(tin)[tin.z != heights[tin.rows, tin.cols]].all()


def _front_at_pixel_centres(mesh):
    """The mesh's front surface at every pixel centre: its triangles on the half-pixel lattice, where
    every vertex (pixel centres and the border's corners) has integer coordinates."""
    rows, cols = mesh.grid_shape
    x, y, z = mesh.vertices.astype(np.float64).T
    width, height = x.max() - x.min(), y.max() - y.min()
    lattice_c = np.rint(2 * x * cols / width).astype(np.int32)
    lattice_r = np.rint(2 * (height - y) * rows / height).astype(np.int32)
    np.testing.assert_allclose(lattice_c, 2 * x * cols / width, atol=1e-3)
    tin = Tin(lattice_r, lattice_c, z, mesh.front_triangles(), (2 * rows + 1, 2 * cols + 1))
    return sample_tin(tin)[1::2, 1::2]


@pytest.mark.parametrize("tile", [None, 16, 5])
@pytest.mark.parametrize("two_sided", [True, False])
def test_the_adaptive_mesh_is_within_max_error_covers_the_image_and_is_watertight(
    two_sided, tile, monkeypatch
):
    """Also with the TIN built in tiles (3 x 4 and 8 x 11 of them) joined by strips."""
    if tile is not None:
        monkeypatch.setattr(tin_module, "_TILE", tile)
    heights = _rough_raster((40, 57), seed=3) * 0.05  # metres
    mesh = adaptive_mesh(heights, max_error=0.01, pixel_size=0.02, two_sided=two_sided, base_depth=0.1)
    surface = _front_at_pixel_centres(mesh)
    assert not np.isnan(surface).any()
    assert np.abs(surface - heights).max() <= 0.01 + 1e-6  # float32 vertices
    front = mesh.front_triangles()
    assert len(front) < (0.5 if tile != 5 else 0.9) * 2 * heights.size
    # Paired into quads: well under a face per triangle.
    assert mesh.n_front_faces < 0.7 * len(front)

    # Front faces point up and cover the image's rectangle exactly once.
    v = mesh.vertices.astype(np.float64)
    normal_z = np.cross(v[front[:, 1]] - v[front[:, 0]], v[front[:, 2]] - v[front[:, 0]])[:, 2]
    assert normal_z.min() > 0
    assert normal_z.sum() / 2 == pytest.approx(40 * 57 * 0.02**2, rel=1e-5)
    assert v[:, 0].min() == 0 and v[:, 0].max() == pytest.approx(57 * 0.02)
    assert v[:, 1].min() == 0 and v[:, 1].max() == pytest.approx(40 * 0.02)
    # Planar front UVs: a top view shows the texture pixel for pixel.
    n_corners = int(mesh.face_sizes[: mesh.n_front_faces].sum())
    front_uv = mesh.uvs[:n_corners]
    front_corners = mesh.corner_verts[:n_corners]
    np.testing.assert_allclose(front_uv, v[front_corners, :2] / [57 * 0.02, 40 * 0.02], atol=1e-6)

    counts = mesh.edge_face_counts()
    if not two_sided:
        assert mesh.n_faces == mesh.n_front_faces and counts.min() == 1
        return
    # A closed, consistently oriented solid: every edge is used once in each direction.
    assert np.all(counts == 2)
    starts = mesh.face_offsets
    nxt = np.arange(1, mesh.corner_verts.size + 1)
    nxt[starts + mesh.face_sizes - 1] = starts
    directed = mesh.corner_verts.astype(np.int64) * mesh.n_vertices + mesh.corner_verts[nxt]
    assert np.unique(directed).size == directed.size
    back = mesh.uvs[n_corners:]
    assert back[:, 0].min() > 1 and back[:, 0].max() <= 2
    base = mesh.vertices[mesh.corner_verts[starts[-1] : starts[-1] + mesh.face_sizes[-1]]]
    np.testing.assert_allclose(base[:, 2], -0.1, rtol=1e-6)
    # Edges and corner edges describe the same faces.
    pairs = np.sort(np.stack([mesh.corner_verts, mesh.corner_verts[nxt]], axis=1), axis=1)
    np.testing.assert_array_equal(np.sort(mesh.edges, axis=1)[mesh.corner_edges], pairs)


def test_level_triangles_and_the_walls_are_flat_shaded_and_the_rest_smooth():
    heights = _rough_raster((40, 57), seed=3)
    for two_sided in (True, False):
        mesh = adaptive_mesh(heights, max_error=0.05, two_sided=two_sided)
        n_front = mesh.n_front_faces
        z = mesh.vertices[mesh.front_triangles(), 2]
        level_triangle = (z.max(axis=1) - z.min(axis=1)) == 0
        # A quad's two triangles are both level or both not.
        face = np.repeat(np.arange(n_front), mesh.face_sizes[:n_front] - 2)
        assert (np.bincount(face, level_triangle) % (mesh.face_sizes[:n_front] - 2) == 0).all()
        level = level_triangle[np.searchsorted(face, np.arange(n_front))]
        np.testing.assert_array_equal(mesh.flat_faces[:n_front], level)
        assert mesh.flat_faces[n_front:].all() and len(mesh.flat_faces) == mesh.n_faces
        assert 0 < level.sum() < n_front


@pytest.mark.parametrize("shape", [(1, 1), (1, 6), (5, 1), (2, 2)])
def test_tiny_rasters_still_close_into_a_solid(shape):
    heights = np.arange(np.prod(shape), dtype=np.float32).reshape(shape)
    mesh = adaptive_mesh(heights, max_error=0.01)
    assert np.all(mesh.edge_face_counts() == 2)
    front = mesh.front_triangles()
    v = mesh.vertices.astype(np.float64)
    area = np.cross(v[front[:, 1]] - v[front[:, 0]], v[front[:, 2]] - v[front[:, 0]])[:, 2].sum() / 2
    assert area == pytest.approx(shape[0] * shape[1])
    surface = _front_at_pixel_centres(mesh)
    np.testing.assert_allclose(surface, heights, atol=0.01)


def test_build_relief_adaptive_has_ten_times_fewer_triangles_within_the_default_error():
    path = uav_image("broccoli/01_clip_raw_test.jpg")
    grid = build_relief(path, max_size=600, mesh="grid")
    adaptive = build_relief(path, max_size=600, mesh="adaptive")
    assert grid.max_error is None and grid.params["mesh"] == "grid" and grid.mesh_kind == "grid"
    assert grid.max_error_rule is None and grid.mesh_rule == "given"
    np.testing.assert_array_equal(adaptive.heights, grid.heights)
    # No scale: half a pixel.
    assert adaptive.max_error == DEFAULT_MAX_ERROR_PIXELS == 0.5
    assert adaptive.max_error_rule.startswith("half a pixel (inflated heights")
    # The grid draws two triangles per pixel; a face is 1 or 2 of them.
    assert 2 * grid.mesh.n_front_faces >= 10 * len(adaptive.mesh.front_triangles())
    assert grid.mesh.n_front_faces >= 10 * adaptive.mesh.n_front_faces
    surface = _front_at_pixel_centres(adaptive.mesh)
    assert np.abs(surface - adaptive.heights).max() <= adaptive.max_error * (1 + 1e-6)
    assert np.all(adaptive.mesh.edge_face_counts() == 2)
    # The grid is unchanged by the option.
    np.testing.assert_array_equal(grid.mesh.vertices, grid_mesh(grid.heights).vertices)


def test_the_default_error_follows_the_source_of_the_heights():
    path = uav_image("broccoli/01_clip_raw_test.jpg")
    relief = build_relief(path, max_size=300, mesh="adaptive", gsd=0.01)
    # A shape prior holds nothing below the photo's resolution: half a processing pixel, in metres.
    assert relief.units == "m" and relief.max_error == pytest.approx(0.5 * relief.pixel_size)
    assert relief.max_error_rule.startswith("half a pixel (inflated heights, ")
    assert default_max_error(units="m", pixel_size=0.02) == (
        0.01,
        "half a pixel (inflated heights, 2 cm pixels)",
    )
    assert default_max_error(height_source="calibrated", units="m", pixel_size=0.021)[0] == pytest.approx(
        0.0105
    )
    assert default_max_error(pixel_size=1.0) == (0.5, "half a pixel (inflated heights, no scale: 0.5 px)")
    # Measured heights: the DSM's noise, at least 1 cm.
    measured = {"height_source": "measured", "units": "m", "pixel_size": 0.05}
    assert default_max_error(**measured, dsm_noise=0.013) == (
        0.013,
        "DSM noise 1.3 cm (robust spread of soil residuals)",
    )
    assert default_max_error(**measured, dsm_noise=0.004)[0] == DEFAULT_MAX_ERROR_FLOOR_M == 0.01
    assert default_max_error(**measured)[1] == "1 cm floor (measured heights)"
    # A value given always wins.
    explicit = build_relief(path, max_size=300, mesh="adaptive", gsd=0.01, max_error=0.05)
    assert explicit.max_error == 0.05 and explicit.max_error_rule == "given"
    assert explicit.mesh.n_faces < relief.mesh.n_faces


def test_measured_heights_default_to_the_dsm_noise():
    from cliff_terrain.measure.canopy import dsm_noise

    relief = build_relief(
        str(EX2 / "odm_orthophoto.tif"),
        max_size=300,
        dsm=str(EX2 / "dsm.tif"),
        height_source="measured",
        mesh="adaptive",
    )
    noise = dsm_noise(relief.canopy, plants=relief.mask)
    soil = ~relief.mask & np.isfinite(relief.canopy.chm)
    residual = (relief.canopy.dsm - relief.canopy.ground)[soil].astype(np.float64)
    assert noise == pytest.approx(1.4826 * np.median(np.abs(residual - np.median(residual))), rel=1e-6)
    assert relief.max_error == pytest.approx(max(0.01, noise))
    assert ("DSM noise" if noise > 0.01 else "1 cm floor") in relief.max_error_rule


def test_auto_chooses_a_mesh_per_build_and_says_which(monkeypatch):
    import cliff_terrain.settings as settings

    assert settings.DEFAULT_MESH == "auto"
    relief = build_relief(uav_image("broccoli/01_clip_raw_test.jpg"), max_size=200)
    assert relief.params["mesh"] == "auto" and relief.mesh_rule.startswith("auto: ")
    assert relief.mesh_kind == choose_mesh("auto", relief.heights.shape)[0]
    assert (relief.max_error is not None) == (relief.mesh_kind == "adaptive")
    assert choose_mesh("grid", (4000, 3000)) == ("grid", "given")
    # The measured rule: the grid below 1.5 MP (the default 1000 px), the adaptive mesh from there.
    assert settings.AUTO_GRID_BELOW_PIXELS == 1_500_000
    assert choose_mesh("auto", (1000, 750)) == (
        "grid",
        "auto: grid (0.75 MP < 1.5 MP, where the grid builds at least as fast)",
    )
    assert choose_mesh("auto", (1500, 1000))[0] == "adaptive"
    monkeypatch.setattr(settings, "AUTO_GRID_BELOW_PIXELS", 2_000_000)
    assert choose_mesh("auto", (1000, 1000))[0] == "grid"
    assert choose_mesh("auto", (2000, 1500))[0] == "adaptive"
    monkeypatch.setattr(settings, "AUTO_GRID_BELOW_PIXELS", None)
    assert choose_mesh("auto", (10, 10))[0] == "adaptive"


@pytest.mark.parametrize("shape", [(60, 90), (300, 500)])
def test_a_flat_relief_is_two_triangles_and_its_frame(shape):
    """Also when it spans several of the TIN's blocks."""
    mesh = adaptive_mesh(np.zeros(shape, np.float32), max_error=0.01, two_sided=False)
    assert len(mesh.front_triangles()) == 2 + 4 * 2 + 4 * 2
    assert mesh.n_faces <= 10  # paired into quads


@pytest.mark.parametrize(
    ("max_error", "match"),
    [
        (0.0, r"`max_error` must be > 0.0, got 0.0"),
        (-1, r"`max_error` must be > 0.0, got -1.0"),
        (float("nan"), r"`max_error` must be finite, got nan"),
        (float("inf"), r"`max_error` must be finite, got inf"),
        ("1", r"`max_error` must be a number, got '1'"),
    ],
)
def test_bad_max_error_is_refused_by_name(max_error, match):
    with pytest.raises(CliffTerrainError, match=match):
        triangulate(np.zeros((4, 4)), max_error=max_error)
    with pytest.raises(CliffTerrainError, match=match):
        build_relief(np.zeros((20, 20, 3), np.uint8), mesh="adaptive", max_error=max_error)


def test_bad_mesh_choice_is_refused_by_name():
    with pytest.raises(
        CliffTerrainError, match=r"`mesh` must be one of 'auto', 'grid', 'adaptive', got 'tin'"
    ):
        build_relief(np.zeros((20, 20, 3), np.uint8), mesh="tin")


def test_non_finite_heights_are_refused():
    heights = np.zeros((5, 5))
    heights[2, 2] = np.nan
    with pytest.raises(CliffTerrainError, match="`heights` must be finite"):
        triangulate(heights, max_error=0.1)


def test_a_missing_pydelatin_is_named_with_how_to_install_it(monkeypatch):
    from cliff_terrain.errors import DependencyError

    monkeypatch.setitem(sys.modules, "pydelatin", None)  # import pydelatin raises ImportError
    with pytest.raises(DependencyError, match=r"the adaptive mesh needs pydelatin.*pip install pydelatin"):
        triangulate(np.zeros((4, 4)), max_error=0.1)
