"""Rendering: Model -> pixels at any size (paper V, VII-A).

``pixelmap`` builds the region and ``(S, T)`` of every output pixel (region
membership from vector outlines in drawing order, inverse patch map) for the
renderer and the encoder alike; ``raster`` is the render path (pixel map,
grouping, Warp solve and rasterise), ``live`` re-renders after an
edit solving only the kernels that changed, ``magnify`` fits a dense model to a
raster for magnification, ``preview`` draws patches and features over a photo.
"""
