"""The A/B harness (postprocess/ab.py): an earlier revision runs from a worktree of its own and
imports none of this tree's code; a series alternates the codes and compares their results."""
import csv
import shutil
import sys

import pytest

from hydrofrac.postprocess import ab

pytestmark = pytest.mark.skipif(shutil.which("git") is None or ab._git("rev-parse", "HEAD").returncode != 0,
                                reason="needs git and this repository's history")


def test_a_base_worktree_imports_only_its_own_packages(tmp_path):
    """The worktree links its subpackages as its pyproject.toml maps them, so every package of a
    base run comes from it; without a link the editable install of this tree would supply that
    package, and the check refuses the run."""
    where = tmp_path / "base"
    ab.worktree(ab.resolve("HEAD"), where)
    try:
        files = ab.check_imports(where, sys.executable)
        assert set(files) == set(ab.PACKAGES)
        for f in files.values():
            assert str(where) in f
        (where / "hydrofrac" / "meshes").unlink()
        with pytest.raises(ab.Error, match="hydrofrac.meshes"):
            ab.check_imports(where, sys.executable)
    finally:
        ab.remove_worktree(where)


def test_a_series_alternates_the_codes_and_compares_their_results(tmp_path):
    """HEAD against this tree on the bars' impact (one rank, two rounds): the rows alternate and
    the order turns in the second round, the same code gives the same accuracy block, and the
    table gives each round's ratio and their mean."""
    rows = ab.main(["scenarios/two_bars.py", "--base", "HEAD", "--args", "--quick", "--ranks", "1", "--rounds", "2",
                    "--warmup", "none", "--variant", "again=", "--out", str(tmp_path)])
    assert [(r["round"], r["label"]) for r in rows] == [(1, "base"), (1, "again"), (2, "again"), (2, "base")]
    with open(tmp_path / "ab.csv") as f:
        assert len(list(csv.DictReader(f))) == 4
    acc = [k for k in rows[0] if k.startswith("accuracy.")]
    assert "accuracy.duration" in acc
    for r in rows[1:]:
        assert all(r[k] == rows[0][k] for k in acc)
    table = (tmp_path / "ab.md").read_text()
    assert "(= base)" in table and "(Δ" not in table
    speed = table.split("\n\n")[1]  # (the first table: wall times and the rounds' ratios)
    assert speed.count("×") == 3 and "geometric mean" in speed  # the variant's two rounds and their mean
    assert "| stepping (wall - remeshing) |" in table and "| bulk operator |" in table
    assert (tmp_path / "ab.png").stat().st_size > 10_000
    assert (tmp_path / "base_1" / "summary.json").exists() and (tmp_path / "again_2" / "summary.json").exists()


@pytest.mark.parametrize("argv, message", [
    (["scenarios/two_bars.py", "--base", "no-such-revision"], "is not a commit"),
    (["scenarios/no_such.py", "--base", "HEAD"], "no scenario script"),
    (["scenarios/two_bars.py", "--base", "HEAD", "--variant", "base=--quick"], "other than 'base'"),
    (["scenarios/two_bars.py", "--base", "HEAD", "--variant", "x=", "--variant", "x=--quick"], "must differ"),
    (["scenarios/two_bars.py", "--base", "HEAD", "--rounds", "0"], "at least 1"),
])
def test_bad_input_is_refused_before_any_run(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        ab.main(argv + ["--out", str(tmp_path / "out")])
    assert e.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_run_without_a_summary_is_refused_not_taken_from_an_earlier_series(tmp_path):
    """A run that writes no summary (here ``--help``, which exits 0) raises with its log's tail,
    even where an earlier series left a summary in its output folder."""
    out = tmp_path / "base_1"
    out.mkdir()
    (out / "summary.json").write_text('{"wall_time_s": 1.0}')
    with pytest.raises(RuntimeError, match="exit 0, summary missing"):
        ab.run_one(ab.ROOT, "scenarios/two_bars.py", ["--help"], out, 1, sys.executable, "mpirun")
