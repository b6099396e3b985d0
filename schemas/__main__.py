"""``python -m spectralize.schemas`` prints the run-store contract as a Markdown table;
``--update-readme`` rewrites the table in ``schemas/README.md`` (from a source checkout)."""

import re
import sys
from pathlib import Path

from .run import render_table

table = render_table()
if "--update-readme" in sys.argv[1:]:
    readme = Path(__file__).with_name("README.md")
    text = readme.read_text()
    pattern = re.compile(r"(<!-- table: generated, do not edit -->\n).*?(\n<!-- /table -->)", re.S)
    readme.write_text(pattern.sub(lambda m: m.group(1) + table + m.group(2), text))
    print(f"updated {readme}")
else:
    print(table)
