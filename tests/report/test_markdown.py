"""report.md rendering (the full-file sections are exercised through write_report in test_build.py)."""

from penfree.core.trust.summary import PROJECTED_FORMULA
from penfree.report.markdown import render_markdown


def _doc(checks):
    return {"penfree_version": "0", "options": {"cd_share": 0.5}, "files": [],
            "plots": {"status": "disabled", "reason": "plots not requested", "files": [], "per_file": []},
            "checks": checks, "all_checks_passed": all(c["passed"] for c in checks)}


def test_header_states_the_projection():
    md = render_markdown(_doc([]))
    assert md.startswith("# penfree report\n") and PROJECTED_FORMULA in md and "`cd_share=0.5`" in md
    assert "Plots disabled: plots not requested." in md and "## Checks" not in md


def test_failed_check_is_marked():
    md = render_markdown(_doc([{"name": "min_speedup", "file": "a.h5", "passed": False, "value": 1.0,
                                "threshold": 1.1, "message": "projected speedup 1.000 (minimum 1.1)"}]))
    assert "| min_speedup | a.h5 | **FAIL** | projected speedup 1.000 (minimum 1.1) |" in md
    assert "All checks passed: NO." in md
