"""`plc test` checks the project (the extensions' preflight: stale generated files) in a child process while it
builds (issue 33: the edit-to-verdict time).  The verdict and what is printed are those of the checks run first:
a refused command prints only why, a passing check's output comes before the build's, a check that raises
raises as it did, and the build's own error waits for the verdict."""
from __future__ import annotations

import sys

import pytest

from plc import extensions, project


@pytest.fixture
def checks(monkeypatch):
    """The preflight checks `plc` runs, replaced by the test's own (no extension's)."""
    ext = extensions.Extensions()
    monkeypatch.setattr(extensions, "load", lambda: ext)
    return ext.preflight


def stale(root, command):
    print(f"{command}: st_src/generated.st: out of date: run `generate`", file=sys.stderr)
    return True


def fresh(root, command):
    print("checked the generated files")
    return False


def broken(root, command):
    raise ValueError("the check itself failed")


def build():
    print("built")
    print("a warning of the build", file=sys.stderr)
    return 42


def test_a_refused_command_prints_only_why(checks, tmp_path, capsys):
    checks.append(stale)
    refused, result = project.beside_preflight(project.Preflight(tmp_path, "plc test"), build)
    assert (refused, result) == (True, None)
    out, err = capsys.readouterr()
    assert out == "" and err == "plc test: st_src/generated.st: out of date: run `generate`\n"


def test_a_passing_check_prints_before_the_build_and_the_result_is_the_builds(checks, tmp_path, capsys):
    checks.append(fresh)
    assert project.beside_preflight(project.Preflight(tmp_path, "plc test"), build) == (False, 42)
    out, err = capsys.readouterr()
    assert out == "checked the generated files\nbuilt\n" and err == "a warning of the build\n"


def test_a_check_that_raises_raises_in_the_command(checks, tmp_path, capsys):
    checks.append(broken)
    with pytest.raises(ValueError, match="the check itself failed"):
        project.beside_preflight(project.Preflight(tmp_path, "plc test"), build)
    assert capsys.readouterr().out == ""        # the build's output is dropped with the command


def test_the_builds_error_comes_after_a_passing_verdict_and_not_after_a_refusal(checks, tmp_path, capsys):
    def failing_build():
        print("error: the build failed", file=sys.stderr)
        raise RuntimeError("build")
    checks.append(fresh)
    with pytest.raises(RuntimeError):
        project.beside_preflight(project.Preflight(tmp_path, "plc test"), failing_build)
    out, err = capsys.readouterr()
    assert out == "checked the generated files\n" and err == "error: the build failed\n"
    checks[:] = [stale]
    assert project.beside_preflight(project.Preflight(tmp_path, "plc test"), failing_build) == (True, None)
    assert "error: the build failed" not in capsys.readouterr().err


def test_the_check_runs_in_a_child_process_when_this_one_has_no_other_thread(checks, tmp_path):
    import threading
    checks.append(fresh)
    preflight = project.Preflight(tmp_path, "plc test")
    if threading.active_count() > 1:
        assert preflight.pid is None            # forking beside threads is unsafe: the check runs here when asked
    else:
        assert preflight.pid is not None
    assert preflight.refused() is False and preflight.pid is None


def test_no_check_no_child(checks, tmp_path):
    preflight = project.Preflight(tmp_path, "plc test")
    assert preflight.pid is None and preflight.refused() is False
