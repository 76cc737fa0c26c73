"""tpsv: image vectorization with real-time thin-plate splines.

The Python API is the command line's library: each ``tpsv`` subcommand is a
thin layer over one of the functions below (``docs/API.md`` has an example).

Reading and writing
    read_image, read_labels   photo / label map file -> array
    load, save                .tpsv file <-> :class:`Model`
    write_image               RGB array -> PNG file
Encoding
    segment                   photo -> label map (automatic segmentation)
    vectorize                 photo (+ label map) -> :class:`VectorizeResult` (``.model``, ``.data``, ``.psnr``)
Rendering
    render                    :class:`Model` -> RGB array at any scale or size
    magnify                   photo -> magnified photo (dense TPS fit)
    export_pdf                :class:`Model` -> PDF bytes (patch-mesh shadings)
Editing (pure functions: model in, new model out)
    recolor, crossmap, move_points, affine, set_grid, stylize

The names are imported on first use, so ``import tpsv`` stays quick and loads
no Warp kernels until something renders.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Public name -> (module, attribute).
_API = {
    "Model": ("tpsv.model", "Model"),
    "read_image": ("tpsv.image", "read_image"),
    "read_labels": ("tpsv.image", "read_labels"),
    "write_image": ("tpsv.image", "write_image"),
    "load": ("tpsv.codec", "load"),
    "save": ("tpsv.codec", "save"),
    "segment": ("tpsv.geometry.segment", "segment_auto"),
    "vectorize": ("tpsv.encode.rate", "encode_quality"),
    "VectorizeResult": ("tpsv.encode.vectorize", "VectorizeResult"),
    "render": ("tpsv.rendering.raster", "render"),
    "magnify": ("tpsv.rendering.magnify", "magnify_raster"),
    "export_pdf": ("tpsv.export", "export_pdf"),
    "recolor": ("tpsv.edit.recolor", "recolor"),
    "crossmap": ("tpsv.edit.crossmap", "crossmap"),
    "move_points": ("tpsv.edit.deform", "move_points"),
    "affine": ("tpsv.edit.deform", "affine"),
    "set_grid": ("tpsv.edit.deform", "set_grid"),
    "stylize": ("tpsv.edit.stylize", "stylize"),
    "TpsvError": ("tpsv.errors", "TpsvError"),
}

__all__ = sorted(_API) + ["__version__"]


def __getattr__(name: str):
    try:
        module, attr = _API[name]
    except KeyError:
        raise AttributeError(f"module 'tpsv' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return __all__
