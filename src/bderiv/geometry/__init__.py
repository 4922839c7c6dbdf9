"""Geometry of corners and pieces: the corner models (:mod:`~bderiv.geometry.corners`:
the protocol and the built-in models) and a B-derivative as a piecewise-linear
homeomorphism (:mod:`~bderiv.geometry.triangulation`, its save and load in
``_triangulation_files``, the file formats in ``_triangulation_io``, its arrays checked in
``_triangulation_fields``)."""
