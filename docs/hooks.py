"""MkDocs hooks: pages generated from the code and the benchmarks when the site is built.

* reference/scene_keys.md: the scene-key reference (poevp_optics/scene/reference.py), from the
  params dataclasses and their registries;
* results/<benchmark>.md: one page per benchmark from the current files in benchmarks/results/
  (its tables as the script wrote them, then its plots), and their list on results/index.md.

Nothing is written into docs/: the pages exist only in the build (mkdocs File.generated), so they
can never be stale.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
#: Result folders written by a benchmark of another name.
FOLDER_GROUP = {"loop": "loop_comparison"}

if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _scripts() -> dict[str, str]:
    """Benchmark script name -> its source text."""
    return {p.stem: p.read_text() for p in sorted((ROOT / "benchmarks").glob("*.py"))
            if p.stem not in ("__init__", "__main__", "common")}


def result_groups() -> dict[str, dict]:
    """Benchmark page name -> {"script": name or None, "md": [paths], "png": [paths]}."""
    scripts = _scripts()
    groups: dict[str, dict] = {}

    def group_of(path: Path) -> tuple[str, str | None]:
        rel = path.relative_to(RESULTS)
        if len(rel.parts) > 1:
            name = FOLDER_GROUP.get(rel.parts[0], rel.parts[0])
            return name, name if name in scripts else ("evaluate" if rel.parts[0].startswith("evaluate") else None)
        stem = path.stem
        pref = [s for s in scripts if stem == s or stem.startswith(s + "_")]
        if pref:
            s = max(pref, key=len)
            return s, s
        mds = [p.stem for p in RESULTS.glob("*.md") if stem == p.stem or stem.startswith(p.stem + "_")]
        if mds:
            return max(mds, key=len), None
        owner = [s for s, text in scripts.items() if path.name in text]
        return (owner[0], owner[0]) if owner else (stem, None)

    for path in sorted(RESULTS.rglob("*")):
        if path.suffix not in (".md", ".png") or "runs" in path.relative_to(RESULTS).parts:
            continue
        name, script = group_of(path)
        g = groups.setdefault(name, {"script": script, "md": [], "png": []})
        g["md" if path.suffix == ".md" else "png"].append(path)
    return {k: v for k, v in sorted(groups.items()) if v["md"]}


def _demote(text: str) -> str:
    """Headings one level down (the page title is the benchmark's name)."""
    return re.sub(r"(?m)^(#{1,5}) ", r"#\1 ", text)


def result_page(name: str, g: dict) -> str:
    out = [f"# {name}", ""]
    if g["script"] == "evaluate":
        out += ["Written by `poevp evaluate` (see [Evaluation](../guides/evaluation.md)).", ""]
    elif g["script"]:
        out += [f"Written by `.venv/bin/python -m benchmarks.{g['script']} --results` (without `--results` "
                "the script writes into `out/benchmarks/`).", ""]
    mds = sorted(g["md"], key=lambda p: (p.stem != name, str(p)))
    for p in mds:
        rel = p.relative_to(RESULTS)
        out += [f"<small>`benchmarks/results/{rel}`</small>", "", _demote(p.read_text()).strip(), ""]
    for p in g["png"]:
        rel = p.relative_to(RESULTS)
        out += [f"![{rel}]({rel.as_posix()})", ""]
    return "\n".join(out) + "\n"


def on_config(config):
    """The results pages join the nav's Results section."""
    for item in config["nav"]:
        if isinstance(item, dict) and "Results" in item:
            item["Results"] = ["results/index.md", *(f"results/{n}.md" for n in result_groups())]
    return config


def on_files(files, config):
    from poevp_optics.scene.reference import markdown

    files.append(File.generated(config, "reference/scene_keys.md", content=markdown()))
    for name, g in result_groups().items():
        files.append(File.generated(config, f"results/{name}.md", content=result_page(name, g)))
        for p in g["png"]:
            rel = p.relative_to(RESULTS).as_posix()
            files.append(File.generated(config, f"results/{rel}", abs_src_path=str(p)))
    return files


def on_page_markdown(markdown, page, config, files):
    if page.file.src_uri == "results/index.md":
        rows = ["| benchmark | files |", "|---|---|"]
        for name, g in result_groups().items():
            rows.append(f"| [{name}]({name}.md) | " + ", ".join(
                f"`{p.relative_to(RESULTS)}`" for p in g["md"]) + " |")
        return markdown + "\n" + "\n".join(rows) + "\n"
    return markdown
