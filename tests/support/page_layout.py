"""Layout checks of rendered pages and figures: text boxes that overlap, blank renders.

:func:`browser_overlaps` loads a page in the real headless browser (:mod:`.browser`) with a
script that measures every line of text and every image as laid out, and returns the pairs
that overlap. :func:`figure_overlaps` does the same for the text of a matplotlib figure
(tick labels, titles, legends) as drawn.
"""

from __future__ import annotations

import html
import json
import re
import subprocess
from itertools import combinations
from pathlib import Path

from .browser import browser

# Every text line (one rect per line of a text node) and image, as laid out; overlapping pairs
_MEASURE = """
<script>
window.addEventListener("load", () => {
  const boxes = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  while (walker.nextNode()) {
    const node = walker.currentNode;
    const text = node.textContent.trim();
    if (!text || node.parentElement.closest("script, style")) continue;
    const range = document.createRange();
    range.selectNodeContents(node);
    for (const r of range.getClientRects()) {
      if (r.width > 0 && r.height > 0) boxes.push([r.left, r.top, r.right, r.bottom, text.slice(0, 40)]);
    }
  }
  for (const img of document.images) {
    const r = img.getBoundingClientRect();
    boxes.push([r.left, r.top, r.right, r.bottom, "<img " + (img.alt || "").slice(0, 30) + ">"]);
  }
  const overlaps = [];
  const slack = 1.0;  // px: neighbours that touch do not overlap
  for (let i = 0; i < boxes.length; i++) {
    for (let j = i + 1; j < boxes.length; j++) {
      const a = boxes[i], b = boxes[j];
      const w = Math.min(a[2], b[2]) - Math.max(a[0], b[0]);
      const h = Math.min(a[3], b[3]) - Math.max(a[1], b[1]);
      if (w > slack && h > slack) overlaps.push([a[4], b[4]]);
    }
  }
  const out = document.createElement("pre");
  out.id = "layout-check";
  out.textContent = JSON.stringify({boxes: boxes.length, images: document.images.length,
    broken: [...document.images].filter(i => !i.complete || i.naturalWidth === 0).length,
    overlaps: overlaps.slice(0, 20)});
  document.body.appendChild(out);
});
</script>
"""


def browser_overlaps(page: Path, work: Path, *, width: int = 1280) -> dict:
    """Lay ``page`` out in the headless browser at ``width`` px: how many text lines and
    images it has (``boxes``, ``images``), images that failed to decode (``broken``) and
    the overlapping pairs of text lines or images (``overlaps``, at most 20)."""
    text = page.read_text(encoding="utf-8")
    probe = work / f"{page.stem}-layout.html"
    probe.write_text(text.replace("</body>", _MEASURE + "</body>"), encoding="utf-8")
    done = subprocess.run(
        [
            browser(),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            f"--window-size={width},2000",
            "--virtual-time-budget=10000",
            "--dump-dom",
            probe.absolute().as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    found = re.search(r'<pre id="layout-check">(.*?)</pre>', done.stdout, re.S)
    assert found, "the layout script did not run"
    return json.loads(html.unescape(found.group(1)))


def _drawn_texts(figure) -> list:
    """The texts of ``figure`` that show: tick labels only of ticks inside their axis' view
    (matplotlib keeps spare ticks outside it), every other visible, non-empty text."""
    from matplotlib.text import Text

    ticks, shown = set(), []
    for ax in figure.axes:
        for axis in (ax.xaxis, ax.yaxis):
            low, high = sorted(axis.get_view_interval())
            for tick in [*axis.get_major_ticks(), *axis.get_minor_ticks()]:
                for label in (tick.label1, tick.label2):
                    ticks.add(id(label))
                    inside = (
                        low - 1e-9 * abs(high - low) <= tick.get_loc() <= high + 1e-9 * abs(high - low)
                    )
                    if inside and label.get_visible() and label.get_text().strip():
                        shown.append(label)
    for text in figure.findobj(Text):
        if id(text) not in ticks and text.get_visible() and text.get_text().strip():
            shown.append(text)
    return shown


def figure_overlaps(figure) -> list[tuple[str, str]]:
    """The pairs of texts of a matplotlib ``figure`` whose boxes overlap as drawn."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    renderer = canvas.get_renderer()
    boxes = [(text.get_text(), text.get_window_extent(renderer)) for text in _drawn_texts(figure)]
    return [
        (a, b)
        for (a, box_a), (b, box_b) in combinations(boxes, 2)
        if min(box_a.x1, box_b.x1) - max(box_a.x0, box_b.x0) > 1
        and min(box_a.y1, box_b.y1) - max(box_a.y0, box_b.y0) > 1
    ]
