"""Feature extraction and descriptor matching: SIFT for photographs; shape context (2-D and 3-D)
for contours, silhouettes and point sets; edge points of an image.

Modules: :mod:`~reglib.features.sift`, :mod:`~reglib.features.shape_context`,
:mod:`~reglib.features.shape_context_3d`, :mod:`~reglib.features.edges`."""
