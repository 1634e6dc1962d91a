"""The READMEs' result tables are what ``benchmarks/tables.py`` renders from the committed JSON.

A rerun benchmark changes its JSON; unless the tables are regenerated
(``python benchmarks/tables.py``) this fails, naming the stale file, so no table can quote a
figure its file no longer holds.
"""

from __future__ import annotations

import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TABLES = runpy.run_path(str(ROOT / "benchmarks" / "tables.py"), run_name="tables_under_test")


@pytest.mark.slow
@pytest.mark.parametrize("readme", ["README.md", "benchmarks/README.md"])
def test_committed_tables_equal_the_generated_ones(readme):
    text = (ROOT / readme).read_text()
    assert "<!-- table:" in text
    assert TABLES["render"](text) == text, (
        f"{readme} quotes figures its JSON no longer holds: run python benchmarks/tables.py"
    )


def test_every_table_renders_and_every_block_names_a_known_table():
    names = {m.group(2) for path in TABLES["READMES"]
             for m in TABLES["BLOCK"].finditer(path.read_text())}  # fmt: skip
    assert names <= set(TABLES["TABLES"]), names - set(TABLES["TABLES"])
    assert names == set(TABLES["TABLES"]), set(TABLES["TABLES"]) - names  # none left unused
    with pytest.raises(ValueError, match="unknown table 'nope'"):
        TABLES["render"]("<!-- table:nope -->\nx\n<!-- /table -->")


def test_a_changed_figure_is_noticed():
    """The check has teeth: a block edited by hand is put back by the renderer."""
    text = (ROOT / "README.md").read_text()
    block = TABLES["BLOCK"].search(text)
    edited = text[: block.start(3)] + "99.9 %\n" + text[block.start(3) :]
    assert TABLES["render"](edited) == text


def test_the_benchmarks_readme_is_short_and_has_a_section_per_script():
    """benchmarks/README.md is read in a quarter of an hour (issue 51: at most 800 lines); every
    script that writes a result has a section heading naming it, and every result file has its
    generated "Main run" line there."""
    text = (ROOT / "benchmarks" / "README.md").read_text()
    assert len(text.splitlines()) <= 800
    headings = "\n".join(line for line in text.splitlines() if line.startswith("## "))
    scripts = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py") if p.name != "tables.py")
    assert [s for s in scripts if f"`{s}`" not in headings] == []
    results = sorted((ROOT / "benchmarks" / "results").glob("*.json*"))
    for path in results:
        stem = path.name.removesuffix(".gz").removesuffix(".json")
        if stem != "pose_ablation":  # no main run: each sweep is a config, in its tables
            assert f"<!-- table:conditions-{stem} -->" in text, stem
    for png in (ROOT / "benchmarks" / "results").glob("*.png"):  # every figure is shown
        assert f"results/{png.name}" in text or png.name == "camera_views.png", png.name
