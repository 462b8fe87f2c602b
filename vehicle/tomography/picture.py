"""A PNG of a reconstruction: the image (one frame's, or the mean of the windows'), a colour bar in dB, a
one-metre scale, the radios (white dots) and the image's peaks (red crosses)."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from vehicle.tomography.imaging import CORRELATION, Result, find_peaks

# viridis at five stops: dark for no attenuation, yellow for the most
STOPS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
SIZE = 560  # pixels of the longer side of the map
MARGIN, BAR = 30, 90


def colours(values: np.ndarray) -> np.ndarray:
    """Values in [0, 1] to RGB bytes."""
    at = np.clip(values, 0, 1) * (len(STOPS) - 1)
    low = np.minimum(at.astype(int), len(STOPS) - 2)
    frac = (at - low)[..., None]
    return (STOPS[low] * (1 - frac) + STOPS[low + 1] * frac).astype(np.uint8)


def draw(result: Result, path: str) -> None:
    grid, image = result.grid, result.mean_image
    x0, y0, x1, y1 = grid.bounds
    scale = SIZE / max(x1 - x0, y1 - y0)  # pixels per metre
    width, height = int((x1 - x0) * scale), int((y1 - y0) * scale)
    top = max(float(image.max()), 1e-9)
    picture = Image.new("RGB", (width + 2 * MARGIN + BAR, height + 2 * MARGIN + 20), "white")
    rgb = colours(np.clip(image, 0, None) / top)[::-1]  # row 0 is the south edge; the picture's top is north
    picture.paste(Image.fromarray(rgb).resize((width, height), Image.NEAREST), (MARGIN, MARGIN))
    pen = ImageDraw.Draw(picture)
    font = ImageFont.load_default()

    def at(x: float, y: float) -> tuple[float, float]:
        return MARGIN + (x - x0) * scale, MARGIN + (y1 - y) * scale

    pen.rectangle([MARGIN, MARGIN, MARGIN + width, MARGIN + height], outline="black")
    for x, y in result.radios:
        cx, cy = at(x, y)
        pen.ellipse([cx - 5, cy - 5, cx + 5, cy + 5], fill="white", outline="black")
    peaks = result.frames[0]["peaks"] if len(result.frames) == 1 else find_peaks(image, grid, 3, CORRELATION)
    for peak in peaks:
        cx, cy = at(peak["x"], peak["y"])
        pen.line([cx - 7, cy - 7, cx + 7, cy + 7], fill="red", width=3)
        pen.line([cx - 7, cy + 7, cx + 7, cy - 7], fill="red", width=3)
    # scale: one metre along the bottom
    sx, sy = MARGIN, MARGIN + height + 10
    pen.line([sx, sy, sx + scale, sy], fill="black", width=3)
    pen.text((sx + scale + 6, sy - 6), "1 m", fill="black", font=font)
    what = "image" if len(result.frames) == 1 else f"mean of {len(result.frames)} windows of {result.window:g} s"
    pen.text((sx + scale + 50, sy - 6), f"{what}, cell {grid.cell:g} m", fill="black", font=font)
    # colour bar with its values (dB of attenuation per pixel, as the solver scales them)
    bx = MARGIN + width + 25
    ramp = colours(np.linspace(1, 0, height)[:, None].repeat(16, axis=1))
    picture.paste(Image.fromarray(ramp), (bx, MARGIN))
    pen.rectangle([bx, MARGIN, bx + 16, MARGIN + height], outline="black")
    for fraction in (0.0, 0.25, 0.5, 0.75, 1.0):
        y = MARGIN + (1 - fraction) * height
        pen.line([bx + 16, y, bx + 20, y], fill="black")
        pen.text((bx + 23, y - 6), f"{fraction * top:.3g}", fill="black", font=font)
    # attenuation, RSS variance, or squared kernel distance
    unit = {"mean": "dB/px", "variance": "dB^2/px"}.get(result.info.get("measure"), "D^2/px")  # the font has no ²
    pen.text((bx - 4, MARGIN - 20), unit, fill="black", font=font)
    picture.save(path)
