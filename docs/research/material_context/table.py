"""Markdown tables of ``results_context.json``: per scene and row median / p95 / fraction under
0.03, the share of the median gap (default -> ``present``) the row closes, and CPU seconds.

    ../../../.venv/bin/python table.py [row ...]
"""

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENES = ("woven-fabric", "halftone-print", "glossy-mosaic", "dark-still-life")


def main():
    results = json.loads((HERE / "results_context.json").read_text())
    wanted = sys.argv[1:]
    for scene in SCENES:
        rows = results.get(scene)
        if not rows:
            continue
        gap = rows["default"]["median"] - rows["present"]["median"]
        print(
            f"\n{scene}\n\n| row | median | p95 | < 0.03 | gap closed | CPU-s |\n"
            "|---|---|---|---|---|---|"
        )
        for name, r in rows.items():
            if wanted and name not in wanted and name not in ("present", "nearest-3", "default"):
                continue
            closed = (rows["default"]["median"] - r["median"]) / gap
            cpu = f"{r['cpu_s']:.0f}" if "cpu_s" in r else ""
            print(
                f"| {name} | {r['median']:.4f} | {r['p95']:.3f} | {100 * r['frac<0.03']:.1f} % | "
                f"{100 * closed:.0f} % | {cpu} |"
            )


if __name__ == "__main__":
    main()
