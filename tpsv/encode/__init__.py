"""Encoding: image (+ label map) -> Model (paper IV-C, VI-A).

``features`` places colour features (curvilinear pairs, gradation samples),
``search`` chooses their thresholds (the paper's Monte Carlo search), ``fit``
solves the feature colours by least squares against the image, and
``vectorize`` runs the pipeline as named stages.
"""
