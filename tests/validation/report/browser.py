"""A report as a reviewer sees it: rendered by headless Chromium (Debian's package; CI
installs it), its first screen taken as a screenshot and its layout measured in the page.

`first_screen(page, tmp)` opens the page at 1280x900 and at 900 px wide and returns what a
reviewer sees first: where the verdict is and what it says, the screenshot, and what does
not fit (tables wider than the page or their box, figures shrunk or without labelled axes).
The page itself carries no script: the measuring one is added to a copy of it.
"""
from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np

CHROMIUM = Path(shutil.which("chromium") or "/usr/bin/chromium")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-extensions",
         "--hide-scrollbars", "--mute-audio"]

_PROBE = """<script>
window.addEventListener('load', function () {
  var out = {width: document.documentElement.clientWidth, pageWidth: document.documentElement.scrollWidth};
  var v = document.getElementById('verdict');
  if (v) {
    var r = v.getBoundingClientRect();
    out.verdict = {top: r.top, bottom: r.bottom, left: r.left, text: v.textContent,
                   border: getComputedStyle(v).borderLeftColor};
  }
  out.tables = [];
  document.querySelectorAll('table').forEach(function (t) {
    var box = t.parentElement;
    out.tables.push({lead: !!t.closest('div.lead'), right: t.getBoundingClientRect().right,
                     scroll: box.scrollWidth, box: box.clientWidth});
  });
  out.figures = [];
  document.querySelectorAll('figure img').forEach(function (i) {
    out.figures.push({alt: i.alt, natural: i.naturalWidth, shown: i.getBoundingClientRect().width});
  });
  var pre = document.createElement('pre');
  pre.id = 'probe';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def run(args, tmp):
    """Chromium with `args`, its profile in tmp."""
    return subprocess.run([str(CHROMIUM), *FLAGS, f"--user-data-dir={Path(tmp) / 'chromium-profile'}", *args],
                          capture_output=True, text=True, timeout=120)


def measure(page, tmp, width):
    """The probe's measurements of `page` (a path) in a window `width` px wide (dict)."""
    copy = Path(tmp) / f"probe-{width}-{Path(page).name}"
    copy.write_text(Path(page).read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    r = run([f"--window-size={width},900", "--virtual-time-budget=5000", "--dump-dom", copy.resolve().as_uri()], tmp)
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r'<pre id="probe">(.*?)</pre>', r.stdout, re.S)
    assert m, "the page did not load in Chromium"
    return json.loads(html.unescape(m.group(1)))


def screenshot(page, tmp, out, width=1280, height=900):
    """The first screen of `page` as Chromium shows it, saved to `out`; an (H, W, 3) array."""
    from matplotlib.image import imread

    r = run([f"--window-size={width},{height}", f"--screenshot={out}", Path(page).resolve().as_uri()], tmp)
    assert r.returncode == 0 and Path(out).is_file(), r.stderr[-2000:]
    return imread(out)[..., :3]


def _rgb(css):
    return np.array([int(v) for v in re.findall(r"\d+", css)[:3]], float) / 255.0


def first_screen(page, tmp, shot):
    """(verdict text, problems): what the first 1280x900 screen of `page` shows, its
    screenshot saved to `shot`. Problems: the verdict missing, below the first screen or
    not drawn there; a table overflowing its box or the page; a figure without labelled
    axes; at 900 px a figure shrunk below 90 % or the page wider than the window."""
    problems = []
    wide = measure(page, tmp, 1280)
    img = screenshot(page, tmp, shot)
    v = wide.get("verdict")
    if v is None:
        return None, ["no verdict on the page"]
    if not (0 <= v["top"] and v["bottom"] <= img.shape[0]):
        problems.append(f"the verdict is not in the first screen (at {v['top']:.0f}-{v['bottom']:.0f} px)")
    else:  # drawn there: the verdict's coloured border, in the screenshot, where the page puts it
        y = int((v["top"] + v["bottom"]) / 2)
        x = int(v["left"]) + 2
        if np.abs(img[y, x] - _rgb(v["border"])).max() > 0.1:
            problems.append(f"the screenshot shows no verdict at ({x}, {y})")
    for t in wide["tables"]:
        if t["scroll"] > t["box"] + 1 or t["right"] > wide["width"] + 1:
            problems.append(f"a table overflows at 1280 px ({t['scroll']} px in a {t['box']} px box)")
    for f in wide["figures"]:
        alt = f["alt"]  # "ALT (image)" or "ALT (x: LABEL; y: LABEL | ...)", figures.plot_of
        if not (alt.endswith("(image)") or ("x: " in alt and "y: " in alt and "(none)" not in alt)):
            problems.append(f"figure {f['alt'][:60]!r} has no labelled axes")
    narrow = measure(page, tmp, 900)
    if narrow["pageWidth"] > narrow["width"] + 1:
        problems.append(f"at 900 px the page is {narrow['pageWidth']} px wide")
    for t in narrow["tables"]:
        if t["lead"] and t["scroll"] > t["box"] + 1:
            problems.append("at 900 px the verdict's table overflows")
    for f in narrow["figures"]:
        if f["shown"] < 0.9 * f["natural"]:
            problems.append(f"at 900 px figure {f['alt'][:40]!r} is shown at {f['shown']:.0f} of {f['natural']} px")
    shutil.rmtree(Path(tmp) / "chromium-profile", ignore_errors=True)
    return v["text"], problems
