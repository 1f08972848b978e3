"""Save the figures embedded in a run's report.html as PNG files, for the docs.

Each figure is written as PREFIX + its name (coverage, scatter, frames, map, mesh: the image's
alt text in the report) + .png:

    python benchmarks/report_figures.py data/real-w03/clip/report.html --prefix docs/real_clip_ \
        --figures coverage frames
"""

from __future__ import annotations

import argparse
import base64
import re
import sys
from pathlib import Path

FIGURE = re.compile(r'<img alt="([^"]+)" src="data:image/png;base64,([^"]+)">')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, help="a report.html written by c2d2 run")
    parser.add_argument("--prefix", required=True, help="output path prefix, e.g. docs/clip_")
    parser.add_argument("--figures", nargs="+", help="names to save (default: all)")
    args = parser.parse_args()
    found = dict(FIGURE.findall(args.report.read_text()))
    wanted = args.figures or list(found)
    missing = [name for name in wanted if name not in found]
    if missing:
        sys.exit(f"{args.report}: no figure named {', '.join(missing)} (it has "
                 f"{', '.join(found) or 'none'})")
    for name in wanted:
        path = Path(f"{args.prefix}{name}.png")
        path.write_bytes(base64.b64decode(found[name]))
        print(path)


if __name__ == "__main__":
    main()
