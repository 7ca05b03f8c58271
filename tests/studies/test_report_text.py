"""A study's free text in report.md (issue 42): the description, notes, published controllers, log names, the
storage URL and error messages went in raw, so a report rendered as HTML ran a study's <script> and fetched its
images, and a newline or a pipe broke a table. They are written as text (HTML and Markdown markup escaped) or as
code spans."""

from __future__ import annotations

import re
from pathlib import Path

from tuner.studies.report import code, render_report, text
from tuner.studies.schema import parse_study

HOSTILE = "<script>alert(1)</script> ![x](http://evil/p.png) *b* | c\nd"


def _report(tmp_path: Path) -> str:
    study = parse_study({
        "name": "html", "description": HOSTILE, "loop": [
            {"name": "a", "plant": "1/(s+1)", "structure": "pi", "note": "<img src=x onerror=alert(1)>",
             "thesis_controller": "2`(s+1)`/s"},
            {"name": "b", "structure": "pi", "data": {"file": "<b>log</b>.csv", "input": "u|x", "output": "<i>y",
                                                      "time": "t", "poles": 1}}]})
    results = {"a": {"loop": "a", "error": "</td><script>bad()</script>"},
               "b": {"loop": "b", "error": "line 2\n| broken | table |"}}
    return render_report(study, results, {}, {}, {}, out_dir=tmp_path, storage="sqlite:///x`<b>`.db")


def test_no_markup_of_the_study_reaches_the_report(tmp_path):
    md = _report(tmp_path)
    for raw in ("<script>", "<img", "<i>y", "</td>"):  # (code spans show theirs as written)
        assert raw not in md, (raw, md)
    assert not re.search(r"(?<!\\)\]\(http://evil", md)  # no image: its brackets are escaped
    assert "&lt;script&gt;alert(1)&lt;/script&gt; \\!\\[x\\](http://evil/p.png) \\*b\\* \\| c" in md
    assert "- **a**: &lt;img src=x onerror=alert(1)&gt;" in md
    assert "Storage: ``sqlite:///x`<b>`.db``" in md and "`<b>log</b>.csv`: u\\|x → &lt;i&gt;y" in md  # code spans
    for line in md.splitlines():  # every table row has its columns: no cell broke the table
        if line.startswith("| b |"):
            assert "line 2 \\| broken \\| table \\|" in line and "\n" not in line, line


def test_text_and_code():
    assert text("a_b [c](d) # e") == "a\\_b \\[c\\](d) \\# e"
    assert text("x\ny", inline=True) == "x y"
    assert code("`a`") == "`` `a` ``" and code("s+1") == "`s+1`"
