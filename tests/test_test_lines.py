"""tools/test_lines.py: each line's pytest status and closing line, and the counts summed over lines."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import test_lines  # noqa: E402


def test_run_returns_pytests_status_and_closing_line(tmp_path, capsys):
    tests = tmp_path / "test_sample.py"
    tests.write_text("def test_passes():\n    pass\n\n\ndef test_fails():\n    assert False\n")
    status, closing, seconds = test_lines.run(sys.executable, [str(tests)], ["-p", "no:cacheprovider"])
    assert status == 1 and seconds > 0
    assert closing.startswith("1 failed, 1 passed in ")
    assert "test_fails" in capsys.readouterr().out  # pytest's own output is passed on


def test_counts_read_every_kind_of_result():
    assert test_lines.counts("2 failed, 56 passed, 3 skipped, 1 xfailed, 1 error in 3.10s") == {
        "passed": 56, "failed": 2, "skipped": 3, "errors": 0, "error": 1}
