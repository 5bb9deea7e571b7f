"""``--indices``, ``--bands`` and ``--band-files``: the vegetation index options shared by the commands."""

from __future__ import annotations

from pathlib import Path


def add_index_arguments(parser, *, band_files=True):
    """Add ``--indices``, ``--bands`` and (with `band_files`) ``--band-files`` to a command's parser."""
    parser.add_argument(
        "--indices",
        default=None,
        help="vegetation indices to add per plant and plot, e.g. NDVI,NDRE "
        "(ExG, NGRDI, VARI, GLI, NDVI, NDRE, GNDVI, OSAVI)",
    )
    parser.add_argument(
        "--bands",
        default=None,
        help="the orthophoto's band names in order when the file does not name them, e.g. B,G,R,RE,NIR",
    )
    if not band_files:
        return
    parser.add_argument(
        "--band-files",
        type=Path,
        nargs="+",
        default=None,
        help="one single-band GeoTIFF per band on the orthophoto's grid, read for the indices instead "
        "of the orthophoto (band names from the file names or --bands)",
    )


def requested_bands(args, ortho):
    """The bands the indices are computed from (read and checked before any work), or None.

    Raises :class:`~cliff_terrain.errors.MissingBandError` (exit 2, one line) when an index needs a
    band the file lacks.
    """
    from ..io.raster.bands import read_bands
    from ..photo_heights.indices import check_indices, parse_indices

    names = parse_indices(getattr(args, "indices", None))
    if not names:
        return None
    bands = read_bands(args.band_files or ortho, names=args.bands)
    check_indices(bands, names)
    return bands


def relief_index_maps(args, bands, shape):
    """{index: map} on a relief grid of `shape` for the requested indices (empty without)."""
    from ..photo_heights.indices import index_maps, parse_indices

    if bands is None:
        return {}
    return index_maps(bands, parse_indices(args.indices), shape=shape)
