"""The manual: the code blocks of the README and of docs/ run, the pages keep their shape
(under 3,000 words, no paragraph over 150 words, no dates or issue numbers in headings), and
the API reference names everything in ``veil.__all__``.

Code blocks: every fenced ```python block runs, the blocks of one page in order in one
namespace, in a scratch folder (a page may write files and read them back). A block preceded
by a line ``<!-- notest: why -->`` is illustrative (it needs the reader's files, or takes
minutes) and is not run; shell blocks (```bash, ```text, indented) never are. All pages run in
one interpreter, so JAX is imported and the engine's programs compiled once."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
FENCE = re.compile(r"(?P<before>[^\n]*)\n```(?P<info>[^\n]*)\n(?P<code>.*?)\n```", re.S)
MAX_WORDS, MAX_PARAGRAPH = 3000, 150


def python_blocks(text: str):
    """(line, code) of the blocks to run."""
    out = []
    for m in FENCE.finditer("\n" + text):
        if m.group("info").strip() == "python" and "notest" not in m.group("before"):
            out.append((text[: m.start("code") - 1].count("\n") + 1, m.group("code")))
    return out


def words(text: str) -> int:
    """Words: tokens with a letter or digit (a formula's '=' and '+' are not words)."""
    return sum(1 for w in text.split() if re.search(r"[A-Za-z0-9]", w))


def paragraphs(text: str):
    """Prose paragraphs: blank-line separated blocks without code, tables and headings; the
    items of a list count one by one."""
    text = re.sub(r"(?ms)^```.*?^```", "", text)
    for block in re.split(r"\n\s*\n", text):
        # a one-line HTML comment (a table's marker, notest) is not prose; what follows it is
        lines = [line for line in block.split("\n") if line.strip()
                 and not re.fullmatch(r"\s*<!--.*-->\s*", line)]
        if not lines or lines[0].lstrip().startswith(("|", "#", "<!--")) \
                or all(line.startswith("    ") for line in lines):
            continue
        item = []
        for line in lines:
            if re.match(r"^\s{0,3}([-*]|\d+\.)\s", line) and item:
                yield "\n".join(item)
                item = []
            item.append(line)
        yield "\n".join(item)


RUNNER = r"""
import json, os, sys, traceback, warnings
warnings.simplefilter("ignore")
import matplotlib
matplotlib.use("Agg")
failures = []
for page, blocks in json.load(sys.stdin):
    here = os.path.join(os.getcwd(), os.path.basename(page) + ".d")
    os.makedirs(here)
    os.chdir(here)
    namespace = {"__name__": "__docs__"}
    for line, code in blocks:
        try:
            exec(compile(code, f"{page}:{line}", "exec"), namespace)
        except Exception:
            failures.append(f"{page}, block at line {line}:\n{traceback.format_exc()}")
            break
    os.chdir("..")
print(json.dumps(failures))
"""


def test_code_blocks_run(tmp_path):
    todo = [(str(p.relative_to(ROOT)), python_blocks(p.read_text())) for p in PAGES]
    todo = [(page, blocks) for page, blocks in todo if blocks]
    assert todo, "no runnable block found: the extraction is broken"
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep
               + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, "-c", RUNNER], input=json.dumps(todo), text=True,
                            capture_output=True, cwd=tmp_path, env=env, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    failures = json.loads(result.stdout.strip().splitlines()[-1])
    assert not failures, "\n\n".join(failures)


def test_the_block_extraction():
    text = ("Intro\n\n```python\nx = 1\n```\n\n<!-- notest: needs files -->\n```python\n"
            "open('mine.csv')\n```\n\n```bash\nveil demo\n```\n")
    assert python_blocks(text) == [(4, "x = 1")]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_page_shape(page):
    text = page.read_text()
    assert words(text) < MAX_WORDS, f"{page.name}: {words(text)} words"
    long = [p[:80] for p in paragraphs(text) if words(p) > MAX_PARAGRAPH]
    assert not long, f"{page.name}: paragraphs over {MAX_PARAGRAPH} words: {long}"
    for line in text.splitlines():
        if line.startswith("#"):
            assert not re.search(r"\b20\d\d-\d\d-\d\d\b|\bissue \d+|\bsession\)", line), line
    levels = heading_levels(text)
    jumps = [(a, b) for a, b in zip(levels, levels[1:]) if b > a + 1]
    assert not jumps, f"{page.name}: a heading level skipped (Sphinx's -W fails): {jumps}"


def heading_levels(text: str) -> list[int]:
    """The levels of the Markdown headings outside fenced code blocks."""
    levels, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (m := re.match(r"(#+) ", line)):
            levels.append(len(m.group(1)))
    return levels


def test_a_skipped_heading_level_is_found():
    assert heading_levels("# A\n```\n# code\n```\n### C\n## D\n") == [1, 3, 2]


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 150, len(lines)
    text = "\n".join(lines)
    assert "make demo" in text and "make test" in text


def test_api_reference_names_all_of_veil():
    import veil
    text = (ROOT / "docs" / "api.md").read_text()
    listed = set(re.findall(r"^\s+(\w+)$", text, re.M)) \
        | set(re.findall(r"`veil\.(\w+)`", text))
    # model families registered by plugins (the suite's test models) join veil.__all__
    # where a test registered them; they are not veil's to document
    def is_veils(name):
        module = str(getattr(getattr(veil, name, None), "__module__", "veil"))
        return module == "veil" or module.startswith("veil.")

    own = {name for name in veil.__all__ if is_veils(name)}
    missing = own - listed
    assert not missing, f"not in docs/api.md: {sorted(missing)}"


def test_readme_links_resolve():
    """The README is read on the forge, outside the site: its relative links name files."""
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert links
    missing = [link for link in links if "://" not in link and not (ROOT / link).exists()]
    assert not missing, missing


def test_named_files_exist():
    """A page that names a file of the repository (src/..., tests/..., benchmarks/...) names
    one that exists; placeholders in capitals (NAME_cmd.py) are not files."""
    pattern = re.compile(r"\b((?:src|tests|benchmarks|validation|examples)/[\w/.-]+\.(?:py|md))")
    missing = []
    for page in PAGES:
        for path in set(pattern.findall(page.read_text())):
            if not re.search(r"[A-Z]{3,}", path) and not (ROOT / path).exists():
                missing.append(f"{page.name}: {path}")
    assert not missing, missing


def test_model_md_presets_are_veils():
    """The preset tables of docs/model.md sec. 6 hold veil.PRESETS' values, in order."""
    import veil
    text = (ROOT / "docs" / "model.md").read_text()
    section = text[text.index("## 6."):text.index("## 7.")]
    rows = re.findall(r"^\| (BRDF\d|BTDF\d)\s*\|(.*)\|\s*$", section, re.M)
    assert [name for name, _ in rows] == ["BRDF1", "BRDF2", "BTDF1", "BTDF2", "BTDF3"]
    for name, cells in rows:
        values = [float(c) for c in cells.split("|")]
        model = veil.PRESETS[name]
        assert values == pytest.approx(list(model.to_vector()), rel=1e-12), name


def _benchmark(name: str):
    """A module of benchmarks/ (not a package), imported from its file."""
    import importlib.util
    with pytest.MonkeyPatch.context() as patch:  # its imports of the other benchmarks
        patch.syspath_prepend(str(ROOT / "benchmarks"))
        spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module


def test_doc_tables_replace_only_their_block():
    tables = _benchmark("doc_tables")
    page = "a\n<!-- table:t (written by x) -->\nold\n<!-- /table:t -->\nb\n"
    new = tables.replace(page, "t", "line\n\n" + tables.markdown(["x", "y"], [["1", "2"]], {1}))
    assert new == ("a\n<!-- table:t (written by x) -->\nline\n\n| x | y |\n|---|---:|\n"
                   "| 1 | 2 |\n<!-- /table:t -->\nb\n")
    with pytest.raises(SystemExit):
        tables.replace("no markers", "t", "line")
    line = tables.provenance(["benchmarks/bench_validity.py", "--media", "m01"])
    assert "bench_validity.py --media m01" in line and "cores" in line and "load" in line


def test_bench_validity_writes_the_table_validity_md_has():
    """The rows --doc writes are the rows docs/validity.md holds (the same run's numbers)."""
    bench = _benchmark("bench_validity")
    text = (ROOT / "docs" / "validity.md").read_text()
    block = text[text.index("<!-- table:validity"):text.index("<!-- /table:validity -->")]
    assert "| " + " | ".join(bench.DOC_COLUMNS) + " |" in block
    rows = [
        dict(medium="m01", target="target", models="physical", est_vs_direct=0.0031,
             est_vs_truth=0.0031, direct_vs_truth=0.0, max_z=4.43, fr_max_z=5.14,
             fr_within_2se=0.75, tau=0.108, tau_stderr=0.125, tau_true=0.1, g=0.98,
             g_true=0.97, seconds=41.2),
        dict(medium="m10", target="target", models="physical (joint)", est_vs_truth=0.0020,
             tau=1.126, tau_stderr=0.016, tau_true=1.0, g=0.8957, g_true=0.88, seconds=87.0),
        dict(medium="m05", target="target", models="paper", est_vs_direct=0.0113,
             est_vs_truth=0.0387, direct_vs_truth=0.0348, max_z=3.49, fr_max_z=3.15,
             fr_within_2se=0.64, tau=math.nan, g=0.9764, g_true=0.92, tau_true=0.5,
             seconds=47.0),
    ]
    for cells in bench.doc_rows(rows):
        assert "| " + " | ".join(cells) + " |" in block, cells


# ---- measurement tables are written by scripts ------------------------------------------------
#
# A table is numeric when more than half of its body cells begin with a number (after an
# optional sign, ~, <, >, emphasis or code marks: "0.21 %", "**1.07**", "-0.028 / ...",
# "1.121 ± 0.016 (1.0)"). Every numeric table of a manual page sits between markers
#
#     <!-- table:NAME (written by SCRIPT --doc docs/PAGE.md [--doc-table NAME] ...) -->
#     <!-- /table:NAME -->
#
# naming a script of benchmarks/ or validation/ that exists and takes --doc (and writes NAME:
# given by --doc-table in the marker, or the script's own default). A table of defined values,
# not of measurements (the paper's presets), is preceded by <!-- not-measured: why -->.
# design-notes.md and changelog.md keep history and its tables as they were.

HISTORY = {"design-notes.md", "changelog.md"}
RULE = re.compile(r"\|(\s*:?-+:?\s*\|)+")
MARKER = re.compile(r"<!-- table:([\w-]+) \(written by ((?:benchmarks|validation)/[\w-]+\.py)"
                    r"([^>]*)\) -->")


def tables_of(text: str):
    """(line index of the header, body cells) of every Markdown table, indented ones too."""
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        if lines[i].lstrip().startswith("|") and i + 1 < len(lines) \
                and RULE.fullmatch(lines[i + 1].strip()):
            j = i + 2
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            cells = [c for row in lines[i + 2:j]
                     for c in re.split(r"(?<!\\)\|", row.strip())[1:-1]]
            yield i, cells
            i = j
        else:
            i += 1


def is_numeric(cells: list[str]) -> bool:
    number = re.compile(r"^[-+~<>≈]?\s*\d")
    return 2 * sum(bool(number.match(c.strip().strip("*`").strip())) for c in cells) > len(cells)


def table_source(lines: list[str], at: int):
    """The marker around the table whose header is line ``at``: (name, script, rest), or
    "not-measured", or None."""
    for k in range(at - 1, -1, -1):
        line = lines[k].strip()
        if line.startswith("<!-- /table:"):
            return None
        if line.startswith("<!-- not-measured:") and at - k <= 2:
            return "not-measured"
        m = MARKER.search(line)
        if m:
            closing = f"<!-- /table:{m.group(1)} -->"
            after = [x.strip() for x in lines[at:]]
            return m.groups() if closing in after else None
    return None


def test_the_numeric_rule():
    assert is_numeric(["m01", "**0.21 %**", "1.121 ± 0.016 (1.0)", "-0.028 / -0.054"])
    assert not is_numeric(["0", "converged", "1", "too few points"])
    text = "<!-- not-measured: presets -->\n| a | b |\n|---|---|\n| 1 | 2 |\n"
    assert table_source(text.splitlines(), 1) == "not-measured"


@pytest.mark.parametrize("page", [p for p in PAGES if p.parent.name == "docs"
                                  and p.name not in HISTORY], ids=lambda p: p.name)
def test_numeric_tables_name_the_script_that_writes_them(page):
    lines = page.read_text().splitlines()
    problems = []
    for at, cells in tables_of(page.read_text()):
        if not is_numeric(cells):
            continue
        where = f"{page.name}:{at + 1}"
        source = table_source(lines, at)
        if source == "not-measured":
            continue
        if source is None:
            problems.append(f"{where}: a numeric table without <!-- table:NAME (written by "
                            f"SCRIPT --doc ...) --> ... <!-- /table:NAME -->")
            continue
        name, script, rest = source
        path = ROOT / script
        if not path.exists():
            problems.append(f"{where}: {script} does not exist")
            continue
        code = path.read_text()
        # --doc comes from the script's parser, doc_tables.add_options or bench_validity's
        # add_doc_options (study_parser includes it)
        if not re.search(r'"--doc"|add_options\(|add_doc_options\(|study_parser\(', code):
            problems.append(f"{where}: {script} takes no --doc")
        named = re.search(r"--doc-table[= ]([\w,-]+)", rest)
        if not (named and name in named.group(1).split(",")) and name not in code:
            problems.append(f"{where}: {script} does not write table {name} (give "
                            f"--doc-table {name} in the marker)")
        if "--doc " not in rest or not re.search(rf"--doc (PAGE|docs/{re.escape(page.name)})\b",
                                                 rest):
            problems.append(f"{where}: the marker's command does not write docs/{page.name}")
    assert not problems, "\n".join(problems)


def test_pages_under_3000_words_by_wc():
    """`wc -w` counts: every whitespace-separated token."""
    big = {p.name: len(p.read_text().split()) for p in PAGES}
    assert not {name: n for name, n in big.items() if n > MAX_WORDS}, big


def _resolves(dotted: str) -> bool:
    import importlib

    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        try:
            for attr in parts[k:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


def unnamed_modules(tree: str, src: Path = ROOT / "src" / "veil") -> list[str]:
    """The modules of ``src`` that the source tree drawn in docs/architecture.md (``tree``,
    its first code block) does not name: a package's module in the package's entry (from
    its line ``  pkg/`` to the next entry at that indent), a top-level one in any top-level
    entry; left out: ``__init__.py``, ``__main__.py`` and the commands (``cli/*_cmd.py``,
    "one module per command")."""
    entries: dict[str, str] = {}
    name = ""
    for line in tree.splitlines():
        if re.match(r"  \S", line):
            head = line.split()[0]
            name = head.rstrip("/") if head.endswith("/") else ""
        entries[name] = entries.get(name, "") + line + "\n"
    missing = []
    for path in sorted(src.rglob("*.py")):
        rel = path.relative_to(src)
        if path.name in ("__init__.py", "__main__.py") or path.name.endswith("_cmd.py"):
            continue
        package = rel.parts[0] if len(rel.parts) > 1 else ""
        if not re.search(rf"(?<![\w/]){re.escape(path.name)}\b", entries.get(package, "")):
            missing.append(str(rel))
    return missing


def test_architecture_names_every_module():
    text = (ROOT / "docs" / "architecture.md").read_text()
    tree = text.split("```")[1]
    assert tree.startswith("\nsrc/veil/"), tree[:40]
    assert not unnamed_modules(tree), unnamed_modules(tree)


def test_an_unnamed_module_is_caught(tmp_path):
    for rel in ("io.py", "fitting/solver.py", "fitting/steps.py", "maps/solve.py",
                "cli/fit_cmd.py", "cli/_common.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    tree = ("src/veil/\n  io.py   atomic writes\n  fitting/   estimation\n"
            "    solver.py   the fits (not maps' solve.py)\n  maps/   per pixel\n"
            "  cli/    one module per command\n")
    assert unnamed_modules(tree, tmp_path) == ["cli/_common.py", "fitting/steps.py",
                                                "maps/solve.py"]


def test_named_python_objects_exist():
    """Every `veil.x.y` a page or the README names in code marks is a module or an object
    of veil today (a module moved or renamed breaks this, not the reader)."""
    pages = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
    missing = sorted({f"{page.name}: {name}" for page in pages
                      for name in re.findall(r"`(veil(?:\.[A-Za-z_]\w*)+)(?![\w/])", page.read_text())
                      if not _resolves(name)})
    assert not missing, missing


def test_the_name_check_fails_for_a_moved_module():
    assert _resolves("veil.maps.near.STEP_FRACTION")
    assert not _resolves("veil.fitting.maps_near.STEP_FRACTION")
    assert not _resolves("veil.maps.near.NO_SUCH_NAME")


def _veil_imports(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of every ``import veil...`` and ``from veil... import name`` of a
    script."""
    import ast

    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                node.module.split(".")[0] == "veil":
            found += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names
                      if a.name.split(".")[0] == "veil"]
    return found


def test_scripts_import_what_veil_has():
    """The benchmarks, validation scripts and examples import modules and names that exist
    (a moved module broke benchmarks/bench_maps_near.py without any test noticing)."""
    scripts = [p for folder in ("benchmarks", "validation", "examples")
               for p in sorted((ROOT / folder).rglob("*.py"))]
    assert len(scripts) > 20
    missing = [f"{p.relative_to(ROOT)}:{line}: {name}" for p in scripts
               for line, name in _veil_imports(p) if not _resolves(name)]
    assert not missing, "\n".join(missing)


def test_auto_table_writes_the_rows_validity_auto_md_has():
    """docs/validity-auto.md's table is the one validation/auto_table.py makes of the rows
    in validation/results/auto_table.json (no fitting: the rows are read); a pick counts as
    the generating one by family and option."""
    import importlib.util
    import json

    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(ROOT / "benchmarks"))
        spec = importlib.util.spec_from_file_location("auto_table",
                                                      ROOT / "validation" / "auto_table.py")
        auto = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(auto)
        rows = json.loads((ROOT / "validation" / "results" / "auto_table.json").read_text())
        text = (ROOT / "docs" / "validity-auto.md").read_text()
        block = text[text.index("<!-- table:auto"):text.index("<!-- /table:auto -->")]
        for cells in auto.doc_rows(rows):
            assert "| " + " | ".join(cells) + " |" in block, cells
        truth = json.loads((ROOT / "validation" / "data" / "truth.json").read_text())
        ggx = auto.generating(truth, "target", "ggx")
        assert auto.is_generating({"family": "rough-plastic",
                                   "options": {"distribution": "ggx"}}, ggx)
        assert not auto.is_generating({"family": "rough-plastic", "options": {}}, ggx)
        assert auto.is_generating({"family": "rough-plastic", "options": {}},
                                  auto.generating(truth, "target", "target"))
