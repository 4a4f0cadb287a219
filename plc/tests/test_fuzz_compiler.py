"""A short, seeded fuzz run in the suite: no traceback, no hang, generated C always compiles.

The full run (10,000 mutations) is `python plc/tests/fuzz_compiler.py --runs 10000 --seed 1`.
"""
from __future__ import annotations

from fuzz_compiler import corpus, fuzz, mutate


def test_corpus_holds_project_sources_and_conformance_snippets():
    names = [n for n, _t in corpus()]
    assert any(n.startswith("st_src/") for n in names)
    assert any(n.startswith("iec_tests/") for n in names)
    assert any("/stdlib/" in n for n in names)
    assert any(n.startswith("test_conformance_") for n in names)


def test_mutations_are_deterministic_for_a_seed():
    import random
    items = corpus()
    a = [mutate(items[k % len(items)][1], random.Random(k), items) for k in range(20)]
    b = [mutate(items[k % len(items)][1], random.Random(k), items) for k in range(20)]
    assert a == b
    assert sum(m[0] != items[k % len(items)][1] for k, m in enumerate(a)) >= 15


def test_300_mutations_give_no_traceback_no_hang_and_valid_c():
    s = fuzz(300, seed=20260, jobs=2, timeout=60.0, check_c_every=1)   # 60 s bounds a hang only
    assert s["runs"] == 300
    assert s["traceback"] == 0 and s["hang"] == 0, s["findings"]
    assert s["cc-fail"] == 0, s["findings"]
    # the run exercised both the diagnostics and the C generator (the corpus grows with the
    # tests, so the exact split changes; about 6 % of the mutants still compile)
    assert s["error"] > 100 and s["ok"] >= 3 and s["cc-checked"] == s["ok"]
