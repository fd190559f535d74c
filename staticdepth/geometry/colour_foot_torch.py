"""The colour foot (``alignment_vertical.colour_foot``, the end of ``upright_depth``) in torch
operations that export to ONNX, for the upright twin (geometry/alignment_upright_torch.py).

The static image is a constant of a deployment (a fixed camera: the adaptation frames' median), so
everything the rule reads from it is computed once, at construction, by the numpy functions
themselves: the depth each pixel takes on the vertical line through its colour run's foot
(``colour_foot`` on every pixel, the frame's part of its test passed), the foot's row and the pixel
below it (``static_colour_feet``, ``below_feet``), each pixel's colour bin (``colour_codes``,
which ``ground_coloured`` reads) and whether its run goes on to the image's bottom past small
objects (``static_surface``: the lawn test, which the frame's snapped pixels take).
What depends on the frame stays in the graph, elementwise gathers: the traced pixels and their
contact rows, the frame's ground (after the recession and walked rules) below each foot, and
``ground_coloured``'s histogram of the walked ground's bins (a ScatterElements add over the
constant bins, opset >= 16), the share test, the ``foot_pull`` limit against the frame's depth.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from staticdepth.geometry.alignment_upright import (FOOT_DIFF, FOOT_GROUND_SHARE, FOOT_LEVELS,
                                                    FOOT_PULL)
from staticdepth.geometry.alignment_vertical import (below_feet, colour_codes, colour_foot,
                                                    static_colour_feet, static_surface)


def colour_bins(image: np.ndarray) -> tuple[np.ndarray, int]:
    """(H W,) int64 bin per pixel (0..k-1) and k: ``ground_coloured``'s colour bins
    (``colour_codes``), numbered over the colours present."""
    _, label = np.unique(colour_codes(image, FOOT_LEVELS).ravel(), return_inverse=True)
    return label.astype(np.int64).ravel(), int(label.max()) + 1


class ColourFoot(nn.Module):
    """``colour_foot`` on a frame's upright result: (out, moved, traced, contact, ground, walked)
    -> (out, moved), all flat (H W,), with the static ``image`` (H, W, C, 0-1) baked in."""

    def __init__(self, image: np.ndarray, du: np.ndarray, q: np.ndarray, rays: np.ndarray,
                 n: np.ndarray, *, foot_diff: float = FOOT_DIFF, foot_pull: float = FOOT_PULL):
        super().__init__()
        h, w = du.shape
        img = np.asarray(image)
        if img.shape[:2] != (h, w):
            raise ValueError(f"the colour foot's image is {img.shape}, the camera {w}x{h}")
        # every pixel's colour run's foot, walked once
        feet = static_colour_feet(img, du, foot_diff)
        fv = feet // w
        # colour_foot itself on every pixel, with the frame's part of its test passed (all ground,
        # no contact, a zero depth): the depth each pixel takes where its foot stands, > 0 where
        # that is defined (a foot above the bottom row, below the horizon), else left at 0
        d = np.zeros((h, w))
        colour_foot(d, img, q, du, rays, n, np.ones((h, w), bool), np.ones((h, w), bool),
                    np.full((h, w), -1), None, foot_diff, 1.0, feet=feet)
        # colour_foot's lawn test (surface_check, on the frame's snapped pixels): static too
        surface = static_surface(img, du, foot_diff, feet)
        bins, k = colour_bins(img)
        # colour_foot's "the foot below the contact's row": contact < the foot row's first pixel
        self.register_buffer("foot_row0", torch.tensor(fv * w, dtype=torch.int64))
        self.register_buffer("below", torch.tensor(below_feet(feet, du), dtype=torch.int64))
        self.register_buffer("depth", torch.tensor(d.ravel(), dtype=torch.float64))
        self.register_buffer("bins", torch.tensor(bins, dtype=torch.int64))
        self.register_buffer("surface", torch.tensor(surface, dtype=torch.bool))
        self.n_bins, self.foot_pull = k, float(foot_pull)

    def forward(self, out: torch.Tensor, moved: torch.Tensor, traced: torch.Tensor,
                contact: torch.Tensor, ground: torch.Tensor, walked: torch.Tensor,
                snapped: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # ground_coloured(image, ground & walked, FOOT_GROUND_SHARE): the walked ground's bins
        g = (ground & walked).to(torch.float64)
        n_g = g.sum()
        hist = torch.zeros(self.n_bins, dtype=torch.float64).scatter_add(0, self.bins, g)
        common = (torch.index_select(hist, 0, self.bins) >= FOOT_GROUND_SHARE * n_g) & (n_g > 0)
        # colour_foot on the re-anchored pixels with a contact, not of a common ground colour
        ok = moved & traced & ~common & (self.depth > 0) \
            & torch.index_select(ground, 0, self.below) \
            & (contact < self.foot_row0) \
            & (self.depth * self.foot_pull >= out) & ~(snapped & self.surface)
        return torch.where(ok, self.depth, out), moved | ok
