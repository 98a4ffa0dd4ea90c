"""The documentation site builds with `mkdocs build --strict` (warnings are errors: broken links,
pages left out of the nav, docstrings mkdocstrings cannot render), as `make docs` runs it, and
holds the generated scene-key reference and one results page per benchmark."""

from __future__ import annotations

import os
import subprocess
import sys

from tests.conftest import ROOT


def test_docs_build_strict(tmp_path):
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    keys = (site / "reference" / "scene_keys" / "index.html").read_text()
    assert "exposure_controller" in keys and "dmd.registration" in keys
    results = ROOT / "benchmarks" / "results"
    for md in results.glob("*.md"):           # every current result is on a page of the site
        pages = " ".join(p.read_text() for p in (site / "results").glob("*/index.html"))
        assert md.name in pages, md.name
    assert (site / "results" / "recognition_examples.png").is_file()


def test_readme_is_short_and_its_links_resolve():
    import re

    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 150
    assert "## What poevp guarantees" in readme and "make demo" in readme and "make test" in readme
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", readme)
    assert len(links) >= 10
    for link in links:
        if not link.startswith("http"):
            assert (ROOT / link).exists(), link
