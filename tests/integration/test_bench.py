"""The benchmark suite ``experiments/bench.py`` (a source-checkout script): its table, options and ratios."""

import re
import sys

import pytest
from _paths import EXPERIMENTS


@pytest.fixture
def bench(monkeypatch):
    """``experiments/bench.py`` imported afresh (its timings are cached per module), ``experiments/`` on the path."""
    monkeypatch.syspath_prepend(EXPERIMENTS)
    for name in ("bench", "_bench"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    import bench

    return bench


def test_quick_fk_table(bench, capsys, tmp_path):
    assert bench.main(bench.parse_args(["--quick", "--only", "fk", "--out", str(tmp_path / "bench.md")])) == 0
    out = capsys.readouterr().out
    assert "| work | batch | dtype | diffkin | pytorch-kinematics | pk / diffkin | notes |" in out
    rows = [line for line in out.splitlines() if line.startswith("| FK |")]
    assert [r.split(" | ")[1:3] for r in rows] == [[b, d] for b in ("1", "1,000") for d in ("float32", "float64")]
    assert all(re.search(r"\| (\*\*[\d.]+x\*\*|\d+x \(implausible: busy machine\? rerun\)) \|", r) for r in rows), rows
    assert (tmp_path / "bench.md").read_text().strip() in out


def test_without_pytorch_kinematics(bench, capsys, monkeypatch):
    import _bench

    for module in (_bench, bench):  # bench.py holds its own reference (from _bench import pk)
        monkeypatch.setattr(module, "pk", None)
    assert bench.main(bench.parse_args(["--quick", "--only", "fk"])) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| FK |")]
    assert len(rows) == 4 and all("| n/a | n/a |" in r for r in rows), rows


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--only", "fk,nope"], "unknown part 'nope'"),
        (["--only", ","], "no part"),
        (["--write", "--out", "x.md"], "not allowed with"),
        (["--out", "/nonexistent/dir/b.md"], "no such directory"),
    ],
)
def test_usage_errors(bench, capsys, argv, match):
    with pytest.raises(SystemExit) as exit_:
        bench.parse_args(argv)
    assert exit_.value.code == 2 and match in capsys.readouterr().err


def test_implausible_ratios_are_marked(bench):
    assert bench._ratio(42.0) == "**42x**"
    assert bench._ratio(850.0) == "850x (implausible: busy machine? rerun)"
