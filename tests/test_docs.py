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
        lines = [line for line in block.split("\n") if line.strip()]
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
