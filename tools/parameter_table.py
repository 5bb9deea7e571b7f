"""The table of a relief's parameters on ``docs/api.md``, made from their declarations.

    python tools/parameter_table.py           # print the table
    python tools/parameter_table.py --write   # write it into docs/api.md

Each setting of :func:`cliff_terrain.build_relief` is declared once, in
``cliff_terrain.settings.PARAMETERS`` (label, help, unit, default, limits, choices); the
command-line options and the Blender sidebar are made from the same declarations, so the table
says what both show. It stands between the two marker comments below on ``docs/api.md``;
``tests/test_docs.py`` fails when it is not this script's output.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cliff_terrain.settings import PARAMETERS, UNITS  # noqa: E402

PAGE = ROOT / "docs" / "api.md"
BEGIN = "<!-- The parameters' table: made by tools/parameter_table.py from cliff_terrain/settings.py. -->"
END = "<!-- End of the parameters' table. -->"
# `progress` is a keyword of build_relief, not a setting: nothing else shows it.
PROGRESS = (
    "| `progress` | `None` | `progress(fraction, stage)` called as each stage starts; the stages run one "
    "after the other in the calling thread |"
)


def _default(value):
    if isinstance(value, str):
        return f'`"{value}"`'
    if value is None or isinstance(value, bool):
        return f"`{value!r}`"
    return repr(value)


def _meaning(parameter):
    """The table's cell: help, choices, unit and limits, "not given", where it shows, the link."""
    text = [parameter.help[0].upper() + parameter.help[1:] + "."]
    if parameter.choices:
        text.append(
            " ".join(f'`"{key}"`: {about[0].lower()}{about[1:]}.' for key, _, about in parameter.choices)
        )
    measure = " ".join(filter(None, [parameter.limits, UNITS.get(parameter.unit, "")]))
    if measure:
        text.append(f"{measure[0].upper()}{measure[1:]}.")
    if parameter.unset:
        text.append(f"Not given: {parameter.unset}.")
    shown = [
        f"option `{parameter.flag}`" + ("" if parameter.relief_option else " of `cliff-terrain heights`")
    ]
    if parameter.name == "height_source":
        shown[0] += " (`--heights`, deprecated)"
    if parameter.sidebar:
        shown.append(f"sidebar *{parameter.label}*")
    text.append(f"{', '.join(shown)[0].upper()}{', '.join(shown)[1:]}.")
    if parameter.see:
        text.append(f"See {parameter.see}.")
    return " ".join(text)


def parameter_table():
    """The Markdown table, between its markers."""
    lines = [BEGIN, "", "| parameter | default | meaning |", "|---|---|---|"]
    for name, parameter in PARAMETERS.items():
        lines.append(f"| `{name}` | {_default(parameter.default)} | {_meaning(parameter)} |")
    lines += [PROGRESS, "", END]
    return "\n".join(lines)


def page_table(text):
    """The table now on the page `text` (between the markers)."""
    start, end = text.index(BEGIN), text.index(END) + len(END)
    return text[start:end]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"write it into {PAGE.relative_to(ROOT)}")
    args = parser.parse_args(argv)
    table = parameter_table()
    if args.write:
        text = PAGE.read_text()
        PAGE.write_text(text.replace(page_table(text), table))
    else:
        print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
