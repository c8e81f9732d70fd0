"""docs/python.md shows the worked example as docs/figures/two_tank_python.py has it (which CTest runs)."""
import os
import textwrap

from conftest import ROOT


def test_the_doc_shows_the_example_that_runs():
    with open(os.path.join(ROOT, "docs", "figures", "two_tank_python.py")) as f:
        script = f.read()
    begin = "# --- the example (docs/python.md shows this function) ---\n"
    example = script[script.index(begin) + len(begin):script.index("# --- end of the example ---")].rstrip()
    with open(os.path.join(ROOT, "docs", "python.md")) as f:
        doc = f.read()
    assert textwrap.indent(example, "    ").replace("    \n", "\n") in doc
