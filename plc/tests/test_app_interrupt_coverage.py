"""The interrupted-change scan tests cover every step of the default Put Tool and Get Tool sequences, and nothing
beyond: the cases of iec_tests/app/TEST_InterruptedChange (its table TEST_InterruptedChange.cases.toml, read as
`plc test` reads it) are every step of put.seq and get.seq, each interrupted by an operator abort and by the
E-stop chain.  Adding a step to put.seq or get.seq without widening the table fails here."""
from __future__ import annotations

from pathlib import Path

from plc import testcases

REPO = Path(__file__).resolve().parents[2]
TEST = REPO / "iec_tests" / "app" / "TEST_InterruptedChange.st"
KINDS = ("OperatorAbort", "EStopOpened")


def step_count(seq: Path) -> int:
    """Steps of a .seq file: every line that is not empty or a whole-line comment ('/')."""
    return sum(1 for line in seq.read_text(encoding="utf-8").splitlines()
               if line.strip() and not line.strip().startswith("/"))


def test_the_interrupt_table_covers_every_step_of_put_and_get_for_both_kinds():
    cases = testcases.load([str(TEST)])
    assert not cases.diags.items, [d.render(cases.sources) for d in cases.diags.items]
    found = [tuple(text for _pos, _name, text in case.args) for case in cases.cases]
    assert all(len(args) == 3 for args in found), found        # every case names Kind, Sequence and AtStep
    expected = [(kind, sequence, str(step))
                for sequence, seq in (("KindPutTool", "put.seq"), ("KindGetTool", "get.seq"))
                for kind in KINDS
                for step in range(1, step_count(REPO / "configs" / "sequences" / seq) + 1)]
    assert sorted(found) == sorted(expected)
