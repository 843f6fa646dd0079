"""A labelled map of small integer counts (``mercury-dem info``'s coverage map), drawn with Pillow.

The map is a lat/lon grid of counts shown in discrete viridis colours, with framed axes, ticks at
round numbers, axis labels, a title and a colour bar of one step per count: what matplotlib's
``imshow`` + ``colorbar`` drew before, at the same size (900 x 500 pixels).

Why not matplotlib: importing it (``matplotlib.figure`` and the Agg canvas) and drawing this one
figure cost ``mercury-dem info`` ~0.5 s CPU on this machine — more than the rest of the command
(opening the mission, projecting the grid into every image) put together; Pillow's import and this
drawing take ~0.03 s. Pillow is the image library matplotlib itself writes PNGs with. The colours
are matplotlib's viridis sampled at 17 points and interpolated linearly (within 6/255 of it).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from PIL import Image

#: matplotlib's viridis at 17 evenly spaced points (0..1), 8-bit RGB.
VIRIDIS_17 = np.array([
    [68, 1, 84], [72, 24, 106], [71, 45, 123], [66, 64, 134], [59, 82, 139], [51, 99, 141], [44, 114, 142],
    [38, 130, 142], [33, 145, 140], [31, 160, 136], [40, 174, 128], [63, 188, 115], [94, 201, 98],
    [132, 212, 75], [173, 220, 48], [216, 226, 25], [253, 231, 37]], dtype=np.float64)

SIZE = (900, 500)
#: plot area (left, top, right, bottom) in pixels, and the colour bar's
PLOT = (72, 40, 720, 445)
BAR = (762, 40, 782, 445)


def viridis(x: NDArray[np.floating]) -> NDArray[np.uint8]:
    """RGB (..., 3) uint8 of values in [0, 1] (clipped) on the viridis colour map."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    grid = np.linspace(0.0, 1.0, len(VIRIDIS_17))
    rgb = np.stack([np.interp(x, grid, VIRIDIS_17[:, k]) for k in range(3)], axis=-1)
    return np.round(rgb).astype(np.uint8)


def nice_ticks(lo: float, hi: float, target: int = 7) -> NDArray[np.float64]:
    """Round-numbered ticks (steps of 1, 2, 2.5 or 5 times a power of ten) inside [lo, hi], about ``target``."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if math.isfinite(lo) else np.zeros(0)
    raw = (hi - lo) / max(1, target - 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * mag >= raw * 0.999)
    first = math.ceil(lo / step - 1e-9) * step
    ticks = np.arange(first, hi + step * 1e-9, step)
    return np.round(ticks / step) * step


def _label(v: float) -> str:
    s = f"{v:.6g}"
    return "0" if s in ("-0", "0") else s  # (the default font has no U+2212 minus sign)


def render_count_map(count: NDArray[np.integer], extent: tuple[float, float, float, float], title: str,
                     xlabel: str, ylabel: str, bar_label: str) -> Image.Image:
    """The map as a Pillow RGB image.

    Parameters
    ----------
    count : (n_lat, n_lon) int array, row 0 at the south edge (``origin="lower"``)
    extent : (lon_min, lon_max, lat_min, lat_max) of the grid's outer edges, degrees
    title, xlabel, ylabel, bar_label : texts of the figure
    """
    from PIL import Image, ImageDraw, ImageFont

    count = np.asarray(count)
    top = max(6, int(count.max(initial=0)))
    n_colours = top + 1
    colours = viridis(np.arange(n_colours) / max(1, n_colours - 1))
    img = Image.new("RGB", SIZE, "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default(size=13)
    x0, y0, x1, y1 = PLOT
    # the counts: north up, nearest-neighbour resampling to the plot area (as imshow at this size)
    raster = colours[np.clip(count, 0, top)[::-1]]
    img.paste(Image.fromarray(np.ascontiguousarray(raster), "RGB").resize((x1 - x0, y1 - y0), Image.NEAREST), (x0, y0))
    draw.rectangle((x0 - 1, y0 - 1, x1, y1), outline="black")
    lon0, lon1, lat0, lat1 = extent

    def text(xy: tuple[float, float], s: str, anchor: str) -> None:
        draw.text(xy, s, fill="black", font=font, anchor=anchor)

    for v in nice_ticks(lon0, lon1):
        x = x0 + (v - lon0) / (lon1 - lon0) * (x1 - x0)
        draw.line((x, y1, x, y1 + 4), fill="black")
        text((x, y1 + 6), _label(v), "mt")
    for v in nice_ticks(lat0, lat1):
        y = y1 - (v - lat0) / (lat1 - lat0) * (y1 - y0)
        draw.line((x0 - 5, y, x0 - 1, y), fill="black")
        text((x0 - 8, y), _label(v), "rm")
    text(((x0 + x1) / 2, y1 + 26), xlabel, "mt")
    draw.text(((x0 + x1) / 2, y0 - 10), title, fill="black", font=ImageFont.load_default(size=16), anchor="mb")
    _vertical_text(img, ylabel, font, (14, (y0 + y1) / 2))
    # colour bar: one band per count, ticks at the band centres
    bx0, by0, bx1, by1 = BAR
    h = (by1 - by0) / n_colours
    for k in range(n_colours):
        draw.rectangle((bx0, by1 - (k + 1) * h, bx1, by1 - k * h), fill=tuple(int(c) for c in colours[k]))
    draw.rectangle((bx0 - 1, by0 - 1, bx1, by1), outline="black")
    for k in range(0, top + 1, max(1, top // 10)):
        y = by1 - (k + 0.5) * h
        draw.line((bx1, y, bx1 + 4, y), fill="black")
        text((bx1 + 7, y), str(k), "lm")
    _vertical_text(img, bar_label, font, (bx1 + 48, (by0 + by1) / 2))
    return img


def _vertical_text(img: Image.Image, s: str, font: Any, centre: tuple[float, float]) -> None:
    """Write ``s`` rotated 90 degrees (reading upwards) centred on ``centre``."""
    from PIL import Image, ImageDraw

    left, top, right, bottom = font.getbbox(s)
    box = Image.new("L", (right - left + 2, bottom - top + 2), 0)
    ImageDraw.Draw(box).text((1 - left, 1 - top), s, fill=255, font=font)
    box = box.rotate(90, expand=True)
    x, y = int(round(centre[0] - box.width / 2)), int(round(centre[1] - box.height / 2))
    img.paste((0, 0, 0), (x, y, x + box.width, y + box.height), box)


def png_bytes(img: Image.Image) -> bytes:
    """The image as PNG file bytes."""
    import io

    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=False)
    return buf.getvalue()
