"""The report's figures, drawn with matplotlib's object API on the Agg canvas, returned as PNG bytes.

No pyplot (no global state, no GUI backend).  Only finite values are drawn: a NaN, an inf or (on a
log axis) a non-positive value is left out, never plotted as a number.  Each figure is small and
few per case (one 4-panel figure per case and dt).

Speed (the default suite's report: 735 runs, 35 case figures, 450 MB of trajectories): a line of
N samples is drawn through at most 4 samples per envelope column, ENVELOPE_PER_PIXEL columns per
pixel of its panel (the first, last, lowest and highest of the column, :func:`envelope`), which
draws what all N draw and keeps every maximum and the last sample before a divergence; the runs of
a figure share one truth, read and reduced once (:class:`freebody.report.data.SeriesReader`);
titles are placed without measuring the axes; PNGs are encoded as RGB; and :func:`render_figures`
draws the figures in parallel processes when there are many (docs/reports.md, "Speed").

Readability: one colour per engine (Okabe-Ito, colour-blind safe; the reference engine black), a
line style and marker per integrator (:func:`styles`), legends next to the panels they explain,
and every text inside its figure: :func:`png_bytes` grows a figure whose labels overflow it and
fails (under pytest) on a text that still does (:func:`text_overflow`, :class:`ClippedText`).
"""
from __future__ import annotations

import io
import math
import os
import zipfile
from pathlib import Path

import numpy as np

from . import data as rd
from .. import tolerances as tol
from ..run.convergence import FITTED_METRICS, MIN_POINTS
from ..run.metrics import ORIENTATION_ERROR_MAX
from ..results.document import trajectory_path
from ..results.io import FileRefused
from ..run.records import Status

DPI = 90
# Figures drawn in one process at most; more are spread over worker processes (render_figures).
SERIAL_FIGURES = 8
# Envelope columns per pixel column of a panel: anti-aliasing makes the drawn line depend a little
# on which samples of a pixel column are joined; two per pixel halve the pixels that differ from
# drawing every sample (measured on a 200 000-sample random walk: 8 % -> 5 % of the line's
# pixels by more than a quarter of the grey range; 36 % with the 800-sample stride used before).
ENVELOPE_PER_PIXEL = 2
CASE_PANELS_W_IN, CASE_PANELS_H_IN = 9.6, 6.0  # a per-case figure's four panels (its legend at the right)
CASE_MARKS = 8  # markers on a time series: this many, evenly spaced in time
CASE_LINE_WIDTH_PT = 72 / DPI  # one pixel
LOG_PANEL_TOP = 1e3  # error panels stop here: beyond, a run has blown up (its status says so)
STATUS_COLOURS = {Status.DIVERGED: "#222222", Status.FAILED: "#b2182b", Status.SKIPPED: "#d9d9d9"}
STATUS_TEXT = {Status.DIVERGED: "div", Status.FAILED: "fail", Status.SKIPPED: "skip"}
# A text may reach this far (pixels) beyond the figure's edge: anti-aliasing of a glyph's edge.
TEXT_SLACK_PX = 0.5
# Room (pixels) left beyond an overflowing text when the figure is grown to hold it.
TEXT_FIT_PAD_PX = 4.0


def _figure(width_in: float, height_in: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=DPI)


# Text layouts and extents kept per process (:func:`agg_canvas`): the same tick labels, titles
# and legend entries recur in every figure of a report; cleared beyond this many entries.
TEXT_CACHE_ENTRIES = 20_000
# The settings that choose a text's font files (those matplotlib's findfont reads).
_FONT_PARAMS = tuple(f"font.{k}" for k in ("family", "style", "variant", "weight", "stretch", "size", "serif",
                                           "sans-serif", "cursive", "fantasy", "monospace"))
_CANVAS_CLASS = None


def agg_canvas(fig):
    """An Agg canvas of ``fig`` whose renderer lays out each text once per process.

    matplotlib's Agg renderer shapes a text's glyphs (FreeType, ~0.7 ms) every time it draws it,
    and measures it afresh for every new renderer (one per figure): the default suite's report
    draws and measures the same few hundred strings (tick labels, titles, legend entries) in
    every one of its figures.  The renderer here keeps a text's layout (glyphs and their offsets)
    and its extent, keyed by the font files, size, dpi, hinting, features and language: pure
    functions of those, so the pixels are the same bytes (tests/test_report_figures.py).  With a
    matplotlib lacking the private layout API it uses, the plain Agg canvas."""
    global _CANVAS_CLASS
    if _CANVAS_CLASS is None:
        _CANVAS_CLASS = _cached_text_canvas()
    return _CANVAS_CLASS(fig)


def _cached_text_canvas():
    """The canvas class of :func:`agg_canvas` (built on first use: matplotlib is imported lazily)."""
    from matplotlib.backends import backend_agg as agg
    from matplotlib.font_manager import fontManager

    if not (hasattr(agg.RendererAgg, "_draw_text_glyphs_and_boxes") and hasattr(agg, "get_hinting_flag")
            and hasattr(fontManager, "_find_fonts_by_props") and hasattr(agg, "RenderMode")
            and hasattr(agg.RendererAgg, "_prepare_font") and hasattr(agg, "get_font")):
        return agg.FigureCanvasAgg
    layouts: dict = {}
    extents: dict = {}
    glyphs: dict = {}
    heights: dict = {}
    fonts: dict = {}
    import matplotlib as mpl

    class Renderer(agg.RendererAgg):
        def _font_files(self, prop) -> tuple:
            """fontManager._find_fonts_by_props(prop), looked up once per font properties and
            font settings (matplotlib's lookup costs 0.1 ms a text and the figures draw thousands)."""
            if getattr(self, "_font_settings", None) is None:  # read once a figure: they do not change while it is drawn
                self._font_settings = (tuple(str(mpl.rcParams[k]) for k in _FONT_PARAMS),
                                       os.getenv("MPL_IGNORE_SYSTEM_FONTS"))
            key = (tuple(prop.__dict__.items()), self._font_settings)  # what FontProperties hashes
            found = fonts.get(key)
            if found is None:
                found = tuple(fontManager._find_fonts_by_props(prop))
                _remember(fonts, key, found)
            return found

        def _text_key(self, s, prop) -> tuple:
            return (self._font_files(prop), prop.get_size_in_points(), self.dpi, agg.get_hinting_flag(), s)

        def draw_text(self, gc, x, y, s, prop, angle, ismath=False, mtext=None):
            if ismath:
                return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
            features = mtext.get_fontfeatures() if mtext is not None else None
            language = mtext.get_language() if mtext is not None else None
            key = (self._text_key(s, prop), repr(features), repr(language))
            items = layouts.get(key)
            if items is None:
                font = self._prepare_font(prop)
                items = [(item.ft_object, item.glyph_index, item.x, item.y) for item in
                         font._layout(s, flags=agg.get_hinting_flag(), features=features, language=language)]
                _remember(layouts, key, items)
            self._draw_glyphs(gc, x, y, angle, prop.get_size_in_points(), items)

        def _draw_glyphs(self, gc, x, y, angle, size, items) -> None:
            _draw_glyphs(self, agg, glyphs, gc, x, y, angle, size, items)

        def _get_font_height_metrics(self, prop):
            """(ascent, descent, line gap) in pixels of the font of ``prop``, as
            matplotlib.text.Text._get_layout reads them from its OS/2 or hhea table (once per
            font, size and dpi here)."""
            key = (self._font_files(prop), prop.get_size_in_points(), self.dpi)
            if key not in heights:
                _remember(heights, key, _font_height_metrics(agg.get_font(key[0]), key[1], self.dpi))
            return heights[key]

        def get_text_width_height_descent(self, s, prop, ismath):
            if ismath:
                return super().get_text_width_height_descent(s, prop, ismath)
            key = self._text_key(s, prop)
            if key not in extents:
                _remember(extents, key, super().get_text_width_height_descent(s, prop, ismath))
            return extents[key]

    class Canvas(agg.FigureCanvasAgg):
        def get_renderer(self):  # FigureCanvasAgg's, with the Renderer above
            w, h = self.get_width_height(physical=True)
            key = w, h, self.figure.dpi
            if self._lastKey != key:
                self.renderer = Renderer(w, h, self.figure.dpi)
                self._lastKey = key
            return self.renderer

    return Canvas


def _draw_glyphs(renderer, agg, glyphs: dict, gc, x, y, angle, size, items) -> None:
    """RendererAgg._draw_text_glyphs_and_boxes of these glyphs (no boxes) on ``renderer`` (of
    :func:`agg_canvas`; ``agg``: matplotlib's backend_agg; ``glyphs``: the bitmaps kept), each glyph's
    bitmap rendered once per font, size, dpi, rotation, hinting and position within its
    pixel (1/64 pixel, FreeType's unit): a glyph moved by whole pixels is the same
    bitmap moved by as many (its outline is translated by whole pixels before it is
    rasterised), so the pixels are those of rendering it each time."""
    cos, sin = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    matrix = (0x10000 * np.array([[cos, -sin], [sin, cos]])).round().astype(int)
    flags = agg.get_hinting_flag()
    antialiased = gc.get_antialiased()
    for ft, glyph, dx, dy in items:  # dy is upwards
        tx = round(0x40 * (x + dx * cos - dy * sin))
        ty = round(0x40 * (renderer.height - y + dx * sin + dy * cos))  # FreeType's y is upwards
        key = (ft, size, renderer.dpi, glyph, tuple(matrix.ravel()), tx & 63, ty & 63, flags, antialiased)
        hit = glyphs.get(key)
        if hit is None:
            ft.set_size(size, renderer.dpi)
            ft._set_transform(matrix, [tx, ty])
            bitmap = ft._render_glyph(glyph, flags, agg.RenderMode.NORMAL if antialiased
                                      else agg.RenderMode.MONO)
            buffer = np.array(bitmap.buffer)
            if not antialiased:
                buffer *= 0xff
            hit = (buffer, bitmap.left - (tx >> 6), bitmap.top - (ty >> 6))
            _remember(glyphs, key, hit)
        buffer, left, top = hit
        # draw_text_image's y is downwards and the bitmap's bottom side
        renderer._renderer.draw_text_image(buffer, left + (tx >> 6),
                                           int(renderer.height) - (top + (ty >> 6)) + buffer.shape[0], 0, gc)


def _remember(cache: dict, key, value) -> None:
    """cache[key] = value, the cache cleared first when it holds TEXT_CACHE_ENTRIES entries."""
    if len(cache) >= TEXT_CACHE_ENTRIES:
        cache.clear()
    cache[key] = value


def _font_height_metrics(font, size_pt: float, dpi: float) -> tuple:
    """(ascent, descent, line gap) in pixels of an FT2Font at a size and dpi from its OS/2 table
    (else hhea), as matplotlib.text.Text._get_layout computes them; (None, None, None) when the
    font has neither table (Text then measures "lp")."""
    for table_name, gap_key, ascent_key, descent_key in (
            ("OS/2", "sTypoLineGap", "sTypoAscender", "sTypoDescender"), ("hhea", "lineGap", "ascent", "descent")):
        table = font.get_sfnt_table(table_name)
        if table is None:
            continue
        scale = 1 / font.get_sfnt_table("head")["unitsPerEm"] * size_pt * dpi / 72
        return table[ascent_key] * scale, -table[descent_key] * scale, table[gap_key] * scale
    return None, None, None


# An opaque figure is stored as a PNG of at most this many colours (a palette picked per image by
# PIL's fast octree, no dithering): line plots use a few dozen colours and their anti-aliased
# edges; measured on the default suite's 38 figures: 6.0 MB -> 2.0 MB of PNG (report.html 8.5 MB ->
# 3.2 MB), 0.3 % of the pixels off by more than 16 of 255 in a channel, none by more than 48.
PNG_COLOURS = 256
# zlib level of the PNGs: 9 against the default 6 is 7 % fewer bytes, lossless (the default suite's
# 50 figures: 2.62 -> 2.43 MB, report.html -0.26 MB), for 3 s CPU more in all (60 ms a figure).
PNG_COMPRESS_LEVEL = 9


class ClippedText(AssertionError):
    """A figure's text extends beyond the figure (a label cut at its edge), even after the figure
    was grown to hold it (:func:`fit_texts`)."""


def _drawn_texts(fig) -> list:
    """The visible, non-empty text artists a drawn figure shows: titles, axis labels, the tick
    labels drawn (those inside the view limits), texts, legends (of axes and of the figure)."""
    from matplotlib.text import Text

    out = list(fig.texts)
    legends = list(fig.legends)
    for ax in [a for parent in fig.axes for a in (parent, *parent.child_axes)]:
        if not ax.get_visible():
            continue
        out += [ax.title, ax._left_title, ax._right_title, *ax.texts]
        for axis in (ax.xaxis, ax.yaxis):
            if not axis.get_visible():
                continue
            out += [axis.label, axis.get_offset_text()]
            for tick in axis._update_ticks():  # the ticks drawn: inside the view limits
                out += [tick.label1 if tick.label1.get_visible() else None,
                        tick.label2 if tick.label2.get_visible() else None]
        if ax.get_legend() is not None:
            legends.append(ax.get_legend())
    for lg in legends:
        if lg.get_visible():
            out += [*lg.get_texts(), lg.get_title()]
    return [t for t in out if isinstance(t, Text) and t.get_visible() and t.get_text().strip()]


def text_overflow(fig, renderer=None) -> tuple[tuple[float, float, float, float], list[str]]:
    """((left, bottom, right, top) pixels by which the drawn figure's texts extend beyond it, the
    texts that do) after ``fig.canvas.draw()``; zeros and [] when every text is inside."""
    renderer = renderer or fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    over = [0.0, 0.0, 0.0, 0.0]
    names = []
    for t in _drawn_texts(fig):
        bb = t.get_window_extent(renderer)
        if not (np.isfinite(bb.x0) and np.isfinite(bb.y1)):
            continue
        sides = (-bb.x0, -bb.y0, bb.x1 - W, bb.y1 - H)
        if max(sides) > TEXT_SLACK_PX:
            names.append(t.get_text()[:60])
            over = [max(o, sd) for o, sd in zip(over, sides)]
    return tuple(over), names


def clipped_texts(fig) -> list[str]:
    """The texts of a figure (drawn here on the Agg canvas) that extend beyond it: [] when none."""

    canvas = agg_canvas(fig)
    canvas.draw()
    return text_overflow(fig, canvas.get_renderer())[1]


def fit_texts(fig, canvas):
    """Grow a drawn figure by the margins its texts overflow (long tick labels, a legend), keeping
    every axes' size in inches and moving it inwards; redraw.  Returns (the canvas to read, the
    texts still beyond the figure: [] unless growing did not help)."""

    for _ in range(3):
        (left, bottom, right, top), names = text_overflow(fig, canvas.get_renderer())
        if not names:
            return canvas, []
        dpi = fig.dpi
        pad = TEXT_FIT_PAD_PX
        grow = [(v + pad) / dpi if v > TEXT_SLACK_PX else 0.0 for v in (left, bottom, right, top)]
        w, h = fig.get_size_inches()
        nw, nh = w + grow[0] + grow[2], h + grow[1] + grow[3]
        for ax in fig.axes:
            x0, y0, aw, ah = ax.get_position().bounds
            ax.set_position(((x0 * w + grow[0]) / nw, (y0 * h + grow[1]) / nh, aw * w / nw, ah * h / nh))
        fig.set_size_inches(nw, nh)
        canvas = agg_canvas(fig)
        canvas.draw()
    return canvas, text_overflow(fig, canvas.get_renderer())[1]


def strict_figures() -> bool:
    """Whether a clipped text fails (under pytest, or FREEBODY_STRICT_FIGURES=1) or only warns."""
    return os.environ.get("FREEBODY_STRICT_FIGURES") == "1" or "PYTEST_CURRENT_TEST" in os.environ


def _unlog_empty_axes(fig) -> None:
    """Give a log axis with nothing positive to show (every run of the panel failed, was skipped
    or diverged) a linear scale without ticks: matplotlib cannot draw a log axis of no data
    ("Data cannot be log-scaled"), and the panel says why it is empty."""
    from matplotlib.ticker import NullLocator

    for ax in fig.axes:
        for axis, get_scale, set_scale, index in ((ax.xaxis, ax.get_xscale, ax.set_xscale, 0),
                                                  (ax.yaxis, ax.get_yscale, ax.set_yscale, 1)):
            if get_scale() != "log":
                continue
            values = [np.asarray(line.get_xydata(), dtype=float)[:, index] for line in ax.lines
                      if len(line.get_xdata())]
            values += [np.asarray(c.get_offsets(), dtype=float).reshape(-1, 2)[:, index]
                       for c in ax.collections if hasattr(c, "get_offsets")]
            data = np.concatenate(values) if values else np.empty(0)
            if not np.any(np.isfinite(data) & (data > 0)):
                set_scale("linear")
                axis.set_major_locator(NullLocator())
                axis.set_minor_locator(NullLocator())


def png_bytes(fig, overlay: DrawnPixels | None = None) -> bytes:
    """The figure as PNG: the pixels ``fig.savefig(format="png")`` draws at DPI, stored with a
    palette of PNG_COLOURS when the figure is opaque (a third of the RGB size), with no software
    metadata (so the bytes depend on the data only).

    overlay : pixels drawn once (a legend, :func:`drawn_alone`) put where the figure would draw
        them; :class:`OverlayRefused` when the figure is not the size they were drawn for (it
        was grown to hold its texts) or its pixels there are not blank: then draw it in.

    Every text must lie inside the figure: the figure is grown where one overflows
    (:func:`fit_texts`); one that still does raises :class:`ClippedText` under pytest (or with
    FREEBODY_STRICT_FIGURES=1), else warns."""
    from PIL import Image

    _unlog_empty_axes(fig)
    canvas = agg_canvas(fig)
    canvas.draw()
    canvas, names = fit_texts(fig, canvas)
    if names:
        message = f"figure text cut at the figure's edge: {names}"
        if strict_figures():
            raise ClippedText(message)
        import warnings

        warnings.warn(message, stacklevel=2)
    rgba = np.asarray(canvas.buffer_rgba())
    if overlay is not None:
        rgba = overlay.put(rgba)
    if bool(np.all(rgba[..., 3] == 255)):
        image = Image.fromarray(np.ascontiguousarray(rgba[..., :3]), "RGB").quantize(
            colors=PNG_COLOURS, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    else:
        image = Image.fromarray(rgba, "RGBA")
    buf = io.BytesIO()
    # zlib's level 9 (PNG_COMPRESS_LEVEL): the same pixels, 7 % fewer bytes than its default
    image.save(buf, format="png", dpi=(DPI, DPI), compress_level=PNG_COMPRESS_LEVEL)  # dpi: as savefig records
    return buf.getvalue()


class OverlayRefused(Exception):
    """Pixels drawn once do not fit this figure (:meth:`DrawnPixels.put`): draw the artist in it."""


# Pixels around an artist's extent taken with it (:func:`drawn_alone`): anti-aliased edges.
OVERLAY_MARGIN_PX = 2


class DrawnPixels:
    """An artist's pixels drawn alone on a blank figure (:func:`drawn_alone`): the block of rows
    and columns around it in a canvas of ``size`` (width, height) pixels, RGBA, rows from the top.

    Agg draws a pixel from its previous value and what covers it, so on a figure whose pixels in
    the block are blank (the figure's own background colour), the artist drawn there gives these
    pixels: :meth:`put` copies them instead of drawing it."""

    def __init__(self, size: tuple[int, int], rows: slice, cols: slice, block: np.ndarray, blank: np.ndarray):
        self.size, self.rows, self.cols, self.block, self.blank = size, rows, cols, block, blank

    def put(self, rgba: np.ndarray) -> np.ndarray:
        """``rgba`` (H x W x 4, a drawn figure without the artist) with the artist's pixels: a
        copy; OverlayRefused when it is another size or not blank under the block."""
        if (rgba.shape[1], rgba.shape[0]) != self.size:
            raise OverlayRefused("the figure is not the size the pixels were drawn for")
        if not np.array_equal(rgba[self.rows, self.cols], np.broadcast_to(self.blank, self.block.shape)):
            raise OverlayRefused("the figure is not blank under the pixels")
        out = np.array(rgba)
        out[self.rows, self.cols] = self.block
        return out


def drawn_alone(size_in: tuple[float, float], add) -> DrawnPixels | None:
    """The pixels of the artist ``add(fig)`` adds to a blank figure of ``size_in`` inches (and
    returns), or None when it cannot be drawn apart: it has texts beyond the figure's edge, or it
    draws outside its extent (every pixel outside the block must stay the background's)."""
    fig = _figure(*size_in)
    artist = add(fig)
    if artist is None:
        return None
    canvas = agg_canvas(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    if text_overflow(fig, renderer)[1]:
        return None
    rgba = np.asarray(canvas.buffer_rgba())
    H, W = rgba.shape[:2]
    box = artist.get_window_extent(renderer)  # pixels, y upwards
    m = OVERLAY_MARGIN_PX
    rows = slice(max(0, int(np.floor(H - box.y1)) - m), min(H, int(np.ceil(H - box.y0)) + m))
    cols = slice(max(0, int(np.floor(box.x0)) - m), min(W, int(np.ceil(box.x1)) + m))
    blank = rgba[0, 0].copy()
    outside = np.array(rgba)
    outside[rows, cols] = blank
    if not np.all(outside == blank):
        return None
    return DrawnPixels((W, H), rows, cols, rgba[rows, cols].copy(), blank)


# --- colours and line styles ------------------------------------------------------------------------

# Okabe & Ito's colour-blind-safe qualitative palette (Color Universal Design, 2008), one colour
# per engine; black is the reference engine's; yellow last (faint on white).
OKABE_ITO = ("#E69F00", "#56B4E9", "#009E73", "#0072B2", "#D55E00", "#CC79A7", "#F0E442")
REFERENCE_COLOUR = "#000000"
LINESTYLES = ("-", "--", ":", "-.")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "*", "h", "p")
TRUTH_STYLE = dict(color="#bdbdbd", linestyle="-", linewidth=3.5, zorder=0.5)  # a wide grey band below


def engine_of(lab: str) -> str:
    return lab.split("/", 1)[0]


def styles(labels: list[str]) -> dict[str, dict]:
    """A line style per engine-run label: colour per engine (Okabe-Ito, the reference engine
    black), line style and marker per integrator within its engine, in the labels' order."""
    from ..adapters.base import REFERENCE_ENGINE

    engines = list(dict.fromkeys(engine_of(lab) for lab in labels))
    others = [e for e in engines if e != REFERENCE_ENGINE]
    colour = {e: OKABE_ITO[i % len(OKABE_ITO)] for i, e in enumerate(others)}
    colour[REFERENCE_ENGINE] = REFERENCE_COLOUR
    seen: dict[str, int] = {}
    out = {}
    for lab in labels:
        e = engine_of(lab)
        k = seen[e] = seen.get(e, -1) + 1
        out[lab] = dict(color=colour[e], linestyle=LINESTYLES[k % len(LINESTYLES)],
                        marker=MARKERS[k % len(MARKERS)])
    return out


def _legend_right(fig, handles: dict, labs: list[str], top: float, title: str | None = None,
                  fontsize: float = 7):
    """A legend of the labels in one column at the figure's right edge, its top at ``top``
    (figure fraction): next to the panels it explains."""
    shown = [lab for lab in labs if lab in handles]
    if not shown:
        return None
    return fig.legend([handles[lab] for lab in shown], shown, loc="upper right", bbox_to_anchor=(1.0, top),
                      fontsize=fontsize, frameon=False, title=title, title_fontsize=fontsize,
                      alignment="left", handlelength=3.2)


def _legend_width_in(labs: list[str], fontsize: float = 7) -> float:
    """The width (inches) of a one-column legend of these labels (handle and padding included)."""
    return 0.0075 * fontsize * max((len(x) for x in labs), default=0) + 0.65


def _finite_xy(x, y, log_y: bool = False, log_x: bool = False):
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    if log_y:
        ok &= y > 0
    if log_x:
        ok &= x > 0
    return x[ok], y[ok]


def envelope(x: np.ndarray, y: np.ndarray, columns: int) -> np.ndarray:
    """Indices (ascending) of the samples of a line (x ascending, finite) that draw it at
    ``columns`` pixel columns across its x range: per column the first, the last, the lowest and
    the highest sample.  Joined in order they cover the same pixels as every sample (the segments
    inside a column span its lowest to its highest value, and the joins between columns are kept),
    and every maximum, minimum and the line's ends stay.  All indices when there are few samples."""
    n = len(x)
    if n <= 4 * columns or not x[-1] > x[0]:
        return np.arange(n)
    col = np.minimum(((x - x[0]) * (columns / (x[-1] - x[0]))).astype(np.int64), columns - 1)
    starts = np.concatenate(([0], np.flatnonzero(col[1:] != col[:-1]) + 1))
    counts = np.diff(np.append(starts, n))
    keep = np.zeros(n, dtype=bool)
    keep[starts] = keep[starts + counts - 1] = True
    for extreme in (np.minimum, np.maximum):
        at = np.flatnonzero(y == np.repeat(extreme.reduceat(y, starts), counts))
        column = np.searchsorted(starts, at, side="right")
        keep[at[np.r_[True, column[1:] != column[:-1]]]] = True  # the first per column
    return np.flatnonzero(keep)  # ascending, each once (np.unique sorts: 20x the rest)


def _columns(ax) -> int:
    """The width of an axes in pixels (at DPI)."""
    return max(1, int(np.ceil(ax.bbox.width)))


def _title(ax, text: str, **kw) -> None:
    """An axes title at its default place (y = 1, above the axes), set explicitly: matplotlib
    otherwise measures every tick label of the axes to see whether the title must move up (it
    need not: no tick labels are drawn above these axes), a fifth of the drawing time."""
    ax.set_title(text, y=1.0, **kw)


def _log_axes(ax, x: bool = False, y: bool = False) -> None:
    """Log scale with labels on the decades only (minor tick labels are slow and crowded)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    for on, axis, setter in ((x, ax.xaxis, ax.set_xscale), (y, ax.yaxis, ax.set_yscale)):
        if on:
            setter("log")
            axis.set_major_locator(LogLocator(base=10, numticks=8))
            axis.set_major_formatter(FuncFormatter(_decade))  # plain text: mathtext is slow
            axis.set_minor_locator(NullLocator())  # hundreds of minor ticks over 16 decades: slow


def _decade(v: float, _pos=None) -> str:
    """A log-axis tick label: 1e-4 for a decade, %g otherwise."""
    if not (v > 0 and np.isfinite(v)):
        return ""
    e = np.log10(v)
    return f"1e{int(round(e))}" if abs(e - round(e)) < tol.PLOT_DECADE_TICK_ATOL else f"{v:g}"


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=8, color="0.4")


# --- front page -----------------------------------------------------------------------------------

HEAT_ROW_IN = 0.27  # height of a heat-map row (inches)
HEAT_COLUMN_IN = 0.5  # width of a heat-map column (inches)


def heatmap(runs: list[dict]) -> bytes | None:
    """The orientation error max of every run: one panel per time step (coarsest first), cases
    (rows, those run at that dt) x engine runs (columns, the same in every panel), one log colour
    scale for all panels; diverged, failed and skipped cells in their own colours with a word.
    The column labels are written above the first panel and below the last."""
    from matplotlib.colors import LogNorm

    by_dt = rd.error_cells(runs)
    cases = list(rd.by_case(runs))
    labs = rd.labels(runs)
    if not by_dt or not labs:
        return None
    panels = [(dt, [c for c in cases if any((c, lab) in cells for lab in labs)]) for dt, cells in by_dt.items()]
    values = [v for cells in by_dt.values() for status, v in cells.values() if status == Status.OK and v is not None]
    finite = np.maximum(np.asarray(values, dtype=float), 1e-16)
    norm = None
    from matplotlib import colormaps

    cmap = colormaps["viridis"].with_extremes(bad="white")
    if finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        norm = LogNorm(vmin=lo, vmax=hi if hi > lo else lo * 10)
    label_in = 0.055 * max(map(len, labs)) * 0.87 + 0.15  # rotated column labels (60 degrees)
    case_in = 0.075 * max(map(len, cases)) + 0.25
    title_in, gap_in = 0.3, 0.15
    rows_in = [HEAT_ROW_IN * len(cs) for _, cs in panels]
    w = case_in + HEAT_COLUMN_IN * len(labs) + 1.2
    h = 2 * label_in + sum(rows_in) + len(panels) * (title_in + gap_in)
    fig = _figure(w, h)
    y = h - label_in  # inches from the bottom, going down
    axes = []
    for k, ((dt, cs), rin) in enumerate(zip(panels, rows_in)):
        y -= title_in + rin
        ax = fig.add_axes((case_in / w, y / h, HEAT_COLUMN_IN * len(labs) / w, rin / h))
        y -= gap_in
        axes.append(ax)
        cells = by_dt[dt]
        data = np.full((len(cs), len(labs)), np.nan)
        for (c, lab), (status, v) in cells.items():
            if status == Status.OK and v is not None and c in cs:
                data[cs.index(c), labs.index(lab)] = max(v, 1e-16)
        if norm is not None:
            im = ax.imshow(np.ma.masked_invalid(data), cmap=cmap, norm=norm, aspect="auto")
        else:
            ax.imshow(np.zeros_like(data), cmap="Greys", vmin=0, vmax=1, aspect="auto")
        _heat_cells(ax, cells, cs, labs, cmap, norm)
        ax.set_yticks(range(len(cs)), cs, fontsize=7.5)
        ax.set_xticks(range(len(labs)), labs if k == len(panels) - 1 else [], rotation=60, ha="right",
                      rotation_mode="anchor", fontsize=7)
        if k == 0:  # the column labels above the first panel as well: read on the first screen
            top = ax.secondary_xaxis("top")
            top.set_xticks(range(len(labs)), labs, rotation=60, ha="left", rotation_mode="anchor", fontsize=7)
        ax.tick_params(length=2)
        _title(ax, f"dt = {dt:g} s" + (f"   ({len(cs)} cases)" if len(cs) > 1 else ""), fontsize=8.5,
               loc="left", pad=2 if k else 2 + 72 * label_in)
    if norm is not None:
        from matplotlib.ticker import FuncFormatter, NullFormatter

        y_top = axes[0].get_position().y1
        y_bot = axes[-1].get_position().y0
        cax = fig.add_axes((1 - 0.95 / w, y_bot, 0.15 / w, y_top - y_bot))
        fig.colorbar(im, cax=cax).set_label("orientation error max (rad)", fontsize=8)
        cax.yaxis.set_major_formatter(FuncFormatter(_decade))
        cax.yaxis.set_minor_formatter(NullFormatter())
        cax.tick_params(labelsize=7)
    return png_bytes(fig)


def _heat_cells(ax, cells: dict, cs: list[str], labs: list[str], cmap, norm) -> None:
    """What each cell of a heat-map panel says: its status (diverged, failed, skipped: a patch of
    the status colour and a word) or its value, in black on a light colour of ``cmap(norm)``, else
    in white (the colours looked up for all cells at once)."""
    shown = {key: v for key, (status, v) in cells.items()
             if key[0] in cs and status == Status.OK and v is not None and norm is not None}
    colours = cmap(norm(np.maximum(np.array(list(shown.values()), dtype=float), 1e-16))) if shown else []
    light = {key: 0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2] > 0.5 for key, rgba in zip(shown, colours)}
    for (c, lab), (status, v) in cells.items():
        if c not in cs:
            continue
        i, j = cs.index(c), labs.index(lab)
        if status != Status.OK:
            ax.add_patch(_cell_patch(j, i, STATUS_COLOURS.get(status, "#ff00ff")))
            ax.text(j, i, STATUS_TEXT.get(status, status), ha="center", va="center", fontsize=6.5,
                    color="white" if status in (Status.DIVERGED, Status.FAILED) else "black")
        elif (c, lab) in light:
            ax.text(j, i, format(v, ".0e"), ha="center", va="center", fontsize=6.5,
                    color="black" if light[c, lab] else "white")


def _cell_patch(x: float, y: float, colour: str):
    from matplotlib.patches import Rectangle

    return Rectangle((x - 0.5, y - 0.5), 1, 1, facecolor=colour, edgecolor="white", linewidth=0.5)


def convergence(runs: list[dict], entries: list[dict]) -> bytes | None:
    """Error vs dt (log-log), one line per engine run.  For the cases run at >= 3 time steps (where
    orders are fitted): a row per case with the orientation and the energy error and the fitted
    order in the legend ('sat.' where the errors saturate).  Without such a case: the orientation
    error of the cases run at 2 time steps, one panel per case (no order)."""
    n_dts = {c: len(rd.dts(rs)) for c, rs in rd.by_case(runs).items()}
    fitted = [c for c, n in n_dts.items() if n >= MIN_POINTS]
    if fitted:
        return _convergence_rows(runs, entries, fitted)
    two = [c for c, n in n_dts.items() if n >= 2]
    if not two:
        return None
    return _per_case_grid(runs, two, lambda r: r["dt"], "dt (s)",
                          f"no order fitted: no case ran at {MIN_POINTS} or more time steps", dt_ticks=True)


def _dt_axis(ax, dts: list[float]) -> None:
    from matplotlib.ticker import NullLocator

    ax.set_xticks(dts, [f"{d:g}" for d in dts])  # the dts themselves: often less than a decade apart
    ax.xaxis.set_minor_locator(NullLocator())


def _convergence_rows(runs: list[dict], entries: list[dict], cases: list[str]) -> bytes:
    labs = rd.labels(runs)
    sty = styles(labs)
    fits = {(e["case"], rd.label(e), e["metric"]): e for e in entries}
    by_case = rd.by_case(runs)
    row_in = max(3.0, 0.115 * max(len(rd.labels(by_case[c])) for c in cases) + 0.7)  # room for the legend
    fig = _figure(11.0, row_in * len(cases) + 0.4)
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.6 / fig.get_figheight(), top=1 - 0.35 / fig.get_figheight(),
                        wspace=0.3, hspace=0.45)
    for row, case in enumerate(cases):
        case_runs = by_case[case]
        handles = []
        axes = [fig.add_subplot(len(cases), 3, 3 * row + k + 1) for k in range(2)]
        for lab in rd.labels(case_runs):
            mine = sorted((r for r in case_runs if rd.label(r) == lab), key=lambda r: float(r["dt"]))
            orders = []
            for ax, m in zip(axes, FITTED_METRICS):
                x, y = _finite_xy([r["dt"] for r in mine],
                                  [rd.metric(r, m) if r.get("status") == Status.OK else None for r in mine],
                                  log_y=True, log_x=True)
                h = _add_line(ax, x, y, dict(markersize=3.5, linewidth=1, fillstyle="none", **sty[lab]))
                e = fits.get((case, lab, m))
                if e and e.get("order") is not None and e.get("log10_coefficient") is not None:
                    fd = np.asarray(e["fitted_dts"], dtype=float)
                    _add_line(ax, fd, 10 ** e["log10_coefficient"] * fd ** e["order"],
                              dict(color=sty[lab]["color"], linewidth=0.6, alpha=0.6, linestyle=":"))
                orders.append("-" if not e else ("sat." if e.get("saturated") else rd.num(e.get("order"), ".2f")))
                if m == FITTED_METRICS[0]:
                    first = h
            handles.append((first, f"{lab}  p = {orders[0]} / {orders[1]}"))
        for ax, m in zip(axes, FITTED_METRICS):
            _log_axes(ax, x=True, y=True)
            _dt_axis(ax, rd.dts(case_runs))
            ax.set_xlabel("dt (s)", fontsize=8)
            ax.set_ylabel("orientation error max (rad)" if m == FITTED_METRICS[0] else "energy error max (rel)",
                          fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(True, which="major", alpha=0.3)
            _title(ax, case, fontsize=9)
            if not any(len(ln.get_xdata()) for ln in ax.lines):
                _empty(ax, "no ok run")
        lax = fig.add_subplot(len(cases), 3, 3 * row + 3)
        lax.axis("off")
        lax.legend([h for h, _ in handles], [t for _, t in handles], loc="center left", fontsize=6.5,
                   title="order p (orientation / energy)", title_fontsize=7, frameon=False)
    return png_bytes(fig)


def _per_case_grid(runs: list[dict], cases: list[str], x_of, xlabel: str, title: str | None = None,
                   dt_ticks: bool = False) -> bytes:
    """A grid of panels (3 per row), one per case: orientation error max (log) against x_of(run)
    (log), one line per engine run through its time steps (colour per engine, line style and marker
    per integrator), one legend for all panels at the right of the first row."""
    labs = rd.labels(runs)
    sty = styles(labs)
    ncol = min(3, len(cases))
    nrow = (len(cases) + ncol - 1) // ncol
    head = 0.35 + (0.35 if title else 0.0)
    panel_w, panel_h = 3.6, 2.8
    legend_w = _legend_width_in(labs)
    w = panel_w * ncol + legend_w + 0.3
    h = max(panel_h * nrow, 0.17 * len(labs) + 0.5) + 0.3 + head
    fig = _figure(w, h)
    handles = {}
    by_case = rd.by_case(runs)
    fig.subplots_adjust(left=0.7 / w, right=(panel_w * ncol) / w, top=1 - head / h, bottom=0.5 / h,
                        wspace=0.35, hspace=0.55)
    for k, case in enumerate(cases):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        case_runs = by_case[case]
        for lab in rd.labels(case_runs):
            mine = sorted((r for r in case_runs if rd.label(r) == lab), key=lambda r: float(r["dt"]))
            x, y = _finite_xy([x_of(r) for r in mine],
                              [rd.metric(r, ORIENTATION_ERROR_MAX) if r.get("status") == Status.OK else None
                               for r in mine], log_x=True, log_y=True)
            if len(x):
                handles[lab] = _add_line(ax, x, y, dict(markersize=3.5, linewidth=1, fillstyle="none", **sty[lab]))
        _log_axes(ax, x=True, y=True)
        if dt_ticks:
            _dt_axis(ax, rd.dts(case_runs))
        _title(ax, case, fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
        ax.set_ylabel("orientation error max (rad)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="major", alpha=0.3)
        if not any(len(ln.get_xdata()) for ln in ax.lines):
            _empty(ax, "no ok run to draw")
    if title:
        fig.suptitle(title, fontsize=9, y=1 - 0.12 / h)
    _legend_right(fig, handles, labs, top=1 - head / h)
    return png_bytes(fig)


def speed_accuracy(runs: list[dict]) -> bytes | None:
    """Per case: orientation error max vs wall time per simulated second (log-log), one line per
    engine run through its time steps."""
    cases = list(rd.by_case(runs))
    if not cases:
        return None
    return _per_case_grid(runs, cases, rd.wall_per_simulated_s, "wall time per simulated second (s/s)")


# --- per case and dt ------------------------------------------------------------------------------

def case_dt(case: str, dt: float, runs: list[dict], physics: rd.CasePhysics | None, out_dir: Path,
            all_labels: list[str]) -> tuple[bytes | None, list[str]]:
    """One 4-panel figure for the runs of a case at one dt: orientation error (log), energy error
    (log), angular momentum error (log), world angular velocity components vs the truth.
    Returns (PNG bytes or None, notes about runs that could not be drawn)."""
    loaded, truth_shown, notes = _load_case_runs(runs, physics, out_dir)
    if not loaded:
        return None, notes
    have = {rd.label(s.run) for s in loaded}
    drawn = [lab for lab in all_labels if lab in have]
    legend_w = _legend_width_in(drawn)
    w, h = CASE_PANELS_W_IN + legend_w, CASE_PANELS_H_IN
    fig, axes = _case_figure(w, h)
    try:
        handles = _draw_case_runs(axes, loaded, styles(all_labels))
        if truth_shown is not None:
            _draw_truth_angular_velocity(axes[3], truth_shown)
        _scale_case_panels(axes, physics)
        fig.suptitle(f"{case}, dt = {dt:g} s", fontsize=10, x=0.6 / w, ha="left", y=1 - 0.12 / h)
        png = _with_legend(fig, handles, drawn, top=1 - 0.45 / h)
    except BaseException:
        _forget_case_figure()
        raise
    if tuple(fig.get_size_inches()) != (w, h):  # grown to hold its texts: its axes moved
        _forget_case_figure()
    return png, notes


# The per-case figure of this process, (figure, its four axes), drawn again for the next case and
# dt (:func:`_case_figure`), or None.
_CASE_FIGURE = None


def _case_figure(w: float, h: float):
    """case_dt's figure of w x h inches and its four panels, titled and labelled, without lines:
    the figure drawn before in this process emptied (:func:`_empty_case_panels`) or a new one.

    An axes keeps its tick objects between figures: making a tick (its lines and labels) is a
    tenth of a figure's drawing, and titles and labels are set once.  What a figure shows is
    the same on a new or a reused figure (tests/test_report_figures.py compares the bytes)."""
    global _CASE_FIGURE
    if _CASE_FIGURE is None:
        fig = _figure(w, h)
        _place_case_panels(fig, w, h)
        axes = [fig.add_subplot(2, 2, k + 1) for k in range(4)]
        _label_case_panels(axes)
        _CASE_FIGURE = fig, axes
        return fig, axes
    fig, axes = _CASE_FIGURE
    for legend in list(fig.legends):
        legend.remove()
    _empty_case_panels(axes)
    fig.set_size_inches(w, h)
    _place_case_panels(fig, w, h)
    return fig, axes


# case_dt's legends drawn once in this process: (what it shows, figure size, top) -> DrawnPixels,
# or None when it is drawn in its figure each time (:func:`_with_legend`).
_LEGENDS: dict = {}
# Legends kept at most (one per set of runs drawn: the default suite's figures have one).
LEGENDS_KEPT = 64


def _with_legend(fig, handles: dict, labs: list[str], top: float) -> bytes:
    """png_bytes of the figure with its legend (:func:`_legend_right`), whose pixels are drawn once
    per process for each set of entries, line styles and figure size (the figures of a report
    show the same runs: a legend is a seventh of a figure's drawing) and copied in."""
    size = tuple(float(v) for v in fig.get_size_inches())
    key = (tuple((lab, _line_look(handles[lab])) for lab in labs if lab in handles), size, top)
    if key not in _LEGENDS:
        if len(_LEGENDS) >= LEGENDS_KEPT:
            _LEGENDS.clear()
        _LEGENDS[key] = drawn_alone(size, lambda f: _legend_right(f, handles, labs, top))
    if _LEGENDS[key] is not None:
        try:
            return png_bytes(fig, overlay=_LEGENDS[key])
        except OverlayRefused:  # grown to hold its texts, or something drawn where the legend goes
            pass
    _legend_right(fig, handles, labs, top)
    return png_bytes(fig)


def _line_look(line) -> tuple:
    """What a legend entry copies from a line (matplotlib's HandlerLine2D: Line2D.update_from)."""
    return (line.get_color(), line.get_linestyle(), line.get_linewidth(), line.get_marker(), line.get_markersize(),
            line.get_fillstyle(), line.get_markeredgecolor(), line.get_markerfacecolor(),
            line.get_markerfacecoloralt(), line.get_markeredgewidth(), line.get_alpha(), line.get_dash_capstyle(),
            line.get_solid_capstyle(), line.get_dash_joinstyle(), line.get_solid_joinstyle(), line.get_drawstyle(),
            line.get_visible(), line.get_gapcolor(), repr(line.get_path_effects()), line.get_sketch_params())


def forget_drawn() -> None:
    """Forget the figure and legends kept for the next per-case figures: the next is drawn anew."""
    _forget_case_figure()
    _LEGENDS.clear()


def _forget_case_figure() -> None:
    """The next case_dt draws on a new figure (this one failed, or was grown by fit_texts)."""
    global _CASE_FIGURE
    _CASE_FIGURE = None


def _place_case_panels(fig, w: float, h: float) -> None:
    """The four panels' place in a w x h inch figure (set before the lines: envelope() needs the
    panels' widths in pixels)."""
    fig.subplots_adjust(left=0.6 / w, right=(CASE_PANELS_W_IN - 0.1) / w, top=1 - 0.5 / h, bottom=0.45 / h,
                        wspace=0.22, hspace=0.38)


def _empty_case_panels(axes: list) -> None:
    """Undo what a figure drew on case_dt's panels: its lines and notes go, each axes is linear
    with its default tick locators and a new axes' limits (0 to 1, autoscaled when lines are
    added), with no data limits; titles, labels and tick styles stay (:func:`_label_case_panels`)."""
    for ax in axes:
        for artist in [*ax.lines, *ax.texts]:
            artist.remove()
        ax.set_yscale("linear")  # default locators and formatters again (a log panel's, or none)
        ax.relim()
        ax.set_xlim(0, 1, auto=True)  # a new axes' limits, autoscaled (set_ylim turned that off) once
        ax.set_ylim(0, 1, auto=True)  # lines are added; an axes left without data keeps them


def _load_case_runs(runs: list[dict], physics: rd.CasePhysics | None, out_dir: Path):
    """The drawable runs of case_dt with their error series, read from their trajectory files.

    Returns (loaded, truth_shown, notes): loaded holds a :class:`~freebody.report.data.RunSeries`
    per ok or diverged run with a readable trajectory and truth; truth_shown is the longest truth
    (a diverged run's is cut short), or None; notes say why a run could not be drawn."""
    reader = rd.SeriesReader(physics)
    notes = []
    loaded = []
    truth_shown = None
    for r in runs:
        if r.get("status") not in (Status.OK, Status.DIVERGED) or not r.get("trajectory"):
            continue
        try:
            s, truth = reader.read(trajectory_path(Path(out_dir), r["trajectory"]), r)
        except rd.NoTruth:
            notes.append(f"{rd.label(r)}: no truth in {r['trajectory']}")
            continue
        except FileRefused as e:  # not a regular file inside the folder, or too large
            notes.append(f"{rd.label(r)}: trajectory file {r['trajectory']} not read: {e.reason}")
            continue
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as e:
            notes.append(f"{rd.label(r)}: trajectory file {r['trajectory']} unreadable ({type(e).__name__})")
            continue
        loaded.append(s)
        if truth_shown is None or len(truth.t) > len(truth_shown.t):  # a diverged run's truth is cut short
            truth_shown = truth
    return loaded, truth_shown, notes


def _line(ax, x, y, log_y: bool = False, marks: float | None = None, **style):
    """Plot the finite (on a log axis: positive) samples of a line through its envelope.

    marks : with a marker style, its markers at CASE_MARKS evenly spaced times, shifted by this
    fraction (0..1) of their spacing (so that the markers of runs drawn on top of each other do
    not hide each other); None: no markers."""
    x, y = _finite_xy(x, y, log_y=log_y)
    keep = envelope(x, y, ENVELOPE_PER_PIXEL * _columns(ax))
    x, y = x[keep], y[keep]
    if marks is None or len(x) < 2:
        style.pop("marker", None)
    else:
        step = (x[-1] - x[0]) / CASE_MARKS
        at = np.searchsorted(x, x[0] + step * (marks + np.arange(CASE_MARKS)))
        style["markevery"] = sorted(set(int(i) for i in at if i < len(x)))
    return _add_line(ax, x, y, style)


def _add_line(ax, x: np.ndarray, y: np.ndarray, style: dict):
    """``ax.plot(x, y, **style)[0]`` for 1-D float arrays and a style that sets the colour: the same
    Line2D (a colour given, the property cycle is not read), made directly (plot's argument
    parsing is two thirds of its cost)."""
    from matplotlib.lines import Line2D

    line = Line2D(x, y, **style)
    ax.add_line(line)
    ax._request_autoscale_view()  # as plot does, for both axes
    return line


def _draw_case_runs(axes: list, loaded: list, sty: dict) -> dict:
    """Each loaded run's three error curves and its angular velocity components on case_dt's
    axes (colour per engine, line style and sparse markers per integrator); returns {label: line
    handle} for the legend."""
    handles = {}
    labs = list(dict.fromkeys(rd.label(s.run) for s in loaded))
    for s in loaded:
        lab = rd.label(s.run)
        # 1-pixel lines without anti-aliasing: crisp, and a third of the PNG bytes of the
        # anti-aliased shades of dense round-off noise (the default suite's report.html: see
        # docs/reports.md, "Size")
        style = dict(sty[lab], linewidth=CASE_LINE_WIDTH_PT, markersize=3.5, fillstyle="none", antialiased=False)
        phase = labs.index(lab) / len(labs)
        t, keep = s.t[s.keep], s.keep
        for ax, y in zip(axes[:3], (s.orientation_error, s.energy_error, s.angular_momentum_error)):
            if y is None:
                continue
            h = _line(ax, t, np.asarray(y)[keep], log_y=True, marks=phase, **style)
            handles.setdefault(lab, h)
        w = s.angular_velocity[keep]
        for k in range(3):
            _line(axes[3], t, w[:, k], alpha=0.85, marks=phase, **style)
    return handles


def _draw_truth_angular_velocity(ax, truth) -> None:
    """The truth's world angular velocity components, dashed, with the y range fitted to them."""
    for k in range(3):
        _line(ax, truth.t, truth.angular_velocity[:, k], **TRUTH_STYLE)
    w_true = truth.angular_velocity[np.all(np.isfinite(truth.angular_velocity), axis=1)]
    if len(w_true):
        lo, hi = float(w_true.min()), float(w_true.max())
        pad = max(0.25 * (hi - lo), 0.1 * max(abs(lo), abs(hi)), 1e-3)
        ax.set_ylim(lo - pad, hi + pad)  # a blown-up run must not flatten the truth


def _label_case_panels(axes: list) -> None:
    """Titles, labels and grids of case_dt's panels (the same in every figure)."""
    titles = ("orientation error (rad)", "energy error (rel. to max KE)",
              "angular momentum error (rel. to max |L|)", "world angular velocity (rad/s); truth: wide grey")
    for ax, title in zip(axes, titles):
        _title(ax, title, fontsize=9)
        ax.set_xlabel("t (s)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)


def _scale_case_panels(axes: list, physics: rd.CasePhysics | None) -> None:
    """After the lines: the three error panels on log axes capped at LOG_PANEL_TOP, or a note
    where there is nothing to draw."""
    for k, ax in enumerate(axes[:3]):
        if any(len(ln.get_xdata()) for ln in ax.lines):
            _log_axes(ax, y=True)
            if ax.get_ylim()[1] > LOG_PANEL_TOP:  # a blow-up must not squash the other runs
                ax.set_ylim(top=LOG_PANEL_TOP)
        else:
            _empty(ax, "needs the case's mass and inertia" if physics is None and k in (1, 2)
                   else "no positive finite error to draw on a log axis")


# --- all figures of report.html -------------------------------------------------------------------

def _figure_task(task: tuple):
    """One figure of :func:`render_figures`: (key, PNG bytes or None, notes)."""
    key, what = task[0], task[1]
    if what == "heatmap":
        return key, heatmap(task[2]), []
    if what == "convergence":
        return key, convergence(task[2], task[3]), []
    if what == "speed":
        return key, speed_accuracy(task[2]), []
    case, dt = key
    png, notes = case_dt(case, dt, *task[2:])
    return key, png, notes


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask; else the machine's count): the figure workers' number."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def figure_count(runs: list[dict]) -> int:
    """The number of figures :func:`render_figures` draws for these runs (3 summary figures and
    one per case and dt)."""
    return 3 + sum(len(rd.dts(case_runs)) for case_runs in rd.by_case(runs).values())


def render_figures(runs: list[dict], conv: list[dict], physics: dict, out_dir: Path,
                   jobs: int | None = None, on_figure=None, workers: list | None = None) -> tuple[dict, dict]:
    """Every figure of report.html: ({'heatmap', 'convergence', 'speed', (case, dt): PNG bytes or
    None}, {case: notes about runs that could not be drawn}).

    jobs : processes drawing the figures (the figures are independent); default: one per usable
        CPU when there are more than SERIAL_FIGURES per-case figures (:func:`drawn_apart`), else
        this process alone.  The figures are the same whatever ``jobs`` is.
    on_figure : called with a figure's name ("heatmap", "case, dt = 0.01 s", ...) as each is done
        (a progress display: :func:`figure_count` figures in all), or None.
    workers : worker processes started ahead (:func:`start_workers`) to draw them (then ``jobs``
        is their number), ended when the figures are done; None: started here when jobs > 1."""
    all_labels = rd.labels(runs)
    tasks = [("heatmap", "heatmap", runs), ("convergence", "convergence", runs, conv),
             ("speed", "speed", runs)]
    cases = rd.by_case(runs)
    for case, case_runs in cases.items():
        for dt in rd.dts(case_runs):
            at_dt = [r for r in case_runs if float(r["dt"]) == dt]
            tasks.append(((case, dt), "case", at_dt, physics.get(case), Path(out_dir), all_labels))
    if workers is not None:
        jobs = max(len(workers), 1)
    elif jobs is None:
        jobs = usable_cpus() if drawn_apart(runs) else 1
    done = (lambda key: on_figure(_figure_name(key))) if on_figure is not None else (lambda key: None)
    if jobs > 1 or workers:
        results = _render_parallel(tasks, jobs, done, workers)
    else:
        results = []
        for t in tasks:
            results.append(_figure_task(t))
            done(t[0])
    order = {t[0]: i for i, t in enumerate(tasks)}
    figures: dict = {}
    notes: dict = {}
    for key, png, n in sorted(results, key=lambda kr: order[kr[0]]):
        figures[key] = png
        if isinstance(key, tuple):
            notes.setdefault(key[0], []).extend(n)
    return figures, notes


def drawn_apart(runs: list[dict]) -> bool:
    """Whether render_figures draws these runs' figures in worker processes by default (more than
    SERIAL_FIGURES per-case figures)."""
    return figure_count(runs) - 3 > SERIAL_FIGURES


def start_workers(jobs: int) -> list:
    """Up to ``jobs`` figure worker processes (``python -m freebody.report.plots``: started afresh,
    so nothing of the caller's ``__main__`` is re-run), for render_figures: started ahead, they
    import matplotlib while the caller reads the results.  [] when none could start."""
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # import as we do
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")  # the workers are the parallelism: no BLAS threads on top
    workers = []
    for _ in range(jobs):
        try:
            workers.append(subprocess.Popen([sys.executable, "-m", "freebody.report.plots"],
                                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env))
        except OSError:
            break
    return workers


def stop_workers(workers: list, wait: bool = True) -> None:
    """End worker processes: each told there is no more work (an idle one exits); a busy one
    killed unless ``wait``; waited for (killed after 5 s)."""
    import subprocess

    for w in workers:
        try:
            w.stdin.close()  # end of tasks: an idle worker exits
        except OSError:
            pass
    for w in workers:
        if not wait:  # interrupted (or failed): a busy worker is not waited for
            w.kill()
        try:
            w.wait(timeout=5)
        except subprocess.TimeoutExpired:
            w.kill()
            w.wait()
        w.stdout.close()


def _figure_name(key) -> str:
    """A figure's name in the progress display."""
    return key if isinstance(key, str) else f"{key[0]}, dt = {key[1]:g} s"


# The summary figures' cost in samples of a per-case figure (they read no trajectory, but draw a
# panel per case: measured on the default suite, each costs 3-4 per-case figures of 33 runs): they
# are dealt out first, so that none is left alone at the end while the other workers idle.
SUMMARY_COST_SAMPLES = 10**12


def _render_parallel(tasks: list[tuple], jobs: int, done=lambda key: None, workers: list | None = None) -> list:
    """The tasks' results, drawn by up to ``jobs`` worker processes (:func:`start_workers`, or
    ``workers`` started ahead), the heaviest figures first (the summary figures, then the
    per-case ones by samples), each worker given the next task as it finishes one; ``done(key)``
    is called as each figure arrives.  A task a worker could not draw (it failed, or no worker
    could start) is drawn here.  The workers are ended before this returns."""
    import pickle
    from multiprocessing.connection import wait

    def size(t: tuple) -> int:  # the samples to read: the heaviest figures go first
        return sum(int(r.get("steps") or 0) for r in t[2]) if t[1] == "case" else SUMMARY_COST_SAMPLES

    pending = sorted(tasks, key=size, reverse=True)
    results: list = []
    busy: dict = {}  # worker -> its task
    finished = False
    try:
        if workers is None:
            workers = start_workers(min(jobs, len(tasks)))

        def give(w) -> None:
            if pending:
                task = pending.pop(0)
                busy[w] = task
                try:
                    pickle.dump(task, w.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                    w.stdin.flush()
                except OSError:  # the worker died: seen below as its end of file
                    pass

        for w in workers:
            give(w)
        while busy:
            for f in wait([w.stdout for w in busy]):
                w = next(w for w in busy if w.stdout is f)
                task = busy.pop(w)
                try:
                    ok, payload = pickle.load(w.stdout)
                except (EOFError, OSError, pickle.UnpicklingError):
                    ok, payload = False, None
                results.append(payload if ok else _figure_task(task))
                done(task[0])
                if ok:
                    give(w)
        finished = True
    finally:
        stop_workers(workers or [], wait=finished)
    for t in list(pending):  # none left unless every worker failed
        results.append(_figure_task(t))
        done(t[0])
    return results


def _worker() -> None:
    """``python -m freebody.report.plots``: draw the pickled tasks read from stdin, one at a time,
    and write each (True, result) or (False, reason) to stdout."""
    import pickle
    import signal
    import sys

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent ends its workers
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # a stray print must not corrupt the results
    import matplotlib.figure  # noqa: F401  imported while the parent prepares the first task
    import PIL.PngImagePlugin  # noqa: F401

    agg_canvas(_figure(1, 1))
    while True:
        try:
            task = pickle.load(inp)
        except EOFError:
            return
        try:
            answer = (True, _figure_task(task))
        except Exception as e:  # the parent draws it again and sees the error itself
            answer = (False, repr(e))
        pickle.dump(answer, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    _worker()
