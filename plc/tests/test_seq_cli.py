"""`plc seq` behaves like a Unix tool: --help, exit codes 0/1/2, errors on stderr, no tracebacks."""

from __future__ import annotations

import os
import subprocess
import sys

from seq_testlib import CONFIG_INDEX, CORPUS, REPO, VALID_INDEX, run_cli


def test_help_exits_zero_and_lists_the_subcommands():
    run = run_cli("--help")
    assert run.status == 0
    assert "check" in run.out and "compile" in run.out


def test_subcommand_help_describes_the_options():
    assert "--check-drift" in run_cli("compile", "--help").out
    assert "--index" in run_cli("check", "--help").out


def test_usage_errors_exit_two_with_a_message_on_stderr():
    for args in ((), ("frobnicate",), ("check",), ("compile", str(CONFIG_INDEX)), ("check", "--kind", "x", "a.seq")):
        run = run_cli(*args)
        assert run.status == 2, args
        assert "error:" in run.err and run.out == ""


def test_missing_input_file_exits_two():
    run = run_cli("check", CORPUS / "no_such.seq")
    assert run.status == 2
    assert "no such file" in run.err


def test_bad_tool_number_exits_two():
    assert run_cli("check", "--tool", "51", CORPUS / "valid" / "get.seq").status == 2


def test_unwritable_output_exits_two(tmp_path):
    run = run_cli("compile", CONFIG_INDEX, "--out", tmp_path)  # a directory
    assert run.status == 2
    assert "cannot" in run.err


def test_quiet_hides_warnings_and_werror_fails_on_them():
    normal = run_cli("check", VALID_INDEX)
    assert normal.status == 0 and "warning:" in normal.err
    quiet = run_cli("check", "-q", VALID_INDEX)
    assert quiet.status == 0 and quiet.err == ""
    assert run_cli("check", "--werror", VALID_INDEX).status == 1


def test_errors_end_with_a_count():
    run = run_cli("check", CORPUS / "broken" / "unknown_command.seq", CORPUS / "broken" / "p_zero.seq",
                  "--index", VALID_INDEX)
    assert run.status == 1
    assert run.err.rstrip().endswith("2 error(s), 0 warning(s)")


def test_module_entry_point_runs_without_traceback(tmp_path):
    bad = tmp_path / "bad.seq"
    bad.write_bytes(b"OUT 3 1\n\xff\xfe broken bytes\n")
    env = dict(os.environ, PYTHONPATH=str(REPO / "plc" / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-m", "atc.seq", "check", str(bad)], capture_output=True, text=True,
                          env=env, timeout=60)
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    assert "cannot read sequence file" in proc.stderr
