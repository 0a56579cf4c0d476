"""The documentation is true: the README is short, every ``smplik`` command and option it or a docs page
names exists, its quick start runs, and relative links point to files of the repository."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from smplik.cli.main import COMMANDS, app, load_command

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
PAGES = [README, *sorted((REPO / "docs").glob("*.md"))]
README_LIMIT = 25_000


def code_blocks(text: str, language: str | None = None) -> list[str]:
    blocks = re.findall(r"^```(\w*)\n(.*?)^```", text, flags=re.S | re.M)
    return [body for lang, body in blocks if language is None or lang == language]


def smplik_commands(page: Path) -> list[str]:
    """Every ``smplik ...`` command line in the page's code blocks and in its inline code (tables)."""
    text = page.read_text()
    found = []
    for body in code_blocks(text):
        joined = body.replace("\\\n", " ")
        for line in joined.splitlines():
            line = line.split("#", 1)[0].strip()
            if line.startswith("smplik ") or line.startswith("pip install") and "&& smplik " in line:
                found.append(line[line.index("smplik "):])
    outside = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    found += [m for m in re.findall(r"`(smplik [^`]+)`", outside)]
    return found


def resolve(command: str):
    """(click command, its path) named by a ``smplik ...`` line; the words after the path are arguments."""
    words = shlex.split(command.replace("|", " ").replace("[", " ").replace("]", " ").replace("(", " ")
                        .replace(")", " "), posix=True)[1:]
    if words and words[0].startswith("-"):  # an option of `smplik` itself
        return load_command_tree(), [], words
    assert words and words[0] in COMMANDS, f"{command!r}: no command {words[:1]}"
    cmd, path = load_command(words[0]), [words[0]]
    for word in words[1:]:
        subs = getattr(cmd, "commands", None)
        if not subs:
            break
        assert word in subs, f"{command!r}: {' '.join(path)} has no subcommand {word!r}"
        cmd, path = subs[word], [*path, word]
    assert not getattr(cmd, "commands", None) or len(words) == len(path), \
        f"{command!r}: {' '.join(path)} needs a subcommand"
    return cmd, path, words


def load_command_tree():
    import typer

    return typer.main.get_command(app)


def all_documented_commands() -> list[tuple[str, str]]:
    return [(page.name, c) for page in PAGES for c in smplik_commands(page)]


def test_readme_is_short_and_names_commands():
    text = README.read_text()
    assert len(text) <= README_LIMIT, f"README.md has {len(text)} characters; keep it under {README_LIMIT}"
    named = {path[0] for path in (resolve(c)[1] for c in smplik_commands(README)) if path}
    assert named == set(COMMANDS), f"README's commands table misses {set(COMMANDS) - named}"


@pytest.mark.parametrize("page,command", all_documented_commands(), ids=lambda x: x if len(x) < 60 else x[:60])
def test_documented_command_and_its_options_exist(page, command):
    cmd, path, words = resolve(command)
    options = {opt for param in cmd.params for opt in (*param.opts, *param.secondary_opts)}
    for word in words:
        if word == "--":  # the words after it are another command's options (`smplik batch JOB ... -- OPTIONS`)
            break
        name = word.split("=", 1)[0]
        if name.startswith("--") and name != "--help":
            assert name in options, f"{page}: `{command}`: {' '.join(path)} has no option {name}"
    res = CliRunner().invoke(app, [*path, "--help"])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_point_to_files(page):
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    for link in links:
        if re.match(r"^[a-z]+:", link) or link.startswith("#"):
            continue
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        assert target.exists(), f"{page.name}: link {link} -> {target} does not exist"
        assert REPO in target.parents or target == REPO, f"{page.name}: link {link} leaves the repository"
        if anchor and target.suffix == ".md":
            assert anchor in heading_anchors(target), f"{page.name}: link {link}: no such heading in {target.name}"


def heading_anchors(page: Path) -> set[str]:
    """GitHub's anchors of the page's headings (lower case, punctuation dropped, spaces as hyphens)."""
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)
    headings = re.findall(r"^#+ (.+)$", text, flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


def test_docs_name_no_files_outside_the_repository():
    for page in PAGES:
        text = page.read_text()
        assert "../shared" not in text and "/work/" not in text, page.name


def test_readme_quick_start_runs(tmp_path, monkeypatch):
    """The README's Python quick start and its `smplik solve` on the README's effector file."""
    SHIPPED = REPO / "smplik" / "checkpoints" / "smplik_cmu.pt"  # as tests/conftest.py (two conftest modules)
    if not SHIPPED.is_file():
        pytest.skip(f"the shipped model {SHIPPED} is absent")
    monkeypatch.chdir(tmp_path)
    text = README.read_text()
    python = code_blocks(text, "python")[0]
    exec(compile(python, "README.md", "exec"), {})
    pose = json.loads((tmp_path / "pose.json").read_text())
    assert len(pose["body_pose"]) == 23 and pose["gender"] == "female"
    effector_file = next(b for b in code_blocks(text, "json") if '"smplik-effectors"' in b)
    (tmp_path / "effectors.json").write_text(effector_file)
    res = CliRunner().invoke(app, ["solve", "effectors.json", "--out", "solved.json"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "solved.json").read_text())["gender"] == "female"


def test_ci_runs_the_readme_test_command():
    """`.ci/run` runs exactly the README's test command (set-up command 2)."""
    readme_bash = "\n".join(code_blocks(README.read_text(), "bash"))
    command = next(line.strip() for line in readme_bash.splitlines()
                   if line.startswith("pip install") and "pytest" in line)
    ci = (REPO / ".ci" / "run").read_text()
    assert any(line.strip() == command for line in ci.splitlines()), command
