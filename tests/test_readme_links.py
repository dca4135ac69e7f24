"""Every relative link of the README reaches a file of the repository (the docs pages are checked by
``mkdocs build --strict``, the README is not part of the site)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)|src=\"([^\"]+)\"")


def test_readme_relative_links_reach_files():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = [a or b for a, b in LINK.findall(text)]
    relative = [t.split("#")[0] for t in targets if not re.match(r"[a-z]+:|#", t)]
    assert any(t.startswith("docs/") for t in relative)      # the README points into the docs
    missing = [t for t in relative if not (ROOT / t).is_file()]
    assert not missing, f"README.md links to files that do not exist: {missing}"
