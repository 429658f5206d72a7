"""Self-contained HTML reports: our Markdown subset to HTML, figures embedded."""

from __future__ import annotations

import base64
import contextlib
import functools
import html
import io
import os
import re
import tempfile
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # matplotlib is imported by whoever draws the figures, not here
    from matplotlib.figure import Figure

_STYLE = """
body { font-family: -apple-system, Segoe UI, Helvetica, Arial, sans-serif; max-width: 1100px;
       margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
th { background: #f0f0f0; }
img { max-width: 100%; display: block; margin: 0.5em 0 1.5em 0; }
code { background: #f4f4f4; padding: 0 3px; }
pre { background: #f4f4f4; padding: 0.5em; white-space: pre-wrap; font-size: 0.85em; }
summary { font-weight: bold; cursor: pointer; margin: 0.4em 0; }
h1 { border-bottom: 2px solid #333; } h2 { border-bottom: 1px solid #aaa; margin-top: 1.6em; }
@media print {
  body { max-width: none; margin: 0; font-size: 10pt; }
  table { font-size: 8pt; page-break-inside: auto; } tr { page-break-inside: avoid; }
  th, td { padding: 1px 4px; }
  img { max-width: 100%; }
  /* a figure a little taller than a page is scaled to fit one (letter and A4 both
     hold 9 in under Chromium's margins); a much taller one would shrink past
     reading and runs on at the page's width instead */
  img.page { max-height: 9in; width: auto; height: auto; page-break-inside: avoid; }
  details > summary { list-style: none; }
}
"""


def figure_png(fig: Figure, *, dpi: int = 90, colors: int | None = None) -> bytes:
    """PNG bytes of a figure, with fixed metadata so identical figures give identical bytes.

    `colors`: quantise to a palette of that many colours (a line figure loses
    nothing visible and shrinks three- to four-fold: a campaign report embeds
    hundreds of figures).
    """
    from PIL import Image

    # drawn on a canvas of our own (`_agg_canvas`), the pixels straight to PIL: a palette
    # PNG from a full-colour one written and read back (as savefig would) costs more
    # than the quantisation
    canvas, old_dpi = fig.canvas, fig.dpi
    out = io.BytesIO()
    try:
        fig.set_dpi(dpi)
        agg = _agg_canvas(fig)
        with _ticks_once_a_draw(fig):
            agg.draw()
        width, height = agg.get_width_height()
        rgba = Image.frombuffer("RGBA", (width, height), agg.buffer_rgba(), "raw", "RGBA", 0, 1)
        if colors is None:
            # as savefig writes it, without its Software note; the renderer's buffer is
            # drawn over by the next figure, so the image is written here
            rgba.save(out, format="PNG", dpi=(dpi, dpi), compress_level=6)
        else:
            # the octree palette: indistinguishable from a median cut on line figures
            # (mean error under 2 of 255 levels), at a sixth of the cost
            small = rgba.convert("RGB").quantize(colors=colors, method=Image.Quantize.FASTOCTREE)
            # zlib's default level: the highest doubles the time for 7 % fewer bytes
            small.save(out, format="PNG", compress_level=6)
    finally:
        fig.set_dpi(old_dpi)
        fig.set_canvas(canvas)
    return out.getvalue()


@contextlib.contextmanager
def _ticks_once_a_draw(fig: Figure) -> Iterator[None]:
    """While on, each axis of `fig` places and measures its ticks once per draw of it.

    Matplotlib's axis draw computes its ticks (locator, formatter, label extents),
    then computes them again to place its label clear of the tick labels: the same
    numbers, nothing having moved in between. Each axis keeps them for the rest of
    its own draw; outside it (another axis asking, a draw before the limits settle)
    they are computed as before. The figure is left as it was found.
    """
    axes = [axis for ax in fig.axes for axis in getattr(ax, "_axis_map", {}).values()]
    if not all(hasattr(axis, name) for axis in axes for name in _TICK_METHODS):
        yield  # another matplotlib: drawn as it draws
        return
    # an axis whose methods someone already replaced on it is left to them
    axes = [a for a in axes if not any(n in a.__dict__ for n in ("draw", *_TICK_METHODS))]
    for axis in axes:
        _keep_ticks(axis)
    try:
        yield
    finally:
        for axis in axes:
            for name in ("draw", *_TICK_METHODS):
                axis.__dict__.pop(name, None)


_TICK_METHODS = ("_update_ticks", "_get_ticklabel_bboxes")


def _keep_ticks(axis: Any) -> None:
    """Give `axis` (for one figure draw) a draw in which its ticks are computed once
    and their marks drawn together (`_draw_axis`)."""
    draw, ticks, boxes = axis.draw, axis._update_ticks, axis._get_ticklabel_bboxes
    kept: dict[str, Any] = {}
    together = _plain_axis(axis)

    def drawing(renderer: Any, *args: Any, **kwargs: Any) -> Any:
        kept.clear()
        kept["on"] = True
        try:
            if together and not args and not kwargs:
                return _draw_axis(axis, renderer)
            return draw(renderer, *args, **kwargs)
        finally:
            kept.clear()

    def update_ticks() -> Any:
        if not kept:
            return ticks()
        if "ticks" not in kept:
            kept["ticks"] = ticks()
        return kept["ticks"]

    def ticklabel_bboxes(drawn: Any, renderer: Any) -> Any:
        if not kept or drawn is not kept.get("ticks"):
            return boxes(drawn, renderer)
        if kept.get("renderer") is not renderer:
            kept["renderer"], kept["boxes"] = renderer, boxes(drawn, renderer)
        return kept["boxes"]

    axis.draw = drawing
    axis._update_ticks = update_ticks
    axis._get_ticklabel_bboxes = ticklabel_bboxes


# what `_draw_axis` calls on an axis, beyond the tick methods `_keep_ticks` replaces
_AXIS_METHODS = ("_update_label_position", "_update_offset_text_position")


def _plain_axis(axis: Any) -> bool:
    """Whether `axis` draws as matplotlib's own `Axis.draw` (the one `_draw_axis` follows):
    not a subclass with a draw of its own, neither rasterised nor filtered."""
    from matplotlib.axis import Axis

    return (
        type(axis).draw is Axis.draw
        and all(hasattr(axis, name) for name in _AXIS_METHODS)
        and not axis.get_rasterized()
        and axis.get_agg_filter() is None
    )


def _draw_axis(axis: Any, renderer: Any) -> None:
    """Matplotlib's `Axis.draw`, but the ticks drawn part by part (`_draw_ticks`)."""
    if not axis.get_visible():
        return
    renderer.open_group("matplotlib.axis", gid=axis.get_gid())
    drawn = axis._update_ticks()
    tlb1, tlb2 = axis._get_ticklabel_bboxes(drawn, renderer)
    _draw_ticks(drawn, renderer)
    axis._update_label_position(renderer)
    axis.label.draw(renderer)
    axis._update_offset_text_position(tlb1, tlb2)
    axis.offsetText.set_text(axis.major.formatter.get_offset())
    axis.offsetText.draw(renderer)
    renderer.close_group("matplotlib.axis")
    axis.stale = False


_TICK_PARTS = ("gridline", "tick1line", "tick2line", "label1", "label2")


def _draw_ticks(ticks: list[Any], renderer: Any) -> None:
    """Draw `ticks` as their own draws would, one part of every tick after the other: the
    tick marks of an axis (a marker each, all alike) in one call of the renderer.

    Each tick mark through its own line's draw costs as much as drawing its label;
    drawn together they are the same pixels (the renderer places a marker at each
    point, each on its own). Parts of different ticks do not overlap (the marks and
    labels of an axis lie apart from each other), so the order of the parts does not
    change the picture. Ticks matplotlib would not draw alike are drawn one by one.
    """
    from matplotlib.axis import Tick

    shown = [t for t in ticks if t.get_visible()]
    alike = all(
        type(t).draw is Tick.draw
        and not t.get_rasterized()
        and t.get_agg_filter() is None
        and not t.get_path_effects()
        for t in shown
    )
    if not alike:
        for t in ticks:
            t.draw(renderer)
        return
    for part in _TICK_PARTS:
        artists = [getattr(t, part) for t in shown]
        artists = [a for a in artists if a.get_visible()]
        if part.startswith("tick") and len(artists) > 1 and _marks_alike(artists):
            _draw_marks(artists, renderer)
        else:
            for artist in artists:
                artist.draw(renderer)
    for t in ticks:
        t.stale = False


def _marks_alike(lines: list[Any]) -> bool:
    """Whether `lines` are markers only (no line between points), drawn alike: same marker,
    size, colours, width, transform and clipping, plain (no effects, every point marked)."""

    def style(line: Any) -> tuple[Any, ...]:
        return (
            type(line).draw,
            line.get_linestyle(),
            line.get_marker(),
            line.get_markersize(),
            line.get_markeredgewidth(),
            str(line.get_markeredgecolor()),
            str(line.get_markerfacecolor()),
            str(line.get_markerfacecoloralt()),
            line.get_fillstyle(),
            line.get_alpha(),
            line.get_antialiased(),
            line.get_drawstyle(),
            line.get_markevery(),
            # the same objects, not equal ones (a transform's equality may be costly)
            id(line.get_transform()),
            line.get_clip_on(),
            id(line.get_clip_box()),
            id(line.get_clip_path()),
            line.get_snap(),
            line.get_sketch_params(),
            line.get_url(),
            line.get_gid(),
            line.get_rasterized(),
            line.get_agg_filter(),
            bool(line.get_path_effects()),
        )

    first = style(lines[0])
    return first[1] in ("None", "none", " ", "") and all(style(ln) == first for ln in lines)


def _draw_marks(lines: list[Any], renderer: Any) -> None:
    """Draw the markers of `lines` (alike, `_marks_alike`) as one line through all their
    points draws them: the first line, given every point for the draw."""
    import numpy as np

    first = lines[0]
    x0, y0 = first.get_xdata(orig=True), first.get_ydata(orig=True)
    xs = np.concatenate([np.atleast_1d(ln.get_xdata(orig=True)) for ln in lines])
    ys = np.concatenate([np.atleast_1d(ln.get_ydata(orig=True)) for ln in lines])
    first.set_data(xs, ys)
    try:
        first.draw(renderer)
    finally:
        first.set_data(x0, y0)
    for line in lines:
        line.stale = False


# Agg renderers kept for the next figure of the same size and dpi, in each thread: a
# renderer's text metrics are cached with it, and a report draws the same layouts with
# mostly the same labels over and over (a new renderer measured every string afresh)
_RENDERERS = threading.local()
_KEEP_RENDERERS = 8
_KEEP_BITMAPS = 4096


def _agg_canvas(fig: Figure) -> Any:
    """An Agg canvas for `fig` (set as its canvas) that draws with a kept renderer."""
    cls = getattr(_RENDERERS, "canvas_class", None)
    if cls is None:
        cls = _RENDERERS.canvas_class = _canvas_class()
        _RENDERERS.kept = {}
    return cls(fig)


def _shaped(text: Any) -> bool:
    """Whether a Text asks for font features or a language (matplotlib >= 3.10), which
    only matplotlib's own text layout honours."""
    features = getattr(text, "get_fontfeatures", None)
    language = getattr(text, "get_language", None)
    return bool(features is not None and features()) or bool(language is not None and language())


def _canvas_class() -> Any:
    """The Agg canvas `figure_png` draws on: renderers kept (`_RENDERERS`), and each
    plain string of text drawn as one bitmap.

    Matplotlib 3.11 rasterises text glyph by glyph, with Python arithmetic around each
    glyph: half the time of drawing a report's figure went to its tick labels and
    titles. FreeType lays out and rasterises a whole string in one call (as Agg did up
    to matplotlib 3.10), at whole-pixel rather than sub-pixel positions, which no one
    can tell apart at these sizes. Mathematical text, text with font features or a
    language, and any matplotlib without those calls are drawn as matplotlib draws them.
    """
    import math

    import matplotlib as mpl
    from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg, get_hinting_flag
    from matplotlib.font_manager import fontManager, get_font
    from matplotlib.ft2font import FT2Font

    whole_strings = all(
        hasattr(FT2Font, name)
        for name in (
            "set_text",
            "draw_glyphs_to_bitmap",
            "get_bitmap_offset",
            "get_descent",
            "get_image",
        )
    ) and hasattr(RendererAgg, "_prepare_font")

    # each string's bitmap, kept: it depends on the string, its font and the dpi, not on
    # where it is drawn, and a report repeats its tick labels on every panel
    bitmaps: dict[Any, tuple[Any, float, float, float]] = {}
    # each string's extent and each font's line height, kept for the same reason: every
    # label is measured on each draw (and its line height looked up in the font file's
    # tables), and matplotlib keeps what it measured for one renderer only
    extents: dict[Any, tuple[float, float, float]] = {}
    heights: dict[Any, tuple[float, float, float] | tuple[None, None, None]] = {}
    # the font tables that give a line's ascent, descent and gap, in matplotlib's order
    line_tables = (
        ("OS/2", "sTypoAscender", "sTypoDescender", "sTypoLineGap"),
        ("hhea", "ascent", "descent", "lineGap"),
    )

    def keep(cache: dict[Any, Any], key: Any, value: Any) -> None:
        if len(cache) >= _KEEP_BITMAPS:
            cache.pop(next(iter(cache)))
        cache[key] = value

    class _Renderer(RendererAgg):
        def get_text_width_height_descent(  # type: ignore[no-untyped-def]
            self, s, prop, ismath
        ) -> tuple[float, float, float]:
            if ismath:
                return super().get_text_width_height_descent(s, prop, ismath)
            key = (s, prop.copy(), self.dpi)
            got = extents.get(key)
            if got is None:
                if whole_strings:  # measured and rasterised in one layout (`_lay_out`)
                    self._lay_out(s, prop, bool(mpl.rcParams["text.antialiased"]))
                    got = extents[key]
                else:
                    got = super().get_text_width_height_descent(s, prop, ismath)
                    keep(extents, key, got)
            return got

        def _lay_out(self, s: str, prop: Any, antialiased: bool) -> None:
            """Lay out `s` once (FreeType's layout of a whole string is most of the cost
            of measuring or drawing it): keep its extent, as matplotlib measures it, and
            its bitmap, which the label's draw then finds."""
            font = self._prepare_font(prop)
            font.set_text(s, 0.0, flags=get_hinting_flag())
            width, height = font.get_width_height()
            extent = (width / 64.0, height / 64.0, font.get_descent() / 64.0)
            keep(extents, (s, prop.copy(), self.dpi), extent)
            font.draw_glyphs_to_bitmap(antialiased=antialiased)
            # the bitmap's corner from the layout's origin, and the descent (26.6 fixed
            # point)
            dx, dy = (v / 64.0 for v in font.get_bitmap_offset())
            drawn = (font.get_image().copy(), font.get_descent() / 64.0, dx, dy)
            keep(bitmaps, (s, prop.copy(), self.dpi, antialiased), drawn)

        def _get_font_height_metrics(  # type: ignore[no-untyped-def]
            self, prop
        ) -> tuple[float, float, float] | tuple[None, None, None]:
            # matplotlib's text layout asks a renderer for a font's line metrics before
            # it reads them from the font: the same numbers, computed once per font
            key = (prop.copy(), self.dpi)
            got = heights.get(key)
            if got is None:
                got = (None, None, None)  # none in the font: matplotlib measures "lp"
                font: Any = get_font(fontManager._find_fonts_by_props(prop))
                for name, ascent, descent, gap in line_tables:
                    table = font.get_sfnt_table(name)
                    if table is not None:
                        per_em = font.get_sfnt_table("head")["unitsPerEm"]
                        scale = 1 / per_em * prop.get_size_in_points() * self.dpi / 72
                        got = (table[ascent] * scale, -table[descent] * scale, table[gap] * scale)
                        break
                keep(heights, key, got)
            return got

        def draw_text(  # type: ignore[no-untyped-def]
            self, gc, x, y, s, prop, angle, ismath=False, mtext=None
        ) -> None:
            if ismath or not whole_strings or _shaped(mtext):
                return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
            key = (s, prop.copy(), self.dpi, bool(gc.get_antialiased()))
            drawn = bitmaps.get(key)
            if drawn is None:
                self._lay_out(s, prop, key[3])
                drawn = bitmaps[key]
            image, descent, dx, dy = drawn
            # the descent runs along the text's rotated vertical
            rad = math.radians(angle)
            left = round(x + dx + descent * math.sin(rad))
            top = round(y + dy + descent * math.cos(rad))
            self._renderer.draw_text_image(image, left, top + 1, angle, gc)
            return None

    class _KeptRendererCanvas(FigureCanvasAgg):
        def get_renderer(self) -> RendererAgg:
            w, h = self.get_width_height(physical=True)
            key = (w, h, self.figure.dpi)
            kept: dict[Any, RendererAgg] = _RENDERERS.kept
            renderer = kept.pop(key, None)
            if renderer is None:
                renderer = _Renderer(w, h, self.figure.dpi)
            kept[key] = renderer  # the most recent last
            while len(kept) > _KEEP_RENDERERS:
                kept.pop(next(iter(kept)))
            self.renderer = renderer
            return renderer

    return _KeptRendererCanvas


_STRONG = re.compile(r"\*\*(.+?)\*\*")
_CODE = re.compile(r"`([^`]+)`")
# compiled once: a campaign report runs them on every line and table cell, and
# `re.match(text, ...)` looks each up in a cache that other libraries churn
_HEADING = re.compile(r"^(#{1,6})\s+(.*)$")
_IMAGE = re.compile(r"^!\[(.*?)\]\((.*?)\)$")
_RULE_CELL = re.compile(r":?-+:?")
_BLOCK_START = re.compile(r"^(#|\||!\[|- |\* |<details|</details>|<summary>|```)")
_TITLE_MARKS = re.compile(r"^#+\s*")
_LINK = re.compile(r"\[([^\]]+)\]\((#[A-Za-z0-9_.:-]+)\)")
# the raw HTML our reports use to fold a section: passed through as it is
_RAW = re.compile(
    r"^(<details( id=\"[A-Za-z0-9_.:-]+\")?( open)?>|</details>|<summary>.*</summary>)$"
)


def _inline(text: str) -> str:
    out = html.escape(text, quote=False)
    # most cells of a campaign's tables have neither: skip the two searches
    if "**" in out:
        out = _STRONG.sub(r"<strong>\1</strong>", out)
    if "`" in out:
        out = _CODE.sub(r"<code>\1</code>", out)
    if "](#" in out:
        out = _LINK.sub(r'<a href="\2">\1</a>', out)
    return out


# a printed figure is scaled to one page only up to this height over width: 9 in tall,
# it is then still 3.5 in wide, about half the page, and its labels readable
_PAGE_ASPECT = 2.6


def _fits_a_page(png: bytes) -> bool:
    """Whether a PNG (its size from the IHDR chunk) prints on one page at a readable
    width; bytes that are not a PNG are left to run on."""
    if len(png) < 24 or png[:8] != b"\x89PNG\r\n\x1a\n" or png[12:16] != b"IHDR":
        return False
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    return width > 0 and height / width <= _PAGE_ASPECT


def markdown_to_html(markdown: str, images: Mapping[str, bytes] | None = None) -> str:
    """Convert the Markdown our reports produce (headings, paragraphs, lists, tables,
    images) into HTML; ``![alt](name)`` whose name is in `images` is embedded as base64."""
    images = images or {}
    lines = markdown.splitlines()
    out: list[str] = []
    i = 0
    n_images = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if not stripped:
            i += 1
            continue
        heading = _HEADING.match(stripped)
        image = _IMAGE.match(stripped)
        if _RAW.match(stripped):
            out.append(stripped)
            i += 1
        elif stripped.startswith("```"):
            # a fenced block (the campaign's config): kept verbatim, escaped
            block = []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith("```"):
                block.append(lines[i])
                i += 1
            i += 1
            out.append("<pre><code>" + html.escape("\n".join(block)) + "</code></pre>")
        elif heading:
            level = len(heading.group(1))
            out.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
            i += 1
        elif image:
            alt, src = image.group(1), image.group(2)
            fits = ""
            if src in images:
                data = base64.b64encode(images[src]).decode("ascii")
                src_attr = f"data:image/png;base64,{data}"
                fits = ' class="page"' if _fits_a_page(images[src]) else ""
            else:
                src_attr = html.escape(src)
            # every image but the first few waits until it is scrolled to or unfolded
            lazy = ' loading="lazy"' if n_images >= 2 else ""
            n_images += 1
            out.append(f'<img alt="{html.escape(alt)}"{fits}{lazy} src="{src_attr}">')
            i += 1
        elif stripped.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(lines[i].strip())
                i += 1
            cells = [[c.strip() for c in r.strip("|").split("|")] for r in rows]
            body = [r for r in cells if not all(_RULE_CELL.fullmatch(c) for c in r if c)]
            table = ["<table>"]
            for k, row in enumerate(body):
                tag = "th" if k == 0 else "td"
                table.append(
                    "<tr>" + "".join(f"<{tag}>{_inline(c)}</{tag}>" for c in row) + "</tr>"
                )
            table.append("</table>")
            out.append("\n".join(table))
        elif stripped.startswith(("- ", "* ")):
            items = []
            while i < len(lines) and lines[i].strip().startswith(("- ", "* ")):
                items.append(f"<li>{_inline(lines[i].strip()[2:])}</li>")
                i += 1
            out.append("<ul>" + "".join(items) + "</ul>")
        else:
            # the first line always: one that looks like a block but is none of them (raw
            # HTML of another form) is text, and the loop must move on
            para = [stripped]
            i += 1
            while i < len(lines) and lines[i].strip() and not _BLOCK_START.match(lines[i].strip()):
                para.append(lines[i].strip())
                i += 1
            out.append(f"<p>{_inline(' '.join(para))}</p>")
    title = next((_TITLE_MARKS.sub("", ln) for ln in lines if ln.startswith("# ")), "AeroID report")
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        + "\n".join(out)
        + "\n</body>\n</html>\n"
    )


@functools.lru_cache(maxsize=1)
def _umask() -> int:
    mask = os.umask(0)  # the only way to read it is to set it
    os.umask(mask)
    return mask


def _atomic_write(path: Path, data: bytes) -> None:
    """Write `path` whole or not at all (a temporary beside it, then a rename)."""
    from ..errors import OutputError

    try:
        if path.is_dir():
            raise IsADirectoryError(21, "it is a directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    try:
        # mkstemp makes the file private (0600); a report gets the usual permissions
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
        raise


def write_report_bundle(
    markdown: str, figures: Mapping[str, Figure], path: str | os.PathLike[str]
) -> tuple[Path, Path]:
    """Write ``path`` (Markdown, figures as PNG files beside it) and a self-contained
    HTML twin (``path`` with suffix ``.html``, images embedded).

    Figures are referenced at the end of the Markdown under "Figures" unless the
    text already references them. Returns (markdown path, html path).
    """
    from ..errors import OutputError

    md_path = Path(path)
    html_path = md_path.with_suffix(".html")
    for target in (md_path, html_path):  # before a figure is written: no partial bundle
        if target.is_dir():
            raise OutputError(f"cannot write {target}: it is a directory")
    pngs = {f"{md_path.stem}_figures/{name}.png": figure_png(fig) for name, fig in figures.items()}
    text = markdown.rstrip() + "\n"
    missing = [k for k in pngs if k not in text]
    if missing:
        text += "\n## Figures\n\n" + "\n\n".join(f"![{Path(k).stem}]({k})" for k in missing) + "\n"
    for rel, data in pngs.items():
        _atomic_write(md_path.parent / rel, data)
    _atomic_write(md_path, text.encode("utf-8"))
    _atomic_write(html_path, markdown_to_html(text, pngs).encode("utf-8"))
    return md_path, html_path
