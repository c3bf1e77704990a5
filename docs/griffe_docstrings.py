"""A Griffe extension for the documentation build (mkdocs.yml): it adapts ftcgym's plain docstrings to Markdown
without touching the code.

1. A class-level attribute without a docstring takes the comment at the end of its line as its docstring, or
   else the comment lines just above it. ftcgym documents the fields of its settings dataclasses that way:

       R: float = TABLE_II["R"]           # measurement noise, times I (Table II)
       # process noise per sample, times I (see Q_PER_SAMPLE)
       Q: float = field(default=Q_PER_SAMPLE, metadata=accepts(POSITIVE))

   Without this, mkdocstrings would list the field with its default but not its meaning.
2. A paragraph of aligned definitions, two or more lines of the form `name:   text`, keeps one definition per
   line (Markdown would run them together into one paragraph).
"""
from __future__ import annotations

import io
import re
import tokenize
from functools import cache
from pathlib import Path

import griffe

ALIGNED = re.compile(r"^\S.*?:\s{2,}\S")   # "name:   text": a label, a colon, then column padding


@cache
def comments_of(path: str) -> tuple[dict[int, str], dict[int, str]]:
    """(line number -> text of a comment that follows code on that line, line number -> text of a comment line
    that has no code)."""
    trailing, whole = {}, {}
    source = Path(path).read_text(encoding="utf-8")
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            text = token.string.lstrip("#").strip()
            (trailing if token.line[:token.start[1]].strip() else whole)[token.start[0]] = text
    return trailing, whole


def comment_of(path: str, first: int, last: int) -> str | None:
    """The comment documenting the code on lines first..last: one at the end of them, else the comment lines
    right above the first (joined)."""
    trailing, whole = comments_of(path)
    for line in (first, last):
        if line in trailing:
            return trailing[line]
    above = []
    line = first - 1
    while line in whole:
        above.insert(0, whole[line])
        line -= 1
    return " ".join(above) or None


def keep_definition_lines(text: str) -> str:
    """`text` with a Markdown hard break ending every line but the last of each aligned-definition paragraph."""
    paragraphs = text.split("\n\n")
    for i, paragraph in enumerate(paragraphs):
        lines = paragraph.split("\n")
        if sum(bool(ALIGNED.match(line)) for line in lines) >= 2:
            paragraphs[i] = "\n".join(line.rstrip() + "  " for line in lines[:-1]) + "\n" + lines[-1]
    return "\n\n".join(paragraphs)


class PlainDocstrings(griffe.Extension):
    """Both adaptations of the module docstring."""

    def on_instance(self, *, node, obj: griffe.Object, agent, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = keep_definition_lines(obj.docstring.value)

    def on_attribute_instance(self, *, node, attr: griffe.Attribute, agent, **kwargs) -> None:
        if (attr.docstring is not None or not attr.parent or not attr.parent.is_class or attr.lineno is None
                or "class-attribute" not in attr.labels):      # fields, not what __init__ assigns
            return
        filepath = attr.parent.filepath
        if isinstance(filepath, list) or not str(filepath).endswith(".py"):
            return
        text = comment_of(str(filepath), attr.lineno, attr.endlineno or attr.lineno)
        if text:
            attr.docstring = griffe.Docstring(text, lineno=attr.lineno, parent=attr)
