"""What a user of the package reads (docs/, --help and the README front page) is
self-contained: no citation of the contract's sections or the design notes, which users never
have, and no words of how it was built (issue numbers, "this stop", commit hashes) that a user
cannot place; the package's and the tests' docstrings and comments cite none of those
either."""

from __future__ import annotations

import re

import pytest
from conftest import REPO, run_cli

CITATION = re.compile(r"SPEC|DESIGN\.md|§")
QUICK_START = '''```bash
python -m pip install . && orange-plan plan scenarios/kiwibot_campus.toml -o plan.geojson --png plan.png
python -m pip install ".[test]" && python -m pytest -q
```'''


@pytest.mark.parametrize("command", [[], ["range"], ["reach"], ["simulate"], ["convert"],
                                     ["predict"], ["calibrate"], ["diagnose"], ["bench"], ["bench", "reach"],
                                     ["bench", "online"], ["bench", "calibration"]])
def test_help_cites_no_spec_section(command):
    code, stdout, _ = run_cli(*command, "--help")
    assert code == 0
    assert not CITATION.search(stdout), CITATION.search(stdout)


PROCESS_WORDS = re.compile(r"this stop|stops before|issue #|before this change|these changes"
                           r"|on commit [0-9a-f]{7}|as the project grows", re.IGNORECASE)
USER_DOCUMENTS = sorted({"README.md", "CHANGELOG.md",
                         *(str(p.relative_to(REPO)) for p in (REPO / "docs").rglob("*.md"))})
README_MAX_LINES = 200


@pytest.mark.parametrize("name", USER_DOCUMENTS)
def test_user_documents_cite_no_spec_section(name):
    text = (REPO / name).read_text(encoding="utf-8")
    assert not CITATION.search(text)
    assert not PROCESS_WORDS.search(text), PROCESS_WORDS.search(text)


def test_readme_is_a_front_page():
    lines = (REPO / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES


def test_readme_opens_with_the_quick_start_and_links_the_docs():
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert QUICK_START in readme.split("## Commands")[0]
    assert "docs/formats.md" in readme and "docs/json.md" in readme


def test_ci_runs_the_quick_starts_test_command_verbatim():
    test_command = QUICK_START.splitlines()[2]
    ci_lines = (REPO / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert test_command in ci_lines


def test_formats_document_every_user_file_and_the_map_origin():
    formats = (REPO / "docs" / "formats.md").read_text(encoding="utf-8")
    for needle in ("## Map", "## Scenario", "## Recording", "## Plan", "## Route CSV",
                   "## Goals CSV", '"origin"', "lat_deg", "mission.reserve", "sensor_rate_Hz",
                   "energy_to_home_J", "coverage_fraction"):
        assert needle in formats, needle


def test_json_document_names_every_range_and_reach_key():
    doc = (REPO / "docs" / "json.md").read_text(encoding="utf-8")
    for key in ("d_max_m", "v_opt_mps", "energy_per_m_J", "ancillary_loss_eta4_J", "generalised",
                "home_reachable", "energy_goal_to_home_J", "margin_J", "speeds_clipped",
                "energy_predicted_J", "holdout_rmse_W", "first_row"):
        assert re.search(rf"`([^`]*[.\]])?{key}`", doc), key


SOURCE_CITATION = re.compile(r"\bSPEC\b|DESIGN\.md|§|(?i:issue #?\d)"
                             r"|README(\s*[\"“:),;]|'s| section| table| quotes)")
"""What a docstring or comment may not cite: sections of the project's contract and design
notes, which a reader of the code does not have, issue numbers, and sections of the README
(they move; docs/ pages stay)."""


def _docstrings_and_comments(path):
    """(line, text) of every docstring, bare string statement and comment of a module."""
    import ast
    import io
    import tokenize

    source = path.read_text(encoding="utf-8")
    found = [(tok.start[0], tok.string) for tok in
             tokenize.generate_tokens(io.StringIO(source).readline)
             if tok.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str)):
            found.append((node.lineno, node.value.value))
    return found


def test_docstrings_and_comments_cite_no_spec_design_issue_or_readme_section():
    """The package's and the tests' docstrings and comments state facts or point to docs/
    pages: no contract or design sections, no issue numbers, no sections of the README."""
    cited = [f"{path.relative_to(REPO)}:{line}: {SOURCE_CITATION.search(text).group(0)}"
             for folder in ("orange_plan", "tests") for path in sorted((REPO / folder).rglob("*.py"))
             for line, text in _docstrings_and_comments(path) if SOURCE_CITATION.search(text)]
    assert not cited, "\n".join(cited)
