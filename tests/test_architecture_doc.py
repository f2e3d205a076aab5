"""docs/architecture.md cannot go stale: every module it names exists, and every module of the
package is named there (in the layer diagram under its folder, or as a path in backquotes)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "balance_opt"
DOC = ROOT / "docs" / "architecture.md"

#: A layer of the diagram: its label (``model/``, or ``base``/``top`` for modules directly in the
#: package) at two spaces, its text after it and on the lines indented below.
_LAYER = re.compile(r"^  (\S+) +(.*)$")
#: A path in backquotes: ``model/robot.py``, ``cli.py``, ``*/options.py``.
_PATH = re.compile(r"`([\w*./-]+\.py)`")


def _without_parentheses(text: str) -> str:
    """``text`` with every (possibly nested) parenthesised part removed: the diagram's comments."""
    while True:
        shorter = re.sub(r"\([^()]*\)", " ", text)
        if shorter == text:
            return text
        text = shorter


def diagram_names(doc: str) -> dict[str, str]:
    """The modules the layer diagram names: ``path in the package -> the words that name it``.
    Under a folder's label its bare names (``robot, joints`` -> ``model/robot.py``, ...), under
    ``base`` and ``top`` the ``*.py`` names."""
    diagram = doc.split("```\n", 2)[1]
    layers: list[tuple[str, list[str]]] = []
    for line in diagram.splitlines():
        if (match := _LAYER.match(line)) and not set(match.group(1)) <= set("|\\/"):
            layers.append((match.group(1), [match.group(2)]))
        elif layers:
            layers[-1][1].append(line)
    names = {}
    for label, lines in layers:
        text = _without_parentheses(" ".join(lines))
        if label.endswith("/"):
            for word in re.findall(r"(?<![\w`'])([a-z_][a-z0-9_]*)(?![\w'])", text):
                names[f"{label}{word}.py"] = f"{label} {word}"
        else:
            for word in re.findall(r"([\w]+\.py)", text):
                names[word] = f"{label} {word}"
    return names


def backquoted_paths(doc: str) -> set[str]:
    """The ``*.py`` paths in backquotes anywhere in the document (globs too)."""
    return set(_PATH.findall(doc))


def package_modules() -> set[str]:
    """Every module of the package, as a path in it; the subpackages' ``__init__.py`` are left
    out (a package is named by its folder), the package's own is in."""
    return {
        p.relative_to(PACKAGE).as_posix()
        for p in PACKAGE.rglob("*.py")
        if p.name != "__init__.py" or p.parent == PACKAGE
    }


def stale_names(doc: str) -> list[str]:
    """The names in ``doc`` of modules that do not exist (backquoted paths: in the package or
    the repository)."""
    missing = [f"diagram, {where}" for path, where in diagram_names(doc).items()
               if not (PACKAGE / path).is_file()]  # fmt: skip
    missing += [f"`{path}`" for path in sorted(backquoted_paths(doc))
                if not [*PACKAGE.glob(path), *ROOT.glob(path)]]  # fmt: skip
    return missing


def unnamed_modules(doc: str) -> list[str]:
    """The package's modules that ``doc`` does not name."""
    named = set(diagram_names(doc))
    for path in backquoted_paths(doc):
        named |= {p.relative_to(PACKAGE).as_posix() for p in PACKAGE.glob(path)}
    return sorted(package_modules() - named)


def test_the_diagram_reads_every_layer():
    names = diagram_names(DOC.read_text())
    # one module of each layer, read through comments in parentheses across lines
    for module in ("errors.py", "config/yaml_lines.py", "model/coupling.py", "geometry/shapes.py",
                   "motion/robustness.py", "analytic/rollout.py", "solvers/ipopt_options.py",
                   "dynamics/capture_impulse.py", "tasks/task.py", "report/scene.py",
                   "app/scenarios.py", "sweep/runner.py", "cli.py", "__init__.py"):  # fmt: skip
        assert module in names, module
    assert "model/numeric.py" not in names  # "maps (numeric)": a comment, not a module


def test_every_module_the_architecture_names_exists():
    missing = stale_names(DOC.read_text())
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"


def test_every_module_of_the_package_is_named_in_the_architecture():
    unnamed = unnamed_modules(DOC.read_text())
    assert not unnamed, f"modules docs/architecture.md does not name: {unnamed}"


@pytest.mark.parametrize(
    "text, problem",
    [
        ("  motion/    so3, warp (a new one)\n", "diagram, motion/ warp"),
        ("| a concept | `optimal/stale.py` |\n", "`optimal/stale.py`"),
    ],
)
def test_a_stale_name_is_found(text, problem):
    """A module that is gone, named in the diagram or in the table, is found."""
    doc = DOC.read_text()
    doc = doc.replace("```\n", "```\n" + text, 1) if text.startswith("  ") else doc + text
    assert stale_names(doc) == [problem]


def test_a_module_left_out_is_found():
    doc = DOC.read_text().replace("smoothness, robustness", "smoothness")
    doc = doc.replace("`motion/robustness.py`", "motion's robustness")
    assert unnamed_modules(doc) == ["motion/robustness.py"]
