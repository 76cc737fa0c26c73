"""The benchmark behind ``tpsv bench``: ``tables`` measures and prints, ``baseline``
gives the raster baselines (JPEG, bicubic, Lanczos) it compares against."""
