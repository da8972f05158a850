"""The suite's own check (conftest.signals_left_as_found): a test that leaves a signal handler
changed fails, named, and the handler is put back for the tests after it."""

from __future__ import annotations

from pathlib import Path

pytest_plugins = ["pytester"]

CONFTEST = Path(__file__).with_name("conftest.py")


def test_a_test_leaving_sigint_ignored_fails_and_the_next_one_finds_it_put_back(pytester):
    pytester.makeconftest(CONFTEST.read_text(encoding="utf-8"))
    pytester.makepyfile(
        test_leaves="""
        import signal

        # Python's own handler, as where SIGINT was not ignored at its start (a shell's
        # background job starts with it ignored, and Python then leaves it so)
        signal.signal(signal.SIGINT, signal.default_int_handler)

        def test_ignores_ctrl_c():
            signal.signal(signal.SIGINT, signal.SIG_IGN)

        def test_after_it():
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler

        def test_puts_back():
            old = signal.signal(signal.SIGTERM, lambda *a: None)
            signal.signal(signal.SIGTERM, old)
        """
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=3, errors=1)
    result.stdout.fnmatch_lines(["*test_ignores_ctrl_c left the handler of SIGINT changed*"])
