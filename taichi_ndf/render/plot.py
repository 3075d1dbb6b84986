"""Line plots drawn with OpenCV (axes, ticks with numbers, legend), e.g. Π over iterations."""

import math

import cv2
import numpy as np

__all__ = ["plot_curves"]

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_INK = (40, 40, 40)
_GRID = (225, 225, 225)
# Tableau-10 colours in BGR: distinguishable and colour-blind tolerant.
_PALETTE = [
    (180, 119, 31),
    (14, 127, 255),
    (44, 160, 44),
    (40, 39, 214),
    (189, 103, 148),
    (75, 86, 140),
    (194, 119, 227),
    (127, 127, 127),
    (34, 189, 188),
    (207, 190, 23),
]


def plot_curves(
    series: dict[str, tuple[np.ndarray, np.ndarray]],
    *,
    title: str,
    xlabel: str,
    ylabel: str,
    log_y: bool = False,
    width: int = 800,
    height: int = 500,
) -> np.ndarray:
    """Plot named (x, y) curves on common axes; returns a uint8 BGR image (height, width, 3).

    Non-finite points (and with ``log_y`` non-positive y) are left out, breaking the line there.
    Text is drawn with OpenCV's Hershey font, which has ASCII characters only.
    """
    if width < 200 or height < 150:
        raise ValueError(f"plot size must be at least 200 x 150, got {width} x {height}")
    curves = {}
    for name, (x, y) in series.items():
        x, y = np.asarray(x, dtype=np.float64).ravel(), np.asarray(y, dtype=np.float64).ravel()
        if x.shape != y.shape:
            raise ValueError(f"series {name!r}: x and y differ in length ({len(x)}, {len(y)})")
        if log_y:
            with np.errstate(divide="ignore", invalid="ignore"):
                y = np.where(y > 0, np.log10(y), np.nan)
        curves[name] = (x, y)

    x_all = np.concatenate([x[np.isfinite(x) & np.isfinite(y)] for x, y in curves.values()] + [[]])
    y_all = np.concatenate([y[np.isfinite(x) & np.isfinite(y)] for x, y in curves.values()] + [[]])
    x_lo, x_hi = _padded_range(x_all, pad=0.0)
    y_lo, y_hi = _padded_range(y_all, pad=0.05)
    x_ticks = [(t, _format(t)) for t in _nice_ticks(x_lo, x_hi)]
    if log_y:
        y_ticks = _log_ticks(y_lo, y_hi)
    else:
        y_ticks = [(t, _format(t)) for t in _nice_ticks(y_lo, y_hi)]

    image = np.full((height, width, 3), 255, dtype=np.uint8)
    label_w = max(_text_size(text)[0] for _, text in y_ticks)
    left, right = 40 + label_w, width - 20
    top, bottom = 40, height - 55

    def to_px(x, y):
        px = left + (x - x_lo) / (x_hi - x_lo) * (right - left)
        py = bottom - (y - y_lo) / (y_hi - y_lo) * (bottom - top)
        return px, py

    for value, text in x_ticks:
        px = int(round(to_px(value, y_lo)[0]))
        cv2.line(image, (px, top), (px, bottom), _GRID, 1)
        cv2.line(image, (px, bottom), (px, bottom + 5), _INK, 1)
        tw, th = _text_size(text)
        _put(image, text, (px - tw // 2, bottom + 10 + th))
    for value, text in y_ticks:
        py = int(round(to_px(x_lo, value)[1]))
        cv2.line(image, (left, py), (right, py), _GRID, 1)
        cv2.line(image, (left - 5, py), (left, py), _INK, 1)
        tw, th = _text_size(text)
        _put(image, text, (left - 9 - tw, py + th // 2))
    cv2.rectangle(image, (left, top), (right, bottom), _INK, 1)

    # Lines are drawn on a 4x finer fixed-point grid so they are placed to a quarter pixel.
    shift = 2
    legend = []
    for index, (name, (x, y)) in enumerate(curves.items()):
        colour = _PALETTE[index % len(_PALETTE)]
        legend.append((name, colour))
        finite = np.isfinite(x) & np.isfinite(y)
        px, py = to_px(x, y)
        points = np.stack([px, py], axis=1) * (1 << shift)
        for run in _runs(finite):
            run_points = np.rint(points[run]).astype(np.int32)
            if len(run_points) == 1:
                cv2.circle(image, tuple(run_points[0]), 3 << shift, colour, -1, cv2.LINE_AA, shift)
            else:
                cv2.polylines(image, [run_points], False, colour, 2, cv2.LINE_AA, shift)

    drawn = [np.stack(to_px(x, y), axis=1) for x, y in curves.values()]
    _draw_legend(image, legend, (left, top, right, bottom), drawn)
    tw, th = _text_size(title, 0.6)
    _put(image, title, ((left + right - tw) // 2, top - 14), 0.6)
    tw, th = _text_size(xlabel)
    _put(image, xlabel, ((left + right - tw) // 2, height - 12))
    _put_vertical(image, ylabel, x=12, centre_y=(top + bottom) // 2)
    return image


def _padded_range(values: np.ndarray, *, pad: float) -> tuple[float, float]:
    if not len(values):
        return 0.0, 1.0
    lo, hi = float(values.min()), float(values.max())
    if hi == lo:
        half = 0.5 * abs(lo) if lo != 0 else 0.5
        return lo - half, hi + half
    margin = pad * (hi - lo)
    return lo - margin, hi + margin


def _nice_ticks(lo: float, hi: float, target: int = 6) -> list[float]:
    """Round tick values (1, 2 or 5 times a power of ten apart) inside [lo, hi]."""
    raw = (hi - lo) / target
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 5, 10) if m * power >= raw)
    first = math.ceil(lo / step - 1e-9)
    last = math.floor(hi / step + 1e-9)
    # Snap values like 0.30000000000000004 and -0.0 to what they should print as.
    return [round(k * step, 12) + 0.0 for k in range(first, last + 1)]


def _log_ticks(lo: float, hi: float) -> list[tuple[float, str]]:
    """Ticks of a log10 axis (lo, hi in decades): powers of ten, or round values in one decade."""
    first, last = math.ceil(lo - 1e-9), math.floor(hi + 1e-9)
    if last - first >= 1:
        stride = max(1, math.ceil((last - first + 1) / 8))
        return [(float(k), _format_power(k)) for k in range(first, last + 1, stride)]
    values = [v for v in _nice_ticks(10.0**lo, 10.0**hi, target=4) if v > 0]
    return [(math.log10(v), _format(v)) for v in values]


def _format(value: float) -> str:
    return f"{value:.4g}"


def _format_power(exponent: int) -> str:
    return f"{10.0**exponent:g}" if -3 <= exponent <= 4 else f"1e{exponent}"


def _runs(mask: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the maximal runs of True in a 1-D mask."""
    index = np.nonzero(mask)[0]
    if not len(index):
        return []
    breaks = np.nonzero(np.diff(index) > 1)[0] + 1
    return np.split(index, breaks)


def _text_size(text: str, scale: float = 0.45) -> tuple[int, int]:
    (w, h), _ = cv2.getTextSize(text, _FONT, scale, 1)
    return w, h


def _put(image, text, origin, scale: float = 0.45, colour=_INK):
    cv2.putText(image, text, (int(origin[0]), int(origin[1])), _FONT, scale, colour, 1, cv2.LINE_AA)


def _put_vertical(image, text: str, *, x: int, centre_y: int):
    """Text rotated 90 degrees counter-clockwise (reading upwards), left edge at column x."""
    if not text:
        return
    w, h = _text_size(text)
    strip = np.full((h + 8, w + 4, 3), 255, dtype=np.uint8)
    _put(strip, text, (2, h + 2))
    strip = cv2.rotate(strip, cv2.ROTATE_90_COUNTERCLOCKWISE)
    sh, sw = strip.shape[:2]
    y0 = max(0, min(image.shape[0] - sh, centre_y - sh // 2))
    sh = min(sh, image.shape[0] - y0)
    sw = min(sw, image.shape[1] - x)
    region = image[y0 : y0 + sh, x : x + sw]
    np.minimum(region, strip[:sh, :sw], out=region)


def _draw_legend(image, entries, plot_box, curve_pixels):
    """Legend in the corner of the plot area holding fewest curve points (top right on ties)."""
    if not entries:
        return
    left, top, right, bottom = plot_box
    line_h, swatch = 20, 24
    text_w = max(_text_size(name)[0] for name, _ in entries)
    box_w, box_h = swatch + 18 + text_w, 10 + line_h * len(entries)
    points = np.concatenate(curve_pixels)
    points = points[np.all(np.isfinite(points), axis=1)]
    corners = [
        (right - box_w - 10, top + 10),
        (left + 10, top + 10),
        (right - box_w - 10, bottom - box_h - 10),
        (left + 10, bottom - box_h - 10),
    ]

    def crossings(corner):
        x0, y0 = corner
        inside = (points[:, 0] >= x0) & (points[:, 0] <= x0 + box_w)
        return int(np.count_nonzero(inside & (points[:, 1] >= y0) & (points[:, 1] <= y0 + box_h)))

    x0, y0 = min(corners, key=crossings)
    cv2.rectangle(image, (x0, y0), (x0 + box_w, y0 + box_h), (255, 255, 255), -1)
    cv2.rectangle(image, (x0, y0), (x0 + box_w, y0 + box_h), (190, 190, 190), 1)
    for k, (name, colour) in enumerate(entries):
        y = y0 + 5 + line_h * k + line_h // 2
        cv2.line(image, (x0 + 6, y), (x0 + 6 + swatch, y), colour, 2, cv2.LINE_AA)
        _put(image, name, (x0 + 12 + swatch, y + 5))
