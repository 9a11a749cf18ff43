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
    """``text`` with the block of table ``name`` replaced by ``body``."""
    pattern = re.compile(r"(<!-- table:" + re.escape(name) + r"\b[^>]*-->\n)(.*?)(\n<!-- /table:"
                         + re.escape(name) + r" -->)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"no markers <!-- table:{name} ... --> ... <!-- /table:{name} --> "
                         f"in the page")
    return pattern.sub(lambda m: m.group(1) + body.strip("\n") + m.group(3), text, count=1)


def write(page: str, name: str, table: str, argv: list[str] | None = None) -> None:
    """Write ``table`` with its provenance into the block ``name`` of ``page``."""
    with open(page) as f:
        text = f.read()
    write_text_atomic(page, replace(text, name, provenance(argv) + "\n\n" + table))
