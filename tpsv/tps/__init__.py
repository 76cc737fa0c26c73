"""Localised thin-plate splines on the host: grouping, packing, blend, numpy reference.

``group`` splits each region's (S, T) square into sub-patches, gives each
kernel the same number of features (packing) and defines the partition-of-unity
blend; it also holds the numpy TPS that the Warp kernels (``tpsv.gpu.tps``)
are pinned against in the tests.
"""
