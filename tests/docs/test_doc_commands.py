"""Every shell command that README.md and docs/**/*.md show runs, as written, from a fresh copy of
the repository, and writes nothing into its tracked files.

What runs: each shell block of a page (4-space indented, or fenced ```bash / ```sh / ```console),
recognised by its first word (`poevp`, `make`, `.venv/bin/...`, `cp`, `dask`, ...; TOML, Python
and XML snippets are not commands), command by command (`\\` continuations joined, `# comments`
kept for bash to drop), in page order, in one temporary copy of the repository per page (the
files git tracks or would: `git ls-files --cached --others --exclude-standard`), with the
repository's `.venv` linked in and the copy's package first on PYTHONPATH, as an editable install
in a fresh clone would have it. `poevp` is on PATH (the installed
`.venv/bin/poevp`); bare `python` is not the venv's (a newcomer's shell): commands call
`.venv/bin/python`. `make TARGET` runs with its `install` prerequisite taken as done (`make -o
install`): the suite already runs inside the installed .venv.

Size: the environment variable POEVP_SCALE (`SCALE` below) sizes every run's camera down, as the
pages say once. A marker on the line before a block (an HTML comment, invisible on the site)
changes how it runs:

* `<!-- docs-test: run-with: ARGS -->`: ARGS appended to each `poevp` / `.venv/bin/python` command
  of the block (for `make TARGET`: to the commands of its recipe, `make -n`): a quick but real run.
* `<!-- docs-test: skip: REASON -->`: not run; each command is still checked to exist (`poevp SUB
  --help`, `.venv/bin/python -m MODULE --help`, a script's file, `make -n TARGET`, the executable on
  PATH), and the test is skipped with REASON.
* `<!-- docs-test: edit: PATH -->` before a TOML snippet: the step "put this into PATH" (each of
  its tables replaces the file's table of the same name, or is added).

After each block, no tracked file of the copy has changed and every new file outside the
git-ignored folders is a path one of the page's commands names, lies under one, or sits beside one
with its stem (a weights file's .json record). A failure names the page,
line and command and shows the last lines of its output.
"""

from __future__ import annotations

import hashlib
import os
import re
import shlex
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VENV = ROOT / ".venv"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
#: POEVP_SCALE for every command: the camera at 1/6 of each scene's mirrors (night_road: 180x320).
SCALE = "1/6"
#: Seconds one command may take before it fails (the markers keep each one to seconds).
COMMAND_TIMEOUT_S = 300
#: First words of a shell command (a block whose first command starts otherwise is a snippet).
SHELL_WORDS = {"poevp", "make", "python", "python3", "pip", "cp", "mv", "rm", "mkdir", "cd", "ls", "cat",
               "du", "dask", "openssl", "bash", "sh", "git", "srun", "sbatch", "kubectl", "export", "source",
               "curl", "tar", "scp", "ssh"}
#: Executables of the venv a newcomer runs by name once .venv/bin is on PATH (first-render.md).
ON_PATH = ("poevp", "dask")
#: Folders .gitignore keeps out of the repository: new files there are outputs.
#: Variables a parent make exports to its children.
MAKE_VARS = ("MAKELEVEL", "MAKEFLAGS", "MFLAGS", "MAKEOVERRIDES", "MAKE_TERMOUT", "MAKE_TERMERR")
IGNORED = ("out/", "site/", "build/", ".venv/", ".pytest_cache/")
MARKER = re.compile(r"^<!--\s*docs-test:\s*(skip|run-with|edit)\s*:\s*(.*?)\s*-->\s*$")
FENCE = re.compile(r"^(`{3,}|~{3,})\s*([\w+-]*)")


@dataclass
class Command:
    line: int          # 1-based line of the page where the command starts
    text: str          # as shown, continuations joined (bash reads the comment)


@dataclass
class Block:
    page: str          # relative to the repository
    line: int
    lang: str          # fence language, or "" for an indented block
    lines: list[str]   # the block's text lines
    markers: dict[str, str] = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"

    def commands(self) -> list[Command]:
        out, pending, start = [], "", 0
        for i, raw in enumerate(self.lines):
            text = raw.strip()
            if not pending and (not text or text.startswith("#")):
                continue
            if not pending:
                start = self.line + i
            if text.endswith("\\"):
                pending += text[:-1].rstrip() + " "
                continue
            out.append(Command(start, pending + text))
            pending = ""
        if pending:
            out.append(Command(start, pending.strip()))
        return out

    @property
    def is_shell(self) -> bool:
        if self.lang and self.lang not in ("bash", "sh", "shell", "console"):
            return False
        cmds = self.commands()
        return bool(cmds) and first_word(cmds[0].text) in SHELL_WORDS | {"<venv>"}


def first_word(cmd: str) -> str:
    """The command's program, past `VAR=value` assignments and a `$ ` prompt; `<venv>` for
    `.venv/bin/...`."""
    for w in cmd.split():
        if w == "$" or re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", w):
            continue
        return "<venv>" if w.startswith(".venv/bin/") else w
    return ""


def parse_page(path: Path) -> list[Block]:
    """The code blocks of a Markdown page, with the docs-test markers just above each."""
    rel = path.relative_to(ROOT).as_posix()
    lines = path.read_text().splitlines()
    blocks, i = [], 0

    def markers_before(k: int) -> dict[str, str]:
        found, j = {}, k - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        while j >= 0 and (m := MARKER.match(lines[j].strip())):
            found[m.group(1)] = m.group(2)
            j -= 1
            while j >= 0 and not lines[j].strip():
                j -= 1
        return found

    while i < len(lines):
        line = lines[i]
        if m := FENCE.match(line.strip()):
            end = next((j for j in range(i + 1, len(lines)) if lines[j].strip().startswith(m.group(1))), len(lines))
            blocks.append(Block(rel, i + 2, m.group(2) or "text", lines[i + 1:end], markers_before(i)))
            i = end + 1
            continue
        if line.startswith("    ") and line.strip() and (i == 0 or not lines[i - 1].strip()):
            start, body = i, []
            while i < len(lines) and (lines[i].startswith("    ") or not lines[i].strip()):
                body.append(lines[i][4:])
                i += 1
            while body and not body[-1].strip():
                body.pop()
            blocks.append(Block(rel, start + 1, "", body, markers_before(start)))
            continue
        i += 1
    return blocks


ALL_BLOCKS = [b for p in PAGES for b in parse_page(p)]
RUN_BLOCKS = [b for b in ALL_BLOCKS if b.is_shell or "edit" in b.markers]


# ---- the copy of the repository each page runs in -------------------------------------------------


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class PageRun:
    """One page's copy of the repository and how far its blocks have run."""

    def __init__(self, base: Path):
        self.repo = base / "repo"
        self.bin = base / "bin"
        files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.split("\0")
        self.tracked: dict[str, str] = {}
        for rel in filter(None, files):
            src = ROOT / rel
            if not src.is_file() or src.is_symlink():
                continue
            dst = self.repo / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
            self.tracked[rel] = _digest(dst)
        (self.repo / ".venv").symlink_to(VENV)
        self.bin.mkdir()
        for name in ON_PATH:
            (self.bin / name).symlink_to(VENV / "bin" / name)
        # A newcomer's shell, not the `make test` that may run this suite: no MAKELEVEL/MAKEFLAGS
        # (under them a nested make prints "make[1]: Entering directory ...").
        shell = {k: v for k, v in os.environ.items() if k not in MAKE_VARS}
        self.env = {**shell, "PATH": f"{self.bin}{os.pathsep}{os.environ.get('PATH', '')}",
                    "PYTHONPATH": str(self.repo), "POEVP_SCALE": SCALE}
        self.done = -1               # index into the page's blocks of the last block run
        self.named: set[str] = set()  # paths the page's commands name (outputs they may write)

    def run(self, block: Block, cmd: str) -> None:
        try:
            r = subprocess.run(["bash", "-c", cmd], cwd=self.repo, env=self.env, capture_output=True, text=True,
                               timeout=COMMAND_TIMEOUT_S)
        except subprocess.TimeoutExpired as e:
            out = _text(e.stdout) + _text(e.stderr)
            pytest.fail(f"{block.id}: `{cmd}` ran past {COMMAND_TIMEOUT_S} s\n{_tail(out)}", pytrace=False)
        if r.returncode != 0:
            pytest.fail(f"{block.id}: `{cmd}` exited {r.returncode}\n{_tail(r.stdout + r.stderr)}", pytrace=False)

    def check_writes(self, block: Block) -> None:
        changed = [rel for rel, h in self.tracked.items()
                   if not (self.repo / rel).is_file() or _digest(self.repo / rel) != h]
        assert not changed, f"{block.id}: the commands changed tracked files: {changed[:10]}"
        new = []
        for p in self.repo.rglob("*"):
            rel = p.relative_to(self.repo).as_posix()
            if (p.is_dir() or rel in self.tracked or rel.startswith(IGNORED) or "__pycache__" in rel
                    or rel.endswith(".egg-info") or ".egg-info/" in rel):
                continue
            stem = os.path.splitext(rel)[0]
            if not any(rel == n or rel.startswith(n.rstrip("/") + "/") or stem == os.path.splitext(n)[0]
                       for n in self.named):      # the named path, under it, or its record beside it (.json)
                new.append(rel)
        assert not new, (f"{block.id}: the commands wrote files that no command names, outside the "
                         f"git-ignored folders: {new[:10]}")


def _text(out) -> str:
    """A timed-out process's output (bytes, even with text=True) as text."""
    return out.decode(errors="replace") if isinstance(out, bytes) else (out or "")


def _tail(text: str, n: int = 25) -> str:
    lines = text.rstrip().splitlines()
    return "--- last lines of its output ---\n" + "\n".join(lines[-n:])


def _named_paths(cmd: str) -> set[str]:
    """Relative paths a command names (its arguments that look like paths)."""
    try:
        words = shlex.split(cmd, comments=True)
    except ValueError:
        words = cmd.split()
    return {os.path.normpath(w) for w in words
            if ("/" in w or re.search(r"\.\w+$", w)) and not w.startswith(("-", "/", "~", "$")) and "://" not in w}


def with_args(cmd: str, extra: str) -> str:
    """`cmd` with `extra` appended before its trailing `# comment` (outside quotes)."""
    quote, cut = None, len(cmd)
    for i, c in enumerate(cmd):
        if quote:
            quote = None if c == quote else quote
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or cmd[i - 1].isspace()):
            cut = i
            break
    return f"{cmd[:cut].rstrip()} {extra}".strip()


def runs_python_or_poevp(cmd: str) -> bool:
    return first_word(cmd) in ("poevp", "<venv>")


def make_recipe(run: PageRun, cmd: str) -> list[str]:
    """The commands `make ... TARGET` runs (its recipe, `install` taken as done)."""
    r = subprocess.run(["bash", "-c", cmd.replace("make ", "make -n --no-print-directory -o install ", 1)], cwd=run.repo, env=run.env,
                       capture_output=True, text=True)
    assert r.returncode == 0, f"`{cmd}`: no such make target?\n{r.stdout}{r.stderr}"
    return [ln for ln in r.stdout.splitlines() if ln.strip()]


def check_exists(run: PageRun, block: Block, cmd: str) -> None:
    """A command not run is still one that exists: its --help, its make target, its executable."""
    word = first_word(cmd)
    words = shlex.split(cmd, comments=True)
    if word == "make":
        make_recipe(run, cmd)
        return
    if word == "poevp":
        sub = next((w for w in words[1:] if not w.startswith("-")), None)
        run.run(block, "poevp " + (f"{sub} " if sub else "") + "--help")
        return
    if word == "<venv>":
        prog = next(w for w in words if w.startswith(".venv/bin/"))
        rest = words[words.index(prog) + 1:]
        if rest[:1] == ["-m"]:
            run.run(block, f"{prog} -m {rest[1]} --help")
        elif rest and not rest[0].startswith("-"):      # a script: it exists (its --help might run it)
            assert (run.repo / rest[0]).is_file(), f"{block.id}: `{cmd}`: no script {rest[0]}"
        else:
            run.run(block, f"{prog} --help")
        return
    if word == "dask":
        run.run(block, f"dask {words[1]} --help")
        return
    assert shutil.which(word, path=run.env["PATH"]), f"{block.id}: `{cmd}`: no `{word}` on PATH"


def apply_toml(path: Path, snippet: str) -> None:
    """Each table of `snippet` replaces the table of the same name in the TOML file `path` (its
    header line through the line before the next header), or is appended."""
    header = re.compile(r"^\[([^\[\]]+)\]\s*(#.*)?$")

    def tables(text: str) -> list[tuple[str | None, list[str]]]:
        out: list[tuple[str | None, list[str]]] = [(None, [])]
        for ln in text.splitlines():
            m = header.match(ln.strip())
            if m:
                out.append((m.group(1).strip(), []))
            out[-1][1].append(ln)
        return out

    have = tables(path.read_text())
    for name, body in tables(snippet):
        if name is None:
            assert not any(ln.strip() and not ln.strip().startswith("#") for ln in body), \
                f"{path}: keys outside a table in the snippet"
            continue
        while body and not body[-1].strip():
            body.pop()
        body = [*body, ""]
        at = next((k for k, (n, _) in enumerate(have) if n == name), None)
        if at is None:
            have.append((name, body))
        else:
            have[at] = (name, body)
    path.write_text("\n".join(ln for _, body in have for ln in body).rstrip() + "\n")


_RUNS: dict[str, PageRun] = {}


def _page_run(page: str, tmp_path_factory) -> PageRun:
    if page not in _RUNS:
        _RUNS[page] = PageRun(tmp_path_factory.mktemp(re.sub(r"\W", "_", page)))
    return _RUNS[page]


def run_block(run: PageRun, block: Block) -> None:
    """Run one block in the page's copy (the module docstring's rules); skip markers are the
    caller's."""
    if "edit" in block.markers:
        target = run.repo / block.markers["edit"]
        assert target.is_file(), f"{block.id}: edit: {block.markers['edit']} does not exist at this step"
        apply_toml(target, "\n".join(block.lines))
        run.named.add(os.path.normpath(block.markers["edit"]))
        return
    extra = block.markers.get("run-with", "")
    for c in block.commands():
        assert first_word(c.text) not in ("python", "python3", "pip"), (
            f"{block.id}: `{c.text}`: a fresh clone has no `{first_word(c.text)}` with this package: "
            f"write .venv/bin/{first_word(c.text)}")
        run.named |= _named_paths(c.text)
        if first_word(c.text) == "make" and extra:
            for recipe in make_recipe(run, c.text):
                run.run(block, with_args(recipe, extra) if runs_python_or_poevp(recipe) else recipe)
        elif first_word(c.text) == "make":
            run.run(block, c.text.replace("make ", "make -o install ", 1))
        else:
            run.run(block, with_args(c.text, extra) if extra and runs_python_or_poevp(c.text) else c.text)
    run.check_writes(block)


@pytest.mark.slow
@pytest.mark.parametrize("block", RUN_BLOCKS, ids=[b.id for b in RUN_BLOCKS])
def test_doc_block(block: Block, tmp_path_factory):
    """The block runs as written (or as its marker says) after the page's earlier blocks."""
    page_blocks = [b for b in RUN_BLOCKS if b.page == block.page]
    run = _page_run(block.page, tmp_path_factory)
    index = page_blocks.index(block)
    for k in range(run.done + 1, index):        # earlier blocks first, when this one runs alone
        if "skip" not in page_blocks[k].markers:
            run_block(run, page_blocks[k])
        run.done = k
    run.done = index
    if "skip" in block.markers:
        for c in block.commands():
            check_exists(run, block, c.text)
        pytest.skip(f"{block.id}: {block.markers['skip']}")
    run_block(run, block)


def test_blocks_found_and_markers_known():
    """The parser sees the pages' command blocks; every marker sits before a block it applies to."""
    ids = {b.id for b in RUN_BLOCKS}
    assert any(i.startswith("README.md:") for i in ids) and any("own-scene" in i for i in ids)
    for b in ALL_BLOCKS:
        if b.markers:
            assert b.is_shell or set(b.markers) == {"edit"}, f"{b.id}: a docs-test marker on a snippet"
            if "edit" in b.markers:
                assert b.lang == "toml", f"{b.id}: edit markers apply TOML snippets"
    for page in PAGES:
        lines = page.read_text().splitlines()
        for i, ln in enumerate(lines):
            if "docs-test" in ln:
                assert MARKER.match(ln.strip()), f"{page.relative_to(ROOT)}:{i + 1}: malformed marker {ln!r}"


def test_inline_commands_exist():
    """Commands quoted inline in the pages (`poevp SUB ...`, `.venv/bin/python -m MODULE`, `make
    TARGET`) name subcommands, modules and targets that exist, and none is a bare `python -m`."""
    import importlib.util

    sub = subprocess.run([str(VENV / "bin" / "poevp"), "--help"], capture_output=True, text=True).stdout
    subcommands = set(re.search(r"\{([\w,-]+)\}", sub).group(1).split(","))
    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    texts = {p.relative_to(ROOT).as_posix(): p.read_text() for p in PAGES}
    texts["docs/hooks.py"] = (ROOT / "docs" / "hooks.py").read_text()
    for path in (ROOT / "benchmarks" / "results").glob("*.md"):
        texts[path.relative_to(ROOT).as_posix()] = path.read_text()
    bad = []
    for name, text in texts.items():
        for span in re.findall(r"`([^`\n]+)`", text):
            span = span.strip()
            if re.match(r"^(PYTHONPATH=\S+ )?python3? -m ", span):
                bad.append(f"{name}: `{span}`: write .venv/bin/python -m")
            elif m := re.match(r"^\.venv/bin/python -m (\S+)", span):
                mod = m.group(1)
                if re.fullmatch(r"[A-Za-z_][\w.]*", mod) and importlib.util.find_spec(mod) is None:
                    bad.append(f"{name}: `{span}`: no module {mod}")
            elif m := re.match(r"^poevp ([a-z][\w-]*)", span):
                if m.group(1) not in subcommands:
                    bad.append(f"{name}: `{span}`: no subcommand {m.group(1)}")
            elif m := re.match(r"^make ([\w-]+)$", span):
                if m.group(1) not in targets:
                    bad.append(f"{name}: `{span}`: no make target {m.group(1)}")
    assert not bad, "\n".join(bad)


def test_apply_toml_replaces_tables_in_place(tmp_path):
    """The edit step: a snippet's [mask] replaces the file's [mask] (whose header carries a
    comment), a new table is appended, other tables stay."""
    import tomllib

    f = tmp_path / "scene.toml"
    f.write_text('a = 1\n\n[mask]   # pinned\nlaw = "target"\nb = 2\n\n[loop]\nmode = "open"\n')
    apply_toml(f, '[mask]\nlaw = "exposure_controller"\n\n[predictor]\nname = "flow"\n')
    assert tomllib.loads(f.read_text()) == {"a": 1, "mask": {"law": "exposure_controller"},
                                            "loop": {"mode": "open"}, "predictor": {"name": "flow"}}


def test_with_args_goes_before_the_comment():
    assert with_args("poevp chart x --out o   # ~10 s", "--frames 2") == "poevp chart x --out o --frames 2"
    assert with_args('poevp evaluate --texts "KA #1"', "--quick") == 'poevp evaluate --texts "KA #1" --quick'
