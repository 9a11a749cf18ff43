"""Tables that benchmarks write into the documentation, with how they were made.

A page holds a generated table between two markers,

    <!-- table:NAME (written by benchmarks/SCRIPT.py --doc PAGE) -->
    ...
    <!-- /table:NAME -->

and a benchmark run with ``--doc PAGE`` replaces what is between them by a provenance line
(the command, the date, the machine, its load) and the table in Markdown. Nothing else on the
page changes; a page without the markers is an error (the table is not appended anywhere).
"""

from __future__ import annotations

import datetime
import os
import platform
import re
import shlex
import sys

from veil.io import write_text_atomic


def provenance(argv: list[str] | None = None) -> str:
    """One line: the command that made a table, its date, the machine and the load."""
    argv = sys.argv if argv is None else argv
    command = " ".join(shlex.quote(a) for a in ["python", os.path.relpath(argv[0])] + argv[1:])
    try:
        load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:  # no load average on this platform
        load = "unknown"
    return (f"Written by `{command}` on {datetime.date.today().isoformat()}, "
            f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores, "
            f"load average (1, 5, 15 min) {load}.")


def markdown(headers: list[str], rows: list[list[str]], right: set[int] = frozenset()) -> str:
    """A Markdown table; columns whose index is in ``right`` are right-aligned."""
    line = lambda cells: "| " + " | ".join(cells) + " |"  # noqa: E731
    rule = ["---:" if i in right else "---" for i in range(len(headers))]
    return "\n".join([line(headers), "|" + "|".join(rule) + "|"] + [line(r) for r in rows])


def replace(text: str, name: str, body: str) -> str:
    """``text`` with the block of table ``name`` replaced by ``body``. A block inside a list
    item (its markers indented) gets its body indented the same way."""
    pattern = re.compile(r"^([ \t]*)(<!-- table:" + re.escape(name) + r"\b[^>]*-->\n)(.*?)"
                         r"(\n[ \t]*<!-- /table:" + re.escape(name) + r" -->)", re.S | re.M)
    if not pattern.search(text):
        raise SystemExit(f"no markers <!-- table:{name} ... --> ... <!-- /table:{name} --> "
                         f"in the page")

    def block(m):
        indent = m.group(1)
        lines = [(indent + line) if line else line for line in body.strip("\n").split("\n")]
        return indent + m.group(2) + "\n".join(lines) + m.group(4)

    return pattern.sub(block, text, count=1)


def write(page: str, name: str, table: str, argv: list[str] | None = None) -> None:
    """Write ``table`` with its provenance into the block ``name`` of ``page``."""
    with open(page) as f:
        text = f.read()
    write_text_atomic(page, replace(text, name, provenance(argv) + "\n\n" + table))


# ---- the --doc option of every benchmark and validation script --------------------------------
#
# A script that prints its results as Markdown tables gets ``--doc PAGE`` by two lines:
#
#     doc_tables.add_options(parser, "NAME1,NAME2")     # the blocks its printed tables go to
#     with doc_tables.printed_tables(args):              # around the part that prints them
#         ...
#
# The tables written are exactly the ones the run printed, in the order it printed them.


def add_options(parser, tables: str) -> None:
    """``--doc PAGE`` and ``--doc-table NAMES`` on an argparse parser."""
    parser.add_argument(
        "--doc", default=None, metavar="PAGE",
        help="write the Markdown tables this run prints into PAGE, each between its markers "
             "<!-- table:NAME ... --> and <!-- /table:NAME -->, with the command, the date, "
             "the machine and its load (benchmarks/doc_tables.py)")
    parser.add_argument(
        "--doc-table", default=tables, metavar="NAMES",
        help="the NAMEs of those blocks, comma-separated, in the order the run prints its "
             "tables; '-' skips a table (default: %(default)s)")


def tables_in(text: str) -> list[str]:
    """The Markdown tables in printed text: runs of lines starting with '|' whose second line
    is a rule (|---|---:|)."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        if lines[i].startswith("|") and i + 1 < len(lines) \
                and re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", lines[i + 1].strip()):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            out.append("\n".join(line.rstrip() for line in lines[i:j]))
            i = j
        else:
            i += 1
    return out


def write_printed(page: str, names: list[str], text: str, argv: list[str] | None = None) -> None:
    """The Markdown tables in ``text``, in order, into the blocks ``names`` of ``page``."""
    tables = tables_in(text)
    if len(tables) < len(names):
        raise SystemExit(f"--doc: the run printed {len(tables)} table(s), "
                         f"--doc-table names {names}")
    for name, table in zip(names, tables):
        if name != "-":
            write(page, name, table, argv)
            print(f"wrote table {name} into {page}", file=sys.stderr)


class _Tee:
    def __init__(self, *streams):
        self.streams = streams

    def write(self, s):
        for stream in self.streams:
            stream.write(s)
        return len(s)

    def flush(self):
        for stream in self.streams:
            stream.flush()

    def __getattr__(self, name):
        return getattr(self.streams[0], name)


class printed_tables:  # noqa: N801 - used as a context manager, like open()
    """Copy what is printed inside the block; at its end, when ``args.doc`` names a page,
    write the Markdown tables printed into the page's blocks ``args.doc_table``."""

    def __init__(self, args, argv: list[str] | None = None):
        self.page = getattr(args, "doc", None)
        self.names = [n.strip() for n in getattr(args, "doc_table", "").split(",") if n.strip()]
        self.argv = argv

    def __enter__(self):
        if self.page:
            import io
            self.buffer, self.stdout = io.StringIO(), sys.stdout
            sys.stdout = _Tee(self.stdout, self.buffer)
        return self

    def __exit__(self, kind, value, tb):
        if not self.page:
            return False
        sys.stdout = self.stdout
        if kind is not None:  # the run failed: the page keeps its tables
            return False
        write_printed(self.page, self.names, self.buffer.getvalue(), self.argv)
        return False

    def start(self):
        """For a script's main(): ``doc = printed_tables(args).start()`` after parsing, then
        ``doc.finish()`` once its tables are printed."""
        return self.__enter__()

    def finish(self) -> None:
        self.__exit__(None, None, None)


def main(argv: list[str] | None = None) -> int:
    """``python benchmarks/doc_tables.py --doc PAGE --doc-table NAMES -- COMMAND ...``: run a
    command that prints Markdown tables (an example, a ``veil`` command) and write them into
    PAGE, the provenance line naming this whole command. Nothing is written if it fails."""
    import argparse
    import subprocess

    ap = argparse.ArgumentParser(description=main.__doc__.split("\n\n")[0].strip())
    add_options(ap, "")
    ap.add_argument("--from", dest="source", default=None, metavar="FILE",
                    help="read the tables from FILE, which the command writes (a report), "
                         "instead of from what it prints")
    ap.add_argument("command", nargs=argparse.REMAINDER,
                    help="the command, after '--' (python examples/ambiguity.py)")
    args = ap.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command or not args.doc or not args.doc_table:
        ap.error("--doc PAGE, --doc-table NAMES and a command after '--' are needed")
    if command[0] == "python":
        command[0] = sys.executable
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    printed = []
    for line in proc.stdout:
        sys.stdout.write(line)
        printed.append(line)
    if proc.wait():
        print(f"{' '.join(command)} exited {proc.returncode}: nothing written", file=sys.stderr)
        return proc.returncode
    names = [n.strip() for n in args.doc_table.split(",") if n.strip()]
    if args.source:
        with open(args.source) as f:
            printed = [f.read()]
    write_printed(args.doc, names, "".join(printed),
                  None if argv is None else ["benchmarks/doc_tables.py"] + argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
