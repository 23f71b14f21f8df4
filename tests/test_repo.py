"""Repository contracts: CI runs the README's test command, and no data enters git."""

import ast
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


# ------------------------------------------------------------------------ pages for readers
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_the_readme_is_short_and_opens_with_the_results():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; keep it to 250"
    headline = lines.index("<!-- results:start -->")
    assert headline < 60, f"the results headline starts at line {headline + 1}, not in 60"
    assert len((ROOT / "docs" / "results.md").read_text().splitlines()) <= 400


def test_the_quick_start_says_how_long_the_main_job_takes_and_how_to_share_cores():
    text = (ROOT / "README.md").read_text()
    quick = text[text.index("## Quick start") : text.index("## Data")]
    main_job = quick.index("src.train experiment=li2018_h36m")
    assert re.search(r"\d+(\.\d+)? hours", quick[:main_job]), "state the time before the command"
    assert "OMP_NUM_THREADS=1" in quick[:main_job]


def test_pages_cite_no_issue_numbers_and_every_link_resolves():
    """Readers cannot open the project's tracker; a page's relative links point at files."""
    for page in DOCS:
        text = page.read_text()
        assert not re.search(r"\bissues? #?\d+", text, flags=re.I), page.name
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
            if not re.match(r"https?://", target):
                assert (page.parent / target).exists(), f"{page.name} links to {target}"


def test_every_test_named_in_the_guarantees_exists():
    """A guarantee whose test was renamed or deleted would stand unproven on the page."""
    text = (ROOT / "docs" / "guarantees.md").read_text()
    named = set(re.findall(r"(tests/test_\w+\.py)::(test_\w+)", text))
    assert len(named) > 50
    defined = {}
    for path, name in sorted(named):
        if path not in defined:
            tree = ast.parse((ROOT / path).read_text())
            defined[path] = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
        assert name in defined[path], f"docs/guarantees.md names {path}::{name}, which is gone"


# ------------------------------------------------------------------------------- code layout
# Lower to higher; a module imports only from its own layer and those below it.
LAYERS = [
    ("src.data",),
    ("src.models", "src.metrics", "src.plots"),
    ("src.config",),
    ("src.lit",),
    ("src.reporting",),
]


def _imports() -> dict[str, set[str]]:
    """Each module of src and the src modules it imports (anywhere in it, lazily too)."""
    files = {
        ".".join(p.relative_to(ROOT).with_suffix("").parts): p for p in ROOT.glob("src/**/*.py")
    }
    files = {m.removesuffix(".__init__"): p for m, p in files.items()}
    graph = {}
    for module, path in files.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            found |= {n for n in names if n in files and n != module}
        graph[module] = found
    return graph


def _layer(module: str) -> int:
    for i, prefixes in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return i
    return len(LAYERS)  # the entry points and what only they use


def test_no_import_circle_and_no_import_from_a_lower_layer_to_a_higher_one():
    graph = _imports()
    upward = [(m, d) for m, deps in graph.items() for d in deps if _layer(d) > _layer(m)]
    assert not upward, f"a lower layer imports a higher one: {upward}"
    # A package's __init__ re-exporting its own modules is not a circle.
    graph = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in graph.items()}
    done, path = set(), []

    def visit(module):
        assert module not in path, f"import circle: {' -> '.join(path[path.index(module) :])}"
        if module in done:
            return
        path.append(module)
        for dep in graph[module]:
            visit(dep)
        path.pop()
        done.add(module)

    for module in graph:
        visit(module)
