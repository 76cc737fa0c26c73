"""Localised thin-plate splines on the host (paper IV-D, V-B, VI-B, VI-C).

``grouping`` splits each region's ``(S, T)`` square into sub-patch cells and
packs ``K`` features into every cell's kernel (:class:`KernelSet`);
``duplicates`` merges coincident features the one way everything else agrees
on; ``blend`` defines the partition-of-unity blend weights; ``reference`` is
the float64 numpy TPS that the Warp kernels (``tpsv.gpu.tps``) are pinned
against. The public names of all four are re-exported here.
"""

from .blend import blend_weights, bump
from .duplicates import Duplicates
from .grouping import (
    COLLINEAR_TOL,
    MAX_KERNEL_SIZE,
    MAX_REFINE,
    MIN_CELL_PX,
    KernelSet,
    group_kernels,
    kernel_lambda,
    recolor,
)
from .reference import blend_reference, tps_eval, tps_fit, tps_phi

__all__ = [
    "KernelSet", "group_kernels", "kernel_lambda", "recolor", "Duplicates",
    "blend_weights", "bump", "tps_phi", "tps_fit", "tps_eval", "blend_reference",
    "MAX_KERNEL_SIZE", "MIN_CELL_PX", "MAX_REFINE", "COLLINEAR_TOL",
]
