"""Ctrl-C and SIGTERM during a command (``catenary.cli.app.Interruptions``)."""

from __future__ import annotations

import signal

import pytest

from catenary.cli.app import Interruptions, Terminated, interrupted_exit_code


class _RaisesInDel:
    """An object whose finaliser receives ``signum``: Python prints what a finaliser raises
    and goes on."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def __del__(self) -> None:
        signal.raise_signal(self.signum)


@pytest.mark.parametrize(
    ("signum", "kind", "code"),
    [(signal.SIGINT, KeyboardInterrupt, 130), (signal.SIGTERM, Terminated, 143)],
)
def test_an_interruption_python_only_prints_is_raised_at_the_next_check(
    signum: int, kind: type[KeyboardInterrupt], code: int, capsys: pytest.CaptureFixture[str]
) -> None:
    before = signal.getsignal(signum)
    interruptions = Interruptions()
    with interruptions.handled():
        _RaisesInDel(signum)  # finalised at once: the interruption lands in __del__
        assert isinstance(interruptions.received, kind)
        with pytest.raises(kind) as raised:
            interruptions.check()
    assert interrupted_exit_code(raised.value) == code
    assert capsys.readouterr().err == ""  # not printed as "Exception ignored in ..."
    assert signal.getsignal(signum) is before
