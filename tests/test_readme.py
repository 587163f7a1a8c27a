"""README's two commands are the ones CI runs."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _commands():
    text = (ROOT / "README.md").read_text()
    blocks = text.split("```")
    first = blocks[1].strip().splitlines()[1:]  # drop the language tag
    return [line for line in first if line and not line.startswith("#")]


def test_readme_starts_with_install_and_test_commands():
    install, test = _commands()[:2]
    assert "pip install ." in install and "needlenet demo" in install
    assert "pytest" in test


def test_ci_runs_exactly_the_readme_test_command():
    test = _commands()[1]
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert test in ci
