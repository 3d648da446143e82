"""A griffe extension for the API reference: the docstrings are written for readers of the
source (reStructuredText roles, ``>>>`` examples, ``::`` literal blocks); this turns them into
Markdown as mkdocstrings renders it, without changing the source."""

import re

import griffe

ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|exc|obj):`~?([^`]+)`")


def to_markdown(text: str) -> str:
    text = ROLE.sub(lambda m: f"`{m.group(1)}`", text)
    text = re.sub(r"(\S)::$", r"\1:", text, flags=re.M)
    out, block = [], None
    for line in text.split("\n"):
        stripped = line.lstrip()
        if block is None and stripped.startswith(">>>"):
            indent = line[: len(line) - len(stripped)]
            block = indent
            out.append(f"{indent}```pycon")
        elif block is not None and not stripped:
            out.append(f"{block}```")
            block = None
        out.append(line)
    if block is not None:
        out.append(f"{block}```")
    return "\n".join(out)


class DoctestBlocks(griffe.Extension):
    def on_instance(self, *, obj, **kwargs):
        if obj.docstring is not None:
            obj.docstring.value = to_markdown(obj.docstring.value)
