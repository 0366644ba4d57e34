"""Screenshot an HTML page in headless Chromium at 1280 px wide, cropped to the page.

    python tools/screenshot.py PAGE.html OUT.png [--width 1280]

Prints the page's height in px (the last row that is not background). Needs a `chromium`
binary (Debian: apt install chromium); used to look at the report, compare and sweep pages.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

TALL = 30_000  # px: taller than any page the bench writes


def screenshot(page: Path, out: Path, width: int = 1280) -> int:
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        raise SystemExit("no chromium binary (Debian: apt install chromium)")
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw.png"
        subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
             f"--user-data-dir={tmp}/profile", f"--window-size={width},{TALL}",
             f"--screenshot={raw}", page.resolve().as_uri()],
            check=True, capture_output=True, timeout=120,
        )  # fmt: skip
        img = Image.open(raw).convert("RGB")
    pixels = np.asarray(img)
    rows = np.nonzero((pixels != pixels[-1, -1]).any(axis=(1, 2)))[0]
    height = int(rows[-1]) + 20 if rows.size else 1
    img.crop((0, 0, width, height)).save(out)
    return height


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("page", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--width", type=int, default=1280)
    a = p.parse_args(argv)
    print(f"{a.out}: {a.width} x {screenshot(a.page, a.out, a.width)} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
