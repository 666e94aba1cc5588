"""A register map as a Markdown table, so the docs show what the code reads and cannot drift.

:func:`markdown` renders one map; :func:`render_doc` replaces every generated block of a document
(``<!-- regmap NAME -->`` ... ``<!-- /regmap -->``) with the table of the shipped map NAME.
``python -m helicalib.devices.regdoc docs/register-maps.md`` rewrites the file in place.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from helicalib.devices.regmap import RegisterMap, load_register_map
from helicalib.devices.regschema import Q

BLOCK = re.compile(r"(<!-- regmap (?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /regmap -->)", re.S)


def _span(q: Q) -> str:
    first, last = q.start, q.start + q.width - 1
    text = f"{first}" if first == last else f"{first}–{last}"
    return f"+{text}" if q.block else text


def _encoding(q: Q) -> str:
    if q.parts:
        return " + ".join(_encoding(p) + (f" × {p.scale:g}" if p.scale != 1 else "") for p in q.parts)
    if q.table == "coil":
        return "bit"
    out = q.type
    if q.width > 1:
        out += ", low word first" if q.word_order == "low_first" else ", high word first"
    if q.byte_order == "little":
        out += ", bytes swapped"
    return out


def _scale(q: Q) -> str:
    if q.parts:
        return ""
    out = f"× {q.scale:g}" if q.scale != 1 else ""
    if q.value_offset:
        out += f" {'+' if q.value_offset > 0 else '−'} {abs(q.value_offset):g}"
    return out.strip()


def _values(q: Q) -> str:
    if q.equals is not None:
        return f"= {q.equals}"
    if q.bits:
        return ", ".join(f"bit {b} {n}" for b, n in sorted(q.bits.items())) + "; none: idle"
    if q.values:
        items = q.values.items()
        if all(isinstance(k, str) for k, _ in items):
            return ", ".join(f"{n} {v}" for n, v in items)
        return ", ".join(f"{v} {n}" for v, n in sorted(items))
    return ""


def markdown(m: RegisterMap) -> str:
    """The map as a paragraph (defaults, blocks, handshake) and a table of every quantity."""
    d, h = m.doc.defaults, m.doc.heliostats
    blocks = (f"{h.base} + {h.stride}·i" if h.addresses is None
              else "the addresses " + ", ".join(str(a) for a in h.addresses))
    if h.per_unit:
        blocks = (f"{h.base} + {h.stride}·(i mod {h.per_unit}) on unit id u + ⌊i / {h.per_unit}⌋ "
                  f"({h.per_unit} heliostats per unit id; u is the field config's `plant.scs.unit`, plant-wide "
                  "registers answer on every unit)")
    hs = h.command.handshake
    done = "the last sequence number processed" if hs.kind == "sequence" else "the commands-taken counter"
    command_table = d.command_table or d.table
    tables = (f"{d.table} registers only" if command_table == d.table
              else f"read-only data in {d.table} registers, commands in {command_table} registers")
    lines = [f"`{m.name}`: {m.doc.title or m.name}. By default {tables}; heliostat i's block (i = 0, 1, ... in "
             f"the field config's order) at {blocks}; handshake `{hs.kind}` (done = {done}).",
             "",
             "| key | table | register | encoding | scale | unit | values | meaning | access |",
             "|---|---|---|---|---|---|---|---|---|"]
    for q in m.q.values():
        cells = (f"`{q.path}`", q.table, _span(q), _encoding(q), _scale(q), q.unit, _values(q), q.meaning,
                 "W" if q.writable else "R")
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    readable = [f"{r.table} {r.first}–{r.last}" for r in m.doc.readable]
    if readable or h.block_size:
        extra = ([f"the ranges {', '.join(readable)}"] if readable else []) + \
                ([f"a block's whole {h.block_size} registers"] if h.block_size else [])
        lines += ["", f"Registers that answer reads besides the mapped ones (0 where nothing is mapped): "
                      f"{' and '.join(extra)}."]
    return "\n".join(lines) + "\n"


def render_doc(text: str) -> str:
    """``text`` with every generated block replaced by its map's current table."""
    return BLOCK.sub(lambda mt: mt.group(1) + markdown(load_register_map(mt.group("name"))) + mt.group(4), text)


if __name__ == "__main__":  # pragma: no cover - a maintainer's tool
    for arg in sys.argv[1:]:
        path = Path(arg)
        path.write_text(render_doc(path.read_text(encoding="utf-8")), encoding="utf-8")
