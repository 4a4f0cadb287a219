"""The Modbus front end against the regression corpus and a short fuzzing run.

Every entry of runtime_fixtures/modbus_corpus.txt (lying MBAP lengths, coalesced ADUs,
truncated frames, function codes not served, fields out of range...) must get exactly its
recorded outcome.  Then 30,000 mutated frames from runtime_fixtures/mbfuzz.c go to the
ASan/UBSan build, which must still answer a valid request, replay the corpus the same way,
exit 0 on SIGTERM and report nothing.  The long run (>= 1M frames) is scripts/fuzz-modbus,
part of scripts/bench.
"""

from __future__ import annotations

import pytest

import modbus_fuzz as fz
import rt_harness as h

CORPUS = fz.load_corpus()


@pytest.fixture(scope="module")
def rt():
    with h.Runtime(h.runtime_binary(), "--no-rt", "--frame-timeout", str(fz.FRAME_TIMEOUT_MS)) as runtime:
        yield runtime


@pytest.mark.parametrize("entry", CORPUS, ids=[e.name for e in CORPUS])
def test_corpus_entry_gets_its_recorded_outcome(rt, entry):
    assert fz.replay(rt.port, entry) is None
    with h.Client(rt.port) as c:                                  # and the server goes on serving
        assert c.read_input(fz.LAYOUT_VERSION[0]) == [fz.LAYOUT_VERSION[1]]


def test_the_corpus_covers_the_shapes_that_matter():
    names = {e.name for e in CORPUS}
    for needed in ("coalesced-two-reads", "length-longer-than-pdu", "length-shorter-than-pdu", "length-0",
                   "length-ffff", "protocol-id-1", "header-3-bytes", "pdu-2-of-5-bytes", "fc-11-report-server-id",
                   "write-registers-124"):
        assert needed in names


def test_30000_fuzzed_frames_leave_the_asan_build_serving_and_clean():
    report = fz.fuzz_session(30000, seed=19, sanitize=True, hang_limit_s=300)
    print(f"{report.frames} frames in {report.seconds:.1f} s ({report.frames_per_s:.0f}/s), "
          f"{report.answered} answered, {report.dropped} connections dropped")
    assert report.frames == 30000
    assert not report.corpus_failures, report.corpus_failures
    assert report.valid_request_after, report.log_tail
    assert report.sanitizer_findings == 0 and report.exit_status == 0, report.log_tail
    assert report.answered > 10000                                # the frames reached the request path
