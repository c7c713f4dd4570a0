"""The haematoxylin channel of both images, for stained tissue in :func:`reglib.match_images`: first try and second.

Serial sections stained differently (H&E against an immunostain) share their nuclei, which both stains colour
with haematoxylin, while the rest of their colours differ (eosin in all of H&E's tissue, a marker in a few cells
of the immunostain): their grey renderings then disagree over most of the tissue, and an answer found on them may
be wrong. Colour deconvolution (Ruifrok and Johnston [1]_, :func:`skimage.color.rgb2hed`) separates the
haematoxylin; matched on that channel alone the two sections look alike.

Where SIFT matches the grey images, the channel is a second try only: on sections whose one side carries little
haematoxylin (an H-DAB stain's marker-rich section) it is poorer than the grey images, so it runs where that first
answer is ``unsupported``, and its answer replaces the first only when it is usable by its own verdict and the
first answer's images (what the first try correlated) rate it over no motion by the margin a usable answer needs
and more clearly than the first answer: colour images that are not stained sections (a fundus photograph) gain
nothing from the channel, and the images they were first judged on keep a wrong second answer out. Where SIFT
finds too little on the grey images, ``features="auto"`` tries SIFT on the channel before the multimodal
features, its answer kept when its own verdict makes it usable (``_pipeline._haematoxylin_first``): H&E against
an immunostain is then answered at a fraction of the multimodal path's cost.

References
----------
.. [1] A. C. Ruifrok, D. A. Johnston, "Quantification of histochemical staining by color deconvolution",
       Analytical and Quantitative Cytology and Histology 23(4), 2001.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from skimage.color import rgb2hed

from ..dense import OverNoMotion
from ._inputs import Images

HAEMATOXYLIN_TOP = 99.5  # percentile of the haematoxylin density scaled to full black: a few saturated nuclei clip


def haematoxylin_image(image: np.ndarray) -> np.ndarray:
    """The haematoxylin density of an (H, W, 3) RGB image as grey uint8, dark where the stain is dense.

    The density scaled so its :data:`HAEMATOXYLIN_TOP` th percentile is black (0) and no stain white (255), as
    a bright-field section looks: the features and the dense stage see it as they see a grey section.
    """
    density = rgb2hed(np.asarray(image)[..., :3])[..., 0]
    top = float(np.percentile(density, HAEMATOXYLIN_TOP))
    scaled = np.clip(density / top, 0.0, 1.0) if top > 0 else np.zeros_like(density)
    return np.rint(255.0 - 255.0 * scaled).astype(np.uint8)


def stain_views(images: Images) -> Images | None:
    """The images with both sides' features seeing their haematoxylin channel, or None when not both are colour
    (grey images, grey ones stored as RGB, or one band picked by ``MatchOptions.band``); the images themselves
    (shapes, masks, factors) are kept."""
    if not (_colour(images.view_a) and _colour(images.view_b)):
        return None
    h_a, h_b = haematoxylin_image(images.view_a), haematoxylin_image(images.view_b)
    return dataclasses.replace(images, view_a=h_a, view_b=h_b, gray_a=h_a, gray_b=h_b)


def _colour(view: np.ndarray) -> bool:
    """Whether the features' view has colour: three bands, not all equal (a grey image stored as RGB has no stain
    to separate)."""
    return view.ndim == 3 and not (np.array_equal(view[..., 0], view[..., 1])
                                   and np.array_equal(view[..., 1], view[..., 2]))


def rated_better(second: OverNoMotion, first: OverNoMotion) -> bool:
    """Whether the first try's images back the second answer: over no motion by the margin a usable answer needs
    (:attr:`~reglib.dense.OverNoMotion.short_of_margin`), and more clearly than the first answer (a larger
    ``z`` and a larger share of wins over its neighbours)."""
    return not second.short_of_margin and second.z > first.z and second.neighbours > first.neighbours
