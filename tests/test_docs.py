"""The README and the reference in docs/: every link leads somewhere, and docs/commands.md names every option.

The README is a newcomer's first read and links the reference; a page moved or renamed, a heading
reworded or an option added without a word would leave a reader at a dead end, so each is checked here
on the files themselves (the command lines' own ``--help``, run in this process).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import groundstation.cli
import vehicle.cli

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)
SUBCOMMANDS = [(vehicle.cli, "vehicle", name) for name in ("sim", "agent", "experiment", "sweep", "scene")] + \
              [(groundstation.cli, "groundstation", name) for name in ("demo", "serve", "replay")]


def prose(path: Path) -> str:
    """The page without its code blocks (a shell line's brackets are no link, nor its ``#`` a heading)."""
    return FENCE.sub("", path.read_text(encoding="utf-8"))


def anchor(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {anchor(h) for h in re.findall(r"^#{1,6} (.+)$", prose(path), flags=re.MULTILINE)}


def local_links(path: Path) -> list[str]:
    return [target for target in LINK.findall(prose(path)) if not re.match(r"[a-z]+:", target)]


def test_the_readme_is_a_first_read_and_links_every_page_of_the_reference():
    readme = ROOT / "README.md"
    assert len(readme.read_text(encoding="utf-8").splitlines()) < 250
    linked = {(readme.parent / target.partition("#")[0]).resolve() for target in local_links(readme)}
    assert {page.resolve() for page in PAGES[1:]} <= linked


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_link_names_a_file_and_a_heading_there(page):
    targets = local_links(page)
    assert page.name not in ("README.md", "commands.md") or targets
    for target in targets:
        path, _, fragment = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        assert dest.is_file(), f"{page.name} links {target}: no such file"
        assert dest.is_relative_to(ROOT), f"{page.name} links {target}, outside the checkout"
        if fragment:
            assert dest.suffix == ".md" and fragment in anchors(dest), f"{page.name} links {target}: no such heading"


def help_options(module, program: str, name: str, capsys) -> set[str]:
    """The options ``PROGRAM NAME --help`` lists (but --help itself)."""
    with pytest.raises(SystemExit):
        module.main([name, "--help"])
    text = capsys.readouterr().out
    assert text.startswith(f"usage: {program} {name}")
    return set(re.findall(r"^  (--[a-z][-a-z]*)", text, flags=re.MULTILINE)) - {"--help"}


@pytest.mark.parametrize(("module", "program"), [(vehicle.cli, "vehicle"), (groundstation.cli, "groundstation")])
def test_docs_commands_has_a_section_for_every_subcommand(module, program, capsys):
    with pytest.raises(SystemExit):
        module.main(["--help"])
    listed = re.search(r"\{([a-z,]+)\}", capsys.readouterr().out).group(1).split(",")
    headings = re.findall(r"^### `(\S+) (\S+)`$", (ROOT / "docs" / "commands.md").read_text(encoding="utf-8"),
                          flags=re.MULTILINE)
    assert {name for prog, name in headings if prog == program} == set(listed)
    assert {(program, name) for _, program_, name in SUBCOMMANDS if program_ == program} <= set(headings)


@pytest.mark.parametrize(("module", "program", "name"), SUBCOMMANDS, ids=[f"{p} {n}" for _, p, n in SUBCOMMANDS])
def test_docs_commands_names_every_option_of_each_command(module, program, name, capsys):
    text = (ROOT / "docs" / "commands.md").read_text(encoding="utf-8")
    match = re.search(rf"^### `{program} {name}`\n(.*?)(?=^##)", text + "\n##", flags=re.MULTILINE | re.DOTALL)
    assert match, f"docs/commands.md has no section for {program} {name}"
    options = help_options(module, program, name, capsys)
    assert options
    if program == "groundstation" and name != "serve":  # demo and replay take serve's options, said so once
        assert "options of `groundstation serve`" in match.group(1) or "server options" in match.group(1)
        options -= help_options(groundstation.cli, "groundstation", "serve", capsys)
    missing = {option for option in options if not re.search(rf"{option}(?![-a-z])", match.group(1))}
    assert not missing, f"docs/commands.md does not name {sorted(missing)} under {program} {name}"


@pytest.mark.parametrize(("module", "program", "name"), SUBCOMMANDS, ids=[f"{p} {n}" for _, p, n in SUBCOMMANDS])
def test_the_usage_in_docs_commands_names_only_options_the_command_has(module, program, name, capsys):
    text = (ROOT / "docs" / "commands.md").read_text(encoding="utf-8")
    usage = re.search(rf"^### `{program} {name}`\n\n```\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)
    assert usage, f"docs/commands.md shows no usage of {program} {name}"
    shown = set(re.findall(r"--[a-z][-a-z]*", re.sub(r"\[server options[^\]]*\]", "", usage.group(1))))
    assert shown
    assert shown <= help_options(module, program, name, capsys)
