"""Rendering: Model -> pixels at any size (paper V, VII-A).

``raster`` is the render path (region membership from vector outlines, inverse
patch map, grouping, Warp solve and rasterise), ``live`` re-renders after an
edit solving only the kernels that changed, ``magnify`` fits a dense model to a
raster for magnification, ``preview`` draws patches and features over a photo.
"""
