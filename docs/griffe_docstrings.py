"""A Griffe extension for the documentation build (mkdocs.yml): it adapts ftcgym's plain docstrings to Markdown
without touching the code.

1. A class-level attribute without a docstring takes the comment at the end of its line as its docstring. ftcgym
   documents the fields of its settings dataclasses that way:

       Q: float = Q_PER_SAMPLE            # process noise per sample, times I (see Q_PER_SAMPLE)

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
def trailing_comments(path: str) -> dict[int, str]:
    """Line number -> text of a comment that follows code on that line."""
    comments = {}
    source = Path(path).read_text(encoding="utf-8")
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT and token.line[:token.start[1]].strip():
            comments[token.start[0]] = token.string.lstrip("#").strip()
    return comments


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
        comments = trailing_comments(str(filepath))
        for line in (attr.lineno, attr.endlineno):
            if line in comments:
                attr.docstring = griffe.Docstring(comments[line], lineno=line, parent=attr)
                return
