"""Headless numpy drawing of the pendulum (the picture gymnasium draws with pygame, without pygame).

White background, a red capsule-shaped rod of length 1 and width 0.2 from the pivot to the tip, a
black pivot dot, upright (theta = 0) pointing up, as gymnasium draws it; the view spans
[-1.25, 1.25] in both directions (gymnasium's spans [-2.2, 2.2]; ours fills small frames better). Edges are anti-aliased by pixel coverage, all in float64 and
rounded once, so a frame depends only on (theta, height, width): bit-identical everywhere.
"""

from __future__ import annotations

import numpy as np

BOUND = 1.25  # half the world extent that is visible
ROD_LENGTH = 1.0
ROD_HALF_WIDTH = 0.1
PIVOT_RADIUS = 0.05
BACKGROUND = np.array([255.0, 255.0, 255.0])
ROD_COLOUR = np.array([204.0, 77.0, 77.0])
PIVOT_COLOUR = np.array([0.0, 0.0, 0.0])


class PendulumPainter:
    """Paints frames of one size; the pixel grid is computed once."""

    def __init__(self, height: int, width: int):
        if height < 8 or width < 8:
            raise ValueError(f"Image size {height}x{width} is too small to draw the pendulum; use at least 8x8.")
        self.height, self.width = int(height), int(width)
        self.scale = min(self.height, self.width) / (2 * BOUND)  # pixels per world unit
        cols = (np.arange(self.width) + 0.5 - self.width / 2) / self.scale
        rows = (self.height / 2 - (np.arange(self.height) + 0.5)) / self.scale
        self._x, self._y = np.meshgrid(cols, rows)  # world coordinates of pixel centres, y up
        self._pivot_cover = self._coverage(np.hypot(self._x, self._y), PIVOT_RADIUS)

    def _coverage(self, distance: np.ndarray, radius: float) -> np.ndarray:
        """Fraction of a pixel covered by a shape whose border is at ``radius`` (1-pixel ramp)."""
        return np.clip((radius - distance) * self.scale + 0.5, 0.0, 1.0)

    def draw(self, theta: float) -> np.ndarray:
        tip_x, tip_y = -np.sin(theta) * ROD_LENGTH, np.cos(theta) * ROD_LENGTH
        # distance from each pixel centre to the segment pivot -> tip (a capsule of half-width 0.1)
        t = np.clip((self._x * tip_x + self._y * tip_y) / ROD_LENGTH**2, 0.0, 1.0)
        distance = np.hypot(self._x - t * tip_x, self._y - t * tip_y)
        rod = self._coverage(distance, ROD_HALF_WIDTH)[..., None]
        pivot = self._pivot_cover[..., None]
        img = BACKGROUND * (1.0 - rod) + ROD_COLOUR * rod
        img = img * (1.0 - pivot) + PIVOT_COLOUR * pivot
        return np.floor(img + 0.5).astype(np.uint8)
