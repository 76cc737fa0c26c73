"""Edits in vector space (paper VII-B..E): pure functions Model -> Model.

``recolor`` (colour editing), ``crossmap`` (structural colour / texture transfer
between regions), ``deform`` (shape manipulation by control points),
``stylize`` (abstraction and strokes; returns an image); ``common`` holds the
helpers they share.
"""
