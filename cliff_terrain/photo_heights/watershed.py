"""The watershed that splits touching plants: markers at the distance map's peaks, a landscape of
distance and colour edges, each component flooded alone, on threads, by scikit-image's kernel.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from .._threads import MAX_THREADS, map_row_bands, usable_cores
from .disk_max import disk_maximum
from .labels import distance_map, label4, label_max


def _load_flood_kernel():
    """scikit-image's compiled flooding kernel, ``watershed_raveled``; None if it has moved.

    Loaded from its file, without running ``skimage.segmentation``'s ``__init__``: that imports
    every segmentation method, and through the active contours SciPy's ``optimize`` and
    ``interpolate``, which cost a fresh Blender's first Build 0.25 s. The kernel is a compiled
    module that imports nothing of its package. If it is not where scikit-image keeps it, the
    usual import is tried, then the public function (see :func:`_flood_kernel`).
    """
    name = "skimage.segmentation._watershed_cy"
    module = sys.modules.get(name)
    if module is None:
        try:
            package = importlib.util.find_spec("skimage")
            folder = os.path.join(package.submodule_search_locations[0], "segmentation")
            loader = (importlib.machinery.ExtensionFileLoader, importlib.machinery.EXTENSION_SUFFIXES)
            spec = importlib.machinery.FileFinder(folder, loader).find_spec(name)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        except (ImportError, AttributeError, TypeError, OSError):
            try:
                module = importlib.import_module(name)
            except ImportError:  # pragma: no cover
                return None
    return getattr(module, "watershed_raveled", None)


_watershed_raveled = _load_flood_kernel()


def colour_edges(filtered):
    """Colour-edge strength of the quaternion filter's output: its distance from the grey axis.

    A uniform colour maps to grey and so does a pure brightness edge; only chroma changes leave
    the grey axis, which is what separates touching plants of slightly different colour.

    Parameters
    ----------
    filtered : (rows, cols, 3) float array

    Returns
    -------
    (rows, cols) float32 array
    """
    filtered = np.ascontiguousarray(filtered, dtype=np.float32)
    rows, cols = filtered.shape[:2]
    out = np.empty((rows, cols), dtype=np.float32)
    to_chroma = (np.eye(3) - 1.0 / 3.0).astype(np.float32)
    summed = np.ones((1, 3), np.float32)

    def band(r0, r1):
        # The chroma vector (I - J) p with J the projection on the grey axis, then its length; in
        # bands of rows that stay in the cache (a 26 MP mosaic window: 0.25 -> 0.09 s).
        chroma = cv2.transform(filtered[r0:r1], to_chroma)
        np.multiply(chroma, chroma, out=chroma)
        length = cv2.transform(chroma, summed)
        np.sqrt(length, out=out[r0:r1])

    map_row_bands(band, rows, max(1, _EDGE_BAND_PIXELS // max(1, cols)))
    return out


# colour_edges works in bands of about this many pixels.
_EDGE_BAND_PIXELS = 131_072


def default_edge_scale(dmax, edges, mask):
    """The colour edges' weight in the watershed's landscape: half the regions' 90th percentile of
    their largest distance over the edge strength's 99th percentile on the mask (from every 7th
    pixel), so that the strongest edges weigh about half a typical region's depth.

    `dmax`: each region's largest distance (pixels); `edges`: :func:`colour_edges`; `mask`: the
    plant mask. One rule for one photo (:func:`split_regions`) and a whole mosaic's overview
    (:func:`cliff_terrain.mosaic.tiles.mosaic_settings`).
    """
    sample = np.asarray(edges).ravel()[::7][np.asarray(mask, dtype=bool).ravel()[::7]]
    return 0.5 * float(np.percentile(dmax, 90)) / (float(np.percentile(sample, 99)) + 1e-6)


def split_regions(mask, distance, *, edges=None, radius=None, edge_scale=None, return_distance=False):
    """Label `mask`, splitting touching blobs by a marker-controlled watershed of the distance map.

    Parameters
    ----------
    mask : (rows, cols) bool array
    distance : (rows, cols) float array
        Distance map of `mask` (``distance_map(mask)``).
    edges : (rows, cols) float array, optional
        Colour-edge strength added to the watershed landscape (scaled to the distance range).
    radius, edge_scale : float, optional
        The markers' neighbourhood radius and the edges' scale; by default from this image's
        regions and edges. Tiles of one mosaic share the whole mosaic's (cliff_terrain.mosaic.tiles).
    return_distance : bool, optional
        Also return ``distance_map(labels)``, computed with the flood, component by component
        (the same values to a float32 rounding; see :func:`_split_distance`).

    Returns
    -------
    labels : (rows, cols) int32 array
        Labels 1..n, 0 on flat ground.
    region_distance : (rows, cols) float32 array
        Only with `return_distance`: each region pixel's distance to the nearest pixel outside its
        region. `distance` itself where no region was split.
    """
    mask = np.asarray(mask, dtype=bool)
    components, n, stats = label4(mask, stats=True)  # with each component's bounding box and area
    if n == 0:
        return (components, distance) if return_distance else components
    dmax = label_max(distance, components)[1:]
    # Markers: pixels within a pixel of the largest distance around them (a grey dilation over
    # about a typical region's radius), so a necked blob splits at the neck while the flat ridge
    # of one long plant stays one marker. Much cheaper than h-maxima by reconstruction.
    smooth = cv2.GaussianBlur(distance.astype(np.float32), (0, 0), 1.0)
    radius = int(np.clip(np.median(dmax) if radius is None else radius, 3, 200))
    local_max = disk_maximum(smooth, radius)
    peaks = mask & (smooth >= local_max - 1.0) & (smooth >= 1.0)
    markers, n_markers = label4(peaks)
    if n_markers <= n:  # nothing to split
        return (components, distance) if return_distance else components
    # Only components holding two or more markers need a watershed (each flooded alone, see
    # _flood_components); the rest keep their component.
    marker_component = np.zeros(n_markers + 1, dtype=np.int64)
    marker_component[markers[peaks]] = components[peaks]  # every marker lies in one component
    split = np.bincount(marker_component[1:], minlength=n + 1) > 1
    split[0] = False
    if edges is not None:
        e = np.asarray(edges, dtype=np.float32)
        if edge_scale is None:
            edge_scale = default_edge_scale(dmax, e, mask)
        landscape = np.multiply(e, np.float32(edge_scale))
        landscape -= smooth
    else:
        landscape = np.negative(smooth)
    # Number the result 1..n without gaps: the components left whole first, in their order, then
    # the watershed's basins in marker order (each basin holds at least its marker).
    whole = ~split
    whole[0] = False
    component_label = np.zeros(n + 1, dtype=np.int32)
    component_label[whole] = np.arange(1, int(whole.sum()) + 1, dtype=np.int32)
    basin = split[marker_component]
    basin[0] = False
    basin_label = np.zeros(n_markers + 1, dtype=np.int32)
    basin_label[basin] = np.arange(1, int(basin.sum()) + 1, dtype=np.int32) + int(whole.sum())
    labels = component_label[components]  # 0 on the components to flood
    # With flat ground, each split component's distances come with its flood (_split_distance);
    # without, distance_map measures to the frame, which only a whole-image map knows.
    region_distance = None
    if return_distance and not mask.all():
        region_distance = np.array(distance, dtype=np.float32)
    labels = _flood_components(
        landscape,
        markers,
        components,
        split,
        stats,
        into=labels,
        relabel=basin_label,
        distance=None if region_distance is None else (distance, region_distance),
    )
    if not return_distance:
        return labels
    return labels, distance_map(labels) if region_distance is None else region_distance


# Components are flooded one at a time, each on its bounding box, on up to _FLOOD_THREADS threads
# (the kernel and numpy's copies release the GIL); with fewer than _POOL_PIXELS pixels to flood in
# all, in the calling thread, where a pool would cost more than it saves.
_FLOOD_THREADS = min(usable_cores(), MAX_THREADS)
_POOL_PIXELS = 50_000


def _flood_components(
    landscape, markers, components, flooded, stats, *, into=None, relabel=None, distance=None
):
    """``_flood(landscape, markers, flooded[components])``, one component at a time, in parallel.

    The watershed floods each connected component of its mask from that component's own markers,
    and the kernel's queue orders pixels by (level, order of entry), so a component floods the same
    whether or not others are flooded in the same call - but for one case: the markers all enter
    first, in a tie, and where two marker pixels of one component have the same level the queue
    (a heap) breaks the tie by its layout, which depends on every marker in the call. Flooding
    each component alone, on its bounding box, makes its labels exactly scikit-image's watershed
    of it (tested, plateaus included), whatever the machine's number of cores or the other
    components. It is also the fastest way: the kernel's heap holds one component's front, not
    the whole image's (12 MP: one call 3.1 s; four groups of components on two threads 1.1 s; one
    component at a time 0.6 s, the same labels on the 12 shared photos at full size).

    `flooded` marks the component labels to flood (index 0, the ground, False); `stats` is
    ``cv2.connectedComponentsWithStats``'s for `components`. Each flooded pixel's basin (its
    marker's label, or ``relabel[label]``) is written into `into` (by default a new array of
    zeros), which is returned; `into`'s other pixels are left as they are. With `distance`, a pair
    ``(mask_distance, out)``, each flooded component's pixels of `out` get their distance to the
    nearest pixel outside their basin (:func:`_split_distance`).
    """
    if into is None:
        into = np.zeros(components.shape, dtype=np.int32)
    labels = np.flatnonzero(flooded)
    area = stats[labels, cv2.CC_STAT_AREA]
    labels = labels[np.argsort(-area, kind="stable")]  # the largest first: the threads end together

    def flood_one(label):
        left, top, width, height = (int(v) for v in stats[label, :4])
        box = (slice(top, top + height), slice(left, left + width))
        basins = _flood(landscape[box], markers[box], components[box] == label)
        # Other components may share the box: write only this one's pixels.
        inside = basins > 0
        np.copyto(into[box], basins if relabel is None else relabel[basins], where=inside)
        if distance is not None:
            np.copyto(distance[1][box], _split_distance(basins, distance[0][box]), where=inside)

    if int(area.sum()) < _POOL_PIXELS or _FLOOD_THREADS < 2:
        for label in labels:
            flood_one(label)
    else:
        with ThreadPoolExecutor(_FLOOD_THREADS, thread_name_prefix="cliff_terrain_flood") as pool:
            list(pool.map(flood_one, labels))
    return into


def _split_distance(basins, mask_distance):
    """``distance_map`` of one component's `basins` (on its bounding box), given its mask's.

    Exact, though the box is a crop. Take a pixel p of the component at distance d0 from flat
    ground (`mask_distance`). Every pixel closer to p than d0 is a mask pixel, and this open disc
    is 4-connected, so all of them lie in p's own component. The nearest pixel outside p's region
    is therefore either flat ground, at d0, or a pixel of a line the watershed drew in this
    component, which lies in the box. The box's transform counts the other components' pixels
    as outside too, but they are at least d0 away, and it cannot see ground beyond the box, which
    d0 does. So the smaller of the two is the whole image's map: the same distances, to the one
    float32 rounding by which OpenCV's transform itself varies with its buffers' alignment (tested
    on real photos and on blobs that touch at corners and at the frame).
    """
    return np.minimum(distance_map(basins), mask_distance)


def _flood(landscape, markers, mask):
    """``skimage.segmentation.watershed(landscape, markers, mask=mask)``, 4-connected.

    The same preparation and the same flooding kernel as scikit-image's (:func:`_flood_kernel`).
    """
    run, output = _flood_kernel(landscape, markers, mask)
    run()
    return output


def _flood_kernel(landscape, markers, mask):
    """scikit-image's watershed prepared: ``(run, output)``, where ``run()`` floods `output`.

    As scikit-image's wrapper: float64 image, int8 mask and int32 markers (inside the mask), padded
    by a pixel of zeros so that the kernel never steps past the border. Falls back to the public
    function (preparation included in ``run``) if scikit-image's internals move.
    """
    if _watershed_raveled is None:
        output = np.zeros(mask.shape, dtype=np.int32)

        def run_public():
            from skimage import segmentation

            output[...] = segmentation.watershed(landscape, markers, mask=mask)

        return run_public, output
    rows, cols = mask.shape
    image = np.zeros((rows + 2, cols + 2), dtype=np.float64)
    image[1:-1, 1:-1] = landscape
    flat_mask = np.zeros((rows + 2, cols + 2), dtype=np.int8)
    flat_mask[1:-1, 1:-1] = mask
    flat_mask = flat_mask.ravel()
    output = np.zeros((rows + 2, cols + 2), dtype=np.int32)
    np.multiply(markers, mask, out=output[1:-1, 1:-1], casting="unsafe")
    neighbours = _neighbour_offsets(image.shape)
    marker_locations = np.flatnonzero(output != 0)
    strides = np.array(image.strides, dtype=np.intp) // image.itemsize

    def run():
        _watershed_raveled(
            image.ravel(), marker_locations, neighbours, flat_mask, strides, 0.0, output.ravel(), False
        )

    return run, output[1:-1, 1:-1]


def _neighbour_offsets(shape):
    """The 4 neighbours' offsets in a raveled C-order image of `shape`, in the order scikit-image's
    watershed visits them (``skimage.morphology._util._offsets_to_raveled_neighbors`` with
    connectivity 1, tested equal): the order decides ties. Not imported, because
    ``skimage.morphology`` imports SciPy's ``ndimage`` (0.15 s of a fresh Blender's first Build).
    """
    cols = shape[1]
    return np.array([-cols, -1, 1, cols], dtype=np.intp)
