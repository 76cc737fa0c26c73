"""tpsv: image vectorization with real-time thin-plate splines."""

__version__ = "0.1.0"
