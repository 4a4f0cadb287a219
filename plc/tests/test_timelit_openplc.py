"""timelit.openplc_duration_ns repeats OpenPLC v3's __time_to_timespec (iec_std_lib.h) exactly.

The figures below were measured by compiling OpenPLC_v3's own header (bb35f69) with g++ on x86-64 and calling
the macro with the numbers iec2c writes for each literal; the portability rule `time-inexact` and the
generators' `ms_literal` rest on this emulation.
"""
from plc.timelit import exact_openplc_spelling, matiec_takes_duration, ms_literal, openplc_duration_ns, \
    portable_spelling


def test_the_values_openplc_makes_of_some_literals():
    assert openplc_duration_ns("4ms") == 3_999_999
    assert openplc_duration_ns("0.004s") == 4_000_000
    assert openplc_duration_ns("1s4ms") == 1_003_999_999
    assert openplc_duration_ns("-4ms") == -3_999_999
    assert openplc_duration_ns("100ms") == 100_000_000
    assert openplc_duration_ns("4.5ms") == 4_500_000
    assert openplc_duration_ns("2s") == 2_000_000_000
    assert openplc_duration_ns("5us") is None


def test_as_many_whole_milliseconds_are_inexact_as_on_openplc():
    # g++ with OpenPLC's header: 3,943 of T#0ms..T#9999ms are short (48,169 of T#0ms..T#99999ms)
    assert sum(openplc_duration_ns(f"{m}ms") != m * 1_000_000 for m in range(10_000)) == 3_943


def test_the_spelling_offered_is_exact_on_every_platform():
    assert exact_openplc_spelling(4_000_000) == "T#0.004s"
    assert exact_openplc_spelling(7_000_000) == "T#7ms"
    for platform in ("x86-64", "arm64", "arm32"):
        assert openplc_duration_ns("0.004s", platform) == 4_000_000


def test_generators_keep_exact_literals_and_replace_the_short_ones():
    assert ms_literal(100) == "T#100ms"
    assert ms_literal(4) == "T#0.004s"


def test_the_durations_matiec_reads():
    # each checked with OpenPLC_v3's iec2c: ok, or "invalid value for duration"
    taken = ["30m0s500ms", "1h30m", "90m", "1.5s", "2s20ms", "0.004s", "1_000ms", "1m1.5s", "1d2h", "100s",
             "1h59m59s999ms", "1h59m59s999.5ms", "1s_5ms", "0_5s", "1d23h", "2.5ms", "-5s"]
    refused = ["30m500ms", "1h90m", "1s1500ms", "1d25h", "1.5m30s", "1d2m", "1h60m", "1d24h", "1h2s", "5m3ms"]
    assert [t for t in taken if not matiec_takes_duration(t)] == []
    assert [t for t in refused if matiec_takes_duration(t)] == []


def test_the_spelling_offered_for_a_refused_duration_is_read_and_exact():
    assert portable_spelling(1_800_500_000_000) == "T#1800500ms"
    assert portable_spelling(2_500_000) == "T#2.5ms"
    assert portable_spelling(-4_000_000) == "T#-0.004s"
