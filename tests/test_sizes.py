"""The house stays small enough to read: no module of the package over MODULE_LINES code lines
and no function over FUNCTION_LINES, counting code alone (blank lines, comments and docstrings
aside). Read from the source with `ast` and `tokenize`; a breach names the file, the line and
its count, so a change that regrows one is caught where it is made."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

from test_layers import ROOT, rooms_of_package

MODULE_LINES = 400
FUNCTION_LINES = 60


def code_lines(source: str) -> set[int]:
    """The line numbers that hold code: not blank, not only a comment, not in a docstring."""
    tree = ast.parse(source)
    docstrings: set[int] = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            value = body[0].value
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                docstrings.update(range(body[0].lineno, (body[0].end_lineno or body[0].lineno) + 1))
    lines: set[int] = set()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT):
            continue
        if token.type == tokenize.ENDMARKER:
            continue
        lines.update(range(token.start[0], token.end[0] + 1))
    return lines - docstrings


def package_modules() -> list[Path]:
    return sorted(p for room in rooms_of_package() for p in (ROOT / room).rglob("*.py"))


def breaches() -> list[str]:
    found = []
    for path in package_modules():
        source = path.read_text()
        code = code_lines(source)
        where = path.relative_to(ROOT)
        if len(code) > MODULE_LINES:
            found.append(f"{where}: {len(code)} code lines (at most {MODULE_LINES})")
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                span = code & set(range(node.lineno, (node.end_lineno or node.lineno) + 1))
                if len(span) > FUNCTION_LINES:
                    limit = f"at most {FUNCTION_LINES}"
                    found.append(f"{where}:{node.lineno} {node.name}: {len(span)} code lines ({limit})")
    return found


def test_no_module_or_function_outgrows_its_limit() -> None:
    assert not breaches(), "\n".join(breaches())


def test_the_count_leaves_out_blank_lines_comments_and_docstrings() -> None:
    source = (
        '"""A module."""\n\n# a comment\ndef f() -> int:\n    """Its doc,\n    two lines."""\n\n'
        "    x = (1,\n         2)  # inline\n    return x[0]\n"
    )
    assert code_lines(source) == {4, 8, 9, 10}
