"""Repository contracts: CI runs the README's test command, and no data enters git."""

import re
import subprocess

from tests.conftest import ROOT


def _readme_test_command() -> str:
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    commands = [b.strip() for b in blocks if "pytest" in b and "\n" not in b.strip()]
    assert len(commands) == 1, "the README must give exactly one one-line test command"
    return commands[0]


def test_ci_runs_the_readme_test_command_verbatim():
    assert _readme_test_command() in (ROOT / ".ci" / "run").read_text()


def test_no_data_or_artefacts_are_tracked():
    tracked = subprocess.run(
        ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    bad = [
        f
        for f in tracked
        if re.search(r"\.(zip|npz|npy|ckpt|pt|pth|h5|pkl)$", f)
        or re.match(r"(outputs|data|lightning_logs)/.+", f)
        and not f.endswith(".gitkeep")
    ]
    assert not bad, bad
