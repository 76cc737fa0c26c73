"""Geometry: label maps, region outlines and Hermite patches (paper IV-A, IV-B).

``segment`` makes label maps, ``outline`` traces each region as polygons and
decides region membership at any output size, ``patch`` builds the bicubic
Hermite patch of a region with its forward map, Jacobian and inverse,
``regions`` turns a label map into regions (outline + patch) and moves points
between pixel space and each region's patch space.
Everything here is numpy; the Warp twin of the inverse map is ``tpsv.gpu.patchmap``.
"""
