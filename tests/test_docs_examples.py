"""Every ```python block of the documentation (docs/**/*.md) runs as written: a page's blocks in page order, in
one namespace, from an empty working directory (so nothing lands in the repository). Examples that cannot run
in a test (a GUI, a cluster, long training) are fenced ```text or ```bash instead."""
import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.DOTALL | re.MULTILINE)


def python_blocks(page: Path) -> list[str]:
    """The page's ```python blocks, in order."""
    return BLOCK.findall(page.read_text(encoding="utf-8"))


PAGES = sorted(page.relative_to(DOCS).as_posix() for page in DOCS.rglob("*.md") if python_blocks(page))


def test_the_docs_carry_runnable_examples():
    assert len(PAGES) >= 4, PAGES


@pytest.mark.parametrize("page", PAGES)
def test_the_python_blocks_of_a_page_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"docs_example_{re.sub(r'[^0-9A-Za-z]', '_', page)}"}
    for i, code in enumerate(python_blocks(DOCS / page)):
        exec(compile(code, f"{page}:block{i}", "exec"), namespace)
