"""The output sizes the renderer takes and the memory it plans for (``tpsv.rendering.raster`` uses them;
the command line's options check against them without importing the renderer)."""

#: Largest output side, in pixels.
MAX_SIDE = 16384
#: Largest output, in pixels.
MAX_PIXELS = 1 << 28
#: Peak memory (bytes) a render stays under whatever the output size (measured
#: in ``tests/test_tiles.py``; the uncovered-pixel record gets a quarter of it).
MEMORY_BUDGET = 1 << 30
#: :func:`~tpsv.rendering.raster.render` draws outputs of at most this many pixels in one piece
#: (3840 x 2160 fits; about 45 bytes a pixel, host and device together), larger ones band by band.
ONE_PIECE_PIXELS = 1 << 23
#: Pixels per band of a banded render (:func:`~tpsv.rendering.raster.render_bands`,
#: :func:`~tpsv.rendering.raster.render_png`).
TILE_PIXELS = 1 << 22
#: Largest output :func:`~tpsv.rendering.raster.render` returns as one float32 array (12 bytes a pixel).
MAX_ARRAY_PIXELS = 1 << 25
