"""MkDocs hook: the pages generated at build time, so that none can drift from its source.

- ``reference/cli.md``: every command's ``--help`` as the CLI prints it;
- ``index.md``: the repository's README (the front page), its links made relative to the site;
- ``changelog.md``: the repository's CHANGELOG.md.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from mkdocs.structure.files import File

PAGE = "reference/cli.md"
WIDTH = 100
ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # the package of this checkout, installed or not
    sys.path.insert(0, str(ROOT))


def _commands(group, path=()):
    """(path, command) of every command under ``group``, the group first, depth first."""
    yield path, group
    for name, command in getattr(group, "commands", {}).items():  # in registration order
        yield from _commands(command, (*path, name))


def _help(app, path) -> str:
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, [*path, "--help"], prog_name="orange-plan",
                                env={"COLUMNS": str(WIDTH), "TERMINAL_WIDTH": str(WIDTH),
                                     "NO_COLOR": "1"})
    if result.exit_code != 0:
        raise RuntimeError(f"orange-plan {' '.join(path)} --help failed: {result.output}")
    return "\n".join(line.rstrip() for line in result.output.strip("\n").splitlines())


def page() -> str:
    """The reference page's Markdown: one section per command, its help in a code block."""
    import typer

    from orange_plan.cli import _register_commands, app

    _register_commands()
    root = typer.main.get_command(app)
    parts = ["# Command line\n",
             "Every command and its options, as `orange-plan COMMAND --help` prints them. "
             "Bad input exits with code 2 and one line on stderr "
             "([errors and exit codes](errors.md)); with `--json` a command prints one JSON "
             "object ([every key](../json.md)).\n"]
    for path, _ in _commands(root):
        title = " ".join(("orange-plan", *path))
        parts.append(f"## `{title}`\n\n```text\n{_help(app, path)}\n```\n")
    return "\n".join(parts)


def site_links(markdown: str) -> str:
    """A repository-root Markdown file's links as the site's: ``docs/x.md`` -> ``x.md``,
    ``CHANGELOG.md`` -> ``changelog.md``, the docs folder -> the site's home."""
    markdown = re.sub(r"\]\(docs/", "](", markdown)
    markdown = markdown.replace("](CHANGELOG.md)", "](changelog.md)")
    return markdown.replace("[docs/](docs)", "`docs/`")


def on_files(files, config):
    os.environ.setdefault("COLUMNS", str(WIDTH))
    files.append(File.generated(config, PAGE, content=page()))
    for source, target in (("README.md", "index.md"), ("CHANGELOG.md", "changelog.md")):
        text = (ROOT / source).read_text(encoding="utf-8")
        files.append(File.generated(config, target, content=site_links(text)))
    return files
