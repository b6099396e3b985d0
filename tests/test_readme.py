"""The README is a manual that starts with the two set-up commands and stays short."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_starts_with_the_two_set_up_commands():
    first_block = re.search(r"```bash\n(.*?)```", README.read_text(), re.S).group(1)
    commands = [line.split("#")[0].strip() for line in first_block.splitlines() if line.strip()]
    assert commands == ["make demo", "make test"]


def test_readme_is_a_manual_of_at_most_300_lines_with_no_path_outside_the_repository():
    text = README.read_text()
    assert len(text.splitlines()) <= 300
    assert "../shared" not in text
