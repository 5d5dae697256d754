"""Progress bars: drawn on a terminal only, off with --quiet or TQDM_DISABLE."""

import io

from tqdm import tqdm

from apps.progress import bar_disable


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _drawn(stream, progress: bool) -> bool:
    for _ in tqdm(range(3), file=stream, disable=bar_disable(progress), mininterval=0):
        pass
    return "3/3" in stream.getvalue()


def test_a_bar_is_drawn_on_a_terminal_only(monkeypatch):
    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    assert _drawn(_Tty(), True)
    assert not _drawn(io.StringIO(), True)  # redirected: no bar in the log
    assert not _drawn(_Tty(), False)  # --quiet


def test_tqdm_disable_in_the_environment_turns_bars_off(monkeypatch):
    monkeypatch.setenv("TQDM_DISABLE", "1")
    assert not _drawn(_Tty(), True)
